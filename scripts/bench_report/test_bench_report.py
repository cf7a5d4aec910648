#!/usr/bin/python3
"""Tests of scripts/bench-report (ctest runs them as Scripts.BenchReport):

    /usr/bin/python3 scripts/bench_report/test_bench_report.py

docs/RESULTS.md must be exactly what the committed docs/results and templates produce (after
editing a template or the code, regenerate the page with the command in the failure), and a
template that does not fit the code must stop the script with a message naming the file and
block rather than write a page with a hole in it.
"""
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

SCRIPTS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(SCRIPTS)
sys.dont_write_bytecode = True
sys.path.insert(0, SCRIPTS)

from bench_report.hybrid_variants import hybrid_variants_section  # noqa: E402
from bench_report.page import build_page  # noqa: E402

RESULTS = os.path.join(ROOT, "docs", "results")
REGENERATE = ("/usr/bin/python3 scripts/bench-report docs/results --img-dir docs/img "
              "--out docs/RESULTS.md")


def main_suite(page):
    """The page up to the AVX2 suite's section (the sections bench.json gives)."""
    end = page.find("\n## Builds for AVX2 CPUs\n")
    return page if end < 0 else page[:end]


class Page(unittest.TestCase):
    def test_committed_page_is_what_the_results_give(self):
        with open(os.path.join(ROOT, "docs", "RESULTS.md")) as f:
            committed = f.read()
        page = build_page(RESULTS, os.path.join(ROOT, "docs"), os.path.join(ROOT, "docs", "img"),
                          ROOT)
        self.assertTrue(page == committed, "docs/RESULTS.md differs from what docs/results and "
                        "the templates give; regenerate it: " + REGENERATE)

    def test_tables_state_cpu_simd_and_which_embree(self):
        # The reference is Embree as a user runs it, beside its robust and high-quality
        # configurations; the throughput and build tables say the CPU and each side's SIMD.
        page = build_page(RESULTS, os.path.join(ROOT, "docs"), os.path.join(ROOT, "docs", "img"),
                          ROOT)
        for row in ("| embree (default flags, medium quality) (reference) |",
                    "| embree-robust (robust flags, medium quality) |",
                    "| embree-high (default flags, high quality) |"):
            self.assertIn(row, page)
        # The throughput, packet, whole-render and build tables of the main suite each say it,
        # and the AVX2 suite's throughput, packet and whole-render tables.
        self.assertEqual(main_suite(page).count("SIMD: kdgrid built for "), 4)
        self.assertEqual(page.count("SIMD: kdgrid built for "), 7)
        self.assertIn("| SIMD, Embree | Embree 3.", page)
        self.assertIn("- primary rays: the hybrid is ", page)
        self.assertIn("| Embree scene flags | `RTC_SCENE_FLAG_ROBUST` (`embree-robust`) |", page)

    def test_absent_files_give_not_measured_sections(self):
        with tempfile.TemporaryDirectory() as tmp:
            res = os.path.join(tmp, "results")
            shutil.copytree(RESULTS, res)
            for name in ("viewer.json", "big-scene.json") + tuple(
                    x for x in os.listdir(res) if x.startswith("hybrid-")):
                os.remove(os.path.join(res, name))
            page = build_page(res, tmp, os.path.join(ROOT, "docs", "img"), ROOT)
        self.assertIn("\n## Viewer\n\n*Not measured: there is no viewer.json in %s." % res, page)
        self.assertIn("## The hybrid's variants\n\n*Not measured: run "
                      "`scripts/hybrid-variants.sh`.*\n\n", page)
        self.assertNotIn("-triangle scene (`", page)
        self.assertTrue(page.endswith("(VmHWM/VmRSS) and `getrusage`.\n"))

    def test_ui_frames_table_names_the_largest_frame_and_its_phases(self):
        import copy

        def add_run(v):
            run = copy.deepcopy(next(r for r in v["runs"] if "stats" in r))
            run["name"] = "dragon-ui-boxes"
            phases = {k: {"max_ms": 1.0, "frame": 3} for k in (
                "events", "tasks", "input", "render_job", "image", "overlay", "accuracy",
                "script", "draw", "swap")}
            phases["draw"] = {"max_ms": 61.5, "frame": 0}
            phases["image"] = {"max_ms": 12.25, "frame": 40}
            phases["swap"] = {"max_ms": 90.0, "frame": 0}  # not UI work: left out
            run["stats"]["frames"].update(count=77, phases=phases, ui_ms_summary={
                "frames": 77, "max": 62.5, "p50": 0.75, "p95": 9.5})
            v["runs"].append(run)

        page = self.page_with_result("viewer.json", add_run)
        self.assertIn("**UI frames on the full dragon.**", page)
        self.assertIn("| boxes | 77 | 0.75 | 9.5 | **62.5** | draw 61.5 (frame 0), image 12.2 "
                      "(frame 40) |", page)
        self.assertNotIn("| dragon-ui-boxes |", page)  # not a row of the progressive table

    @staticmethod
    def page_with_result(name, edit):
        """The page from a copy of the committed results whose file `name` `edit` changed."""
        import json
        with tempfile.TemporaryDirectory() as tmp:
            res = os.path.join(tmp, "results")
            shutil.copytree(RESULTS, res)
            with open(os.path.join(res, name)) as f:
                b = json.load(f)
            edit(b)
            with open(os.path.join(res, name), "w") as f:
                json.dump(b, f)
            return build_page(res, tmp, os.path.join(ROOT, "docs", "img"), ROOT)

    @staticmethod
    def page_with_bench(edit):
        """The page from a copy of the committed results whose bench.json `edit` changed."""
        return Page.page_with_result("bench.json", edit)

    def test_render_column_gives_a_whole_render_section(self):
        def add_renders(b):
            b["renders"] = [
                {"scene": s, "accel": a, "reference": "embree", "seconds": sec,
                 "seconds_reps": [sec], "mrays": 1.0, "ratio_to_reference": ratio,
                 "reference_seconds": 0.5, "pixels_differ": differ,
                 "rays": {"primary": 100, "shadow": 40, "reflection": 3, "refraction": 2,
                          "total": 145}}
                for s in ("bunny", "sponza")
                for a, sec, ratio, differ in (("embree", 0.5, 1.0, 0), ("hybrid", 0.4, 1.25, 3))]
        page = self.page_with_result("bench.json", add_renders)
        self.assertIn("## The whole render\n", page)
        self.assertIn("bunny: 100 / 40 / 3 / 2; sponza: 100 / 40 / 3 / 2.", page)
        self.assertIn("| hybrid | 1.25 (0.4 s; 3 px differ) |", page)
        self.assertNotIn("## The whole render", main_suite(
            self.page_with_result("bench.json", lambda b: b.pop("renders", None))))

    def test_an_avx2_run_gets_a_section_of_its_own(self):
        import json
        with tempfile.TemporaryDirectory() as tmp:
            res = os.path.join(tmp, "results")
            shutil.copytree(RESULTS, res)
            with open(os.path.join(res, "bench.json")) as f:
                b = json.load(f)
            b["meta"]["simd"]["kdgrid"]["isa"] = "AVX2"
            b["meta"]["simd"]["embree"]["isa"] = "AVX2"
            with open(os.path.join(res, "bench-avx2.json"), "w") as f:
                json.dump(b, f)
            page = build_page(res, tmp, os.path.join(ROOT, "docs", "img"), ROOT)
        self.assertEqual(page.count("\n## Builds for AVX2 CPUs\n"), 1)
        avx2 = page[page.index("## Builds for AVX2 CPUs"):]
        self.assertIn("kdgrid's code is AVX2, Embree's AVX2.", avx2)
        self.assertIn("**primary rays** (ratio", avx2)
        self.assertIn("\n### Packets\n", avx2)  # the committed run has a packet column
        self.assertIn("**Bytes a triangle** of this build", avx2)
        # bench.json's bytes, copied: the hybrid's row of whole bytes a triangle, scene by scene.
        scenes = [sc["scene"] for sc in b["scenes"]]
        per_scene = {x["scene"]: x["bytes_per_triangle"] for x in b["builds"]
                     if x["accel"] == "hybrid"}
        row = " | ".join("%.0f" % per_scene[n] for n in scenes)
        self.assertIn("| hybrid | %s |" % row, avx2)
        self.assertIn("- primary rays: the hybrid is ", avx2)

    def test_other_cpu_folders_give_one_table_each_with_ranges_over_runs(self):
        import json
        with open(os.path.join(RESULTS, "bench.json")) as f:
            base = json.load(f)

        def run(ratio, render, packet, isa="AVX-512"):
            b = json.loads(json.dumps(base))
            b["meta"]["simd"]["kdgrid"]["isa"] = b["meta"]["simd"]["embree"]["isa"] = isa
            for r in b["results"]:
                if r["accel"] == "hybrid" and r["scene"] == "bunny" and r["set"] == "primary":
                    r["ratio_to_reference"] = ratio
                    r["packet"]["ratio_to_reference"] = packet
            for x in b["renders"]:
                if x["accel"] == "hybrid" and x["scene"] == "bunny":
                    x["ratio_to_reference"] = render
            return b
        with tempfile.TemporaryDirectory() as tmp:
            res = os.path.join(tmp, "results")
            shutil.copytree(RESULTS, res)
            shutil.rmtree(os.path.join(res, "cpus"), ignore_errors=True)
            page = build_page(res, tmp, os.path.join(ROOT, "docs", "img"), ROOT)
            self.assertIn("## On other CPUs\n\n*Not measured on another CPU: run "
                          "`scripts/bench-cpu.sh` there.*", page)
            cpu = os.path.join(res, "cpus", "test-cpu")
            os.makedirs(cpu)
            os.makedirs(os.path.join(res, "cpus", "no-runs-yet"))
            for name, b in (("avx512.1.json", run(0.9, 1.2, 0.7)),
                            ("avx512.2.json", run(1.1, 1.2, 0.704)),
                            ("avx2.1.json", run(0.5, 0.6, 0.8, "AVX2"))):
                with open(os.path.join(cpu, name), "w") as f:
                    json.dump(b, f)
            # bench-cpu.sh's runs in progress: a hidden folder, not a CPU of the page.
            partial = os.path.join(res, "cpus", ".other-cpu.partial")
            os.makedirs(partial)
            with open(os.path.join(partial, "avx512.1.json"), "w") as f:
                json.dump(run(0.3, 0.3, 0.3), f)
            with open(os.path.join(cpu, "cpu.json"), "w") as f:
                json.dump({"model_name": "Test CPU", "vendor": "GenuineIntel", "family": 6,
                           "model": 1, "avx512": True, "commit": "abc1234",
                           "commands": ["kdgrid bench --json X"]}, f)
            page = build_page(res, tmp, os.path.join(ROOT, "docs", "img"), ROOT)
        part = page[page.index("## On other CPUs"):page.index("## Speed vs accuracy")]
        # Neither the folder without runs nor the hidden one has a table.
        self.assertEqual(part.count("\n### "), 1)
        self.assertNotIn("other-cpu", part)
        self.assertIn("### Test CPU (GenuineIntel, family 6, model 1; with AVX-512)", part)
        self.assertIn("`docs/results/cpus/test-cpu/`: 2 thread(s), 1 run(s) of 5", part)
        # Ranges over the runs, each build's rows under its own heading, AVX-512 first.
        self.assertLess(part.index("**AVX-512 build"), part.index("**AVX2 build"))
        avx512, avx2 = part.split("**AVX2 build")
        self.assertIn("| primary rays | 0.90-1.10 |", avx512)
        self.assertIn("| primary packets (64 rays) / `rtcIntersect16` | 0.70 |", avx512)
        self.assertIn("| the whole render | 1.20 |", avx512)
        self.assertIn("| primary rays | 0.50 |", avx2)
        self.assertIn("| the whole render | 0.60 |", avx2)
        hyb = {x["scene"]: x["bytes_per_triangle"] for x in base["builds"]
               if x["accel"] == "hybrid"}
        emb = {x["scene"]: x["bytes_per_triangle"] for x in base["builds"]
               if x["accel"] == "embree"}
        self.assertIn("| bytes a triangle, hybrid / Embree | %.2f |" % (
            hyb["bunny"] / emb["bunny"]), avx512)
        self.assertIn("kdgrid bench --json X\n```", part)

    def test_packet_column_gives_a_packets_section(self):
        # A bench.json with kdgrid bench's packet column gets a Packets section; one without it
        # (measured before the column existed, or with --packet-tile 0) gets none.
        def without_packets(b):
            b["meta"].pop("packet_tile", None)
            for r in b["results"]:
                r.pop("packet", None)

        def one_packet_figure(b):
            without_packets(b)
            b["meta"]["packet_tile"] = 8
            scene = b["results"][0]["scene"]
            for r in b["results"]:
                if r["scene"] == scene and r["set"] == "primary" and r["accel"] == "hybrid":
                    r["packet"] = {"rays_per_packet": 64, "packet_width": 1, "mrays": 2.72,
                                   "ratio_to_reference": 0.33, "speedup_over_single_loop": 0.96,
                                   "mismatches": 0, "mismatched_ties": 0}

        self.assertNotIn("\n## Packets\n", main_suite(self.page_with_bench(without_packets)))
        page = main_suite(self.page_with_bench(one_packet_figure))
        self.assertIn("\n## Packets\n\nThe primary rays again in 8x8 tiles, one packet of 64", page)
        self.assertIn("**primary rays, packets**", page)
        self.assertNotIn("**shadow rays, packets**", page)
        self.assertIn("| hybrid | 0.33 (2.72; x0.96; 1) |", page)

    def test_tables_name_the_leaf_lanes_where_recorded(self):
        # bench.json files from before the hybrid's leaves held triangle groups have no
        # leaf_lanes: their tables say the leaves test one triangle at a time.
        def lanes(n):
            def edit(b):
                k = b["meta"]["simd"]["kdgrid"]
                k.pop("leaf_lanes", None)
                if n:
                    k["leaf_lanes"] = n
            return edit

        self.assertIn("vectors, its leaves' triangles 8 at a time", self.page_with_bench(lanes(8)))
        self.assertIn("vectors, its leaves' triangles one at a time",
                      self.page_with_bench(lanes(None)))

    def test_variant_file_under_its_earlier_name_gives_the_same_section(self):
        # hybrid-nocache.json was hybrid-noguess.json: a results directory written before the
        # rename gives the same section.
        with tempfile.TemporaryDirectory() as tmp:
            res = os.path.join(tmp, "results")
            shutil.copytree(RESULTS, res)
            os.rename(os.path.join(res, "hybrid-nocache.json"),
                      os.path.join(res, "hybrid-noguess.json"))
            old = hybrid_variants_section(res)
        new = hybrid_variants_section(RESULTS)
        self.assertIn("no next-leaf cache (`--hybrid-no-next-leaf-cache`)", new)
        self.assertTrue(old == new, "the section differs when the variant's file has its old name")

class Templates(unittest.TestCase):
    """Each test breaks one template in a copy of templates/ and runs the real entry point."""

    def run_with(self, edit):
        with tempfile.TemporaryDirectory() as tmp:
            pkg = os.path.join(tmp, "scripts", "bench_report")
            shutil.copytree(os.path.join(SCRIPTS, "bench_report"), pkg)
            shutil.copy(os.path.join(SCRIPTS, "bench-report"), os.path.join(tmp, "scripts"))
            edit(os.path.join(pkg, "templates"))
            out = os.path.join(tmp, "RESULTS.md")
            p = subprocess.run([sys.executable, os.path.join(tmp, "scripts", "bench-report"),
                                RESULTS, "--out", out], capture_output=True, text=True)
            return p.returncode, p.stderr, os.path.exists(out)

    @staticmethod
    def replace(path, old, new):
        with open(path) as f:
            text = f.read()
        assert old in text, (path, old)
        with open(path, "w") as f:
            f.write(text.replace(old, new, 1))

    def expect_error(self, edit, *words):
        rc, err, written = self.run_with(edit)
        self.assertEqual(rc, 1, err)
        self.assertFalse(written)
        for w in words:
            self.assertIn(w, err)

    def test_unchanged_copy_writes_the_page(self):
        rc, err, written = self.run_with(lambda t: None)
        self.assertEqual((rc, written), (0, True), err)

    def test_misspelt_placeholder(self):
        self.expect_error(lambda t: self.replace(os.path.join(t, "bench.md"), "found with $ref",
                                                 "found with $reff"),
                          "bench.md, block 'suite'", "unknown placeholder(s) $reff",
                          "placeholder(s) $ref missing")

    def test_dropped_placeholder_even_when_empty(self):
        # $errors is empty for docs/results: dropping it must still be caught.
        self.expect_error(lambda t: self.replace(os.path.join(t, "bench.md"),
                                                 "$build_plot$extras$errors",
                                                 "$build_plot$extras"),
                          "bench.md, block 'build'", "placeholder(s) $errors missing")

    def test_missing_block(self):
        self.expect_error(lambda t: self.replace(os.path.join(t, "viewer.md"),
                                                 "<!-- block: progressive -->",
                                                 "<!-- block: progress -->"),
                          "viewer.md: no block 'progressive'")

    def test_block_defined_twice(self):
        self.expect_error(lambda t: self.replace(os.path.join(t, "sweeps.md"),
                                                 "<!-- block: lambda -->",
                                                 "<!-- block: cellsize -->"),
                          "sweeps.md:", "block 'cellsize' is defined twice")

    def test_lone_dollar(self):
        self.expect_error(lambda t: self.replace(os.path.join(t, "howto.md"), "$$KDGRID_SCENES",
                                                 "$ KDGRID_SCENES"),
                          "howto.md, block 'howto'", "write $$ for a dollar sign")

    def test_missing_template_file(self):
        self.expect_error(lambda t: os.remove(os.path.join(t, "big_scene.md")),
                          "cannot read the template", "big_scene.md")


if __name__ == "__main__":
    unittest.main()
