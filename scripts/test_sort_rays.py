"""Tests of scripts/sort-rays.py: the output holds the input's rays, each block sorted by the
chosen key and no ray leaving its block, and a file that is not a whole .rays file stops it
with a message naming the file. Run from anywhere: python3 scripts/test_sort_rays.py (ctest
Scripts.SortRays)."""
import importlib.util
import os
import struct
import subprocess
import sys
import tempfile
import unittest

import numpy as np

SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "sort-rays.py")
spec = importlib.util.spec_from_file_location("sort_rays", SCRIPT)
sort_rays = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sort_rays)


def rays_file(path, rays):
    with open(path, "wb") as f:
        f.write(b"RAYS" + struct.pack("<IQ", 1, len(rays)))
        f.write(np.asarray(rays, "<f4").tobytes())


def read_rays(path):
    with open(path, "rb") as f:
        raw = f.read()
    return raw[:16], np.frombuffer(raw, "<f4", offset=16).reshape(-1, 8)


class SortRays(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.TemporaryDirectory()
        rng = np.random.default_rng(3)
        n = 1000
        self.rays = np.zeros((n, 8), np.float32)
        self.rays[:, 0:3] = rng.uniform(-5, 5, (n, 3))
        self.rays[:, 4:7] = rng.normal(size=(n, 3))
        self.rays[:, 7] = np.inf
        self.rays[:, 3] = np.arange(n)  # tmin tags each ray, so its place can be followed
        self.src = os.path.join(self.tmp.name, "in.rays")
        rays_file(self.src, self.rays)

    def tearDown(self):
        self.tmp.cleanup()

    def sort(self, *args):
        out = os.path.join(self.tmp.name, "out.rays")
        p = subprocess.run([sys.executable, SCRIPT, self.src, out, *args],
                           capture_output=True, text=True)
        return p, out

    def test_each_block_sorted_by_its_key_and_no_ray_leaves_its_block(self):
        for key in ("octant-origin", "origin", "direction", "dir-origin"):
            p, out = self.sort("--block", "300", "--key", key)
            self.assertEqual(p.returncode, 0, p.stderr)
            head, got = read_rays(out)
            self.assertEqual(head, b"RAYS" + struct.pack("<IQ", 1, len(self.rays)))
            tags = got[:, 3].astype(int)
            keys = sort_rays.sort_keys(self.rays, key)  # the origin's box is the whole set's
            self.assertEqual(sorted(tags), list(range(len(self.rays))), key)
            np.testing.assert_array_equal(got, self.rays[tags])
            for b in range(0, len(self.rays), 300):
                block = tags[b:b + 300]
                self.assertTrue(((block >= b) & (block < b + 300)).all(), key)
                self.assertTrue((np.diff(keys[block]) >= 0).all(), key)
            self.assertNotEqual(list(tags), list(range(len(self.rays))), key)

    def test_octant_comes_first(self):
        p, out = self.sort()
        self.assertEqual(p.returncode, 0, p.stderr)
        d = read_rays(out)[1][:, 4:7]
        octant = (d[:, 0] < 0) + 2 * (d[:, 1] < 0) + 4 * (d[:, 2] < 0)
        self.assertTrue((np.diff(octant) >= 0).all())

    def test_not_a_rays_file_is_refused_naming_it(self):
        with open(self.src, "wb") as f:
            f.write(b"PLY\n" + bytes(40))
        p, out = self.sort()
        self.assertNotEqual(p.returncode, 0)
        self.assertIn("in.rays is not a .rays file", p.stderr)
        self.assertFalse(os.path.exists(out))

    def test_truncated_file_is_refused_with_its_size(self):
        with open(self.src, "rb") as f:
            raw = f.read()
        with open(self.src, "wb") as f:
            f.write(raw[:-8])
        p, out = self.sort()
        self.assertNotEqual(p.returncode, 0)
        self.assertIn("not the 32016 of 1000 rays", p.stderr)
        self.assertFalse(os.path.exists(out))

    def test_empty_set(self):
        rays_file(self.src, np.zeros((0, 8), np.float32))
        p, out = self.sort("--block", "4")
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(read_rays(out)[1].shape, (0, 8))


if __name__ == "__main__":
    unittest.main()
