"""Tests of scripts/rays_file.py: a cut holds exactly the chosen rays under a header of its own
count; a file that is not a whole version-1 .rays file, and a cut outside the file, stop it with
a message naming the file. Run from anywhere: python3 scripts/test_rays_file.py (ctest
Scripts.RaysFile)."""
import os
import struct
import subprocess
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import rays_file  # noqa: E402

SCRIPT = os.path.join(HERE, "rays_file.py")


def write_rays(path, rays, version=1, count=None):
    with open(path, "wb") as f:
        f.write(b"RAYS" + struct.pack("<IQ", version, len(rays) if count is None else count))
        for r in rays:
            f.write(struct.pack("<8f", *r))


def read_rays(path):
    with open(path, "rb") as f:
        raw = f.read()
    n = struct.unpack("<Q", raw[8:16])[0]
    return n, [struct.unpack_from("<8f", raw, 16 + 32 * i) for i in range(n)]


class RaysFile(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.rays = [tuple(float(8 * i + k) for k in range(8)) for i in range(10)]
        self.src = os.path.join(self.dir.name, "all.rays")
        write_rays(self.src, self.rays)

    def tearDown(self):
        self.dir.cleanup()

    def run_script(self, *args):
        return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True)

    def test_count_and_cut(self):
        r = self.run_script("count", self.src)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(r.stdout.strip(), "10")
        dst = os.path.join(self.dir.name, "cut.rays")
        r = self.run_script("cut", self.src, dst, "3", "4")
        self.assertEqual(r.returncode, 0, r.stderr)
        n, rays = read_rays(dst)
        self.assertEqual(n, 4)
        self.assertEqual(rays, self.rays[3:7])
        self.assertEqual(rays_file.count(dst), 4)

    def test_read_gives_the_count_and_the_bytes(self):
        n, raw = rays_file.read(self.src)
        self.assertEqual(n, 10)
        with open(self.src, "rb") as f:
            self.assertEqual(raw, f.read())
        bad = os.path.join(self.dir.name, "short.rays")
        write_rays(bad, self.rays, count=9)
        with self.assertRaisesRegex(rays_file.RaysFileError, "short.rays holds"):
            rays_file.read(bad)

    def test_whole_and_empty_cuts(self):
        dst = os.path.join(self.dir.name, "cut.rays")
        rays_file.cut(self.src, dst, 0, 10)
        self.assertEqual(read_rays(dst)[1], self.rays)
        rays_file.cut(self.src, dst, 10, 0)
        self.assertEqual(read_rays(dst), (0, []))

    def refused(self, path, *words):
        r = self.run_script("count", path)
        self.assertNotEqual(r.returncode, 0)
        self.assertIn(path, r.stderr)
        for w in words:
            self.assertIn(w, r.stderr)

    def test_broken_files_are_refused(self):
        bad = os.path.join(self.dir.name, "bad.rays")
        with open(bad, "wb") as f:
            f.write(b"RAYZ" + bytes(12))
        self.refused(bad, "not a .rays file")
        write_rays(bad, self.rays, version=2)
        self.refused(bad, "version 2")
        write_rays(bad, self.rays, count=11)
        self.refused(bad, "not the")
        with open(bad, "wb") as f:
            f.write(b"RAY")
        self.refused(bad, "not a .rays file")
        self.refused(os.path.join(self.dir.name, "missing.rays"))

    def test_cut_outside_the_file_is_refused(self):
        dst = os.path.join(self.dir.name, "cut.rays")
        r = self.run_script("cut", self.src, dst, "8", "3")
        self.assertNotEqual(r.returncode, 0)
        self.assertIn(self.src, r.stderr)
        self.assertIn("outside", r.stderr)
        self.assertFalse(os.path.exists(dst))


if __name__ == "__main__":
    unittest.main()
