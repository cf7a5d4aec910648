"""The whole page: the title, the machine and run, each section in order, and how to run it."""
import os

from .common import load, prose, table
from .bench import bench_section, isa_section, leaf_lanes_text
from .big_scene import big_scene_section
from .hybrid_variants import hybrid_variants_section
from .other_cpus import other_cpus_section
from .speed_accuracy import speed_accuracy_section
from .sweeps import sweep_section
from .viewer import viewer_section


def build_page(results_dir, md_dir, img_dir, root):
    """The text of RESULTS.md from the files in results_dir; md_dir is the folder the page is
    written to (plot links are relative to it), root the repository (the results folder is
    named relative to it)."""
    b = load(os.path.join(results_dir, "bench.json"))
    run = load(os.path.join(results_dir, "run.json")) or {}
    facts = []
    if b:
        simd = b["meta"].get("simd")
        facts += [("CPU", run.get("cpu", b["meta"]["machine"])),
                  ("SIMD, kdgrid", "%s build; one ray at a time outside the packet tables, the "
                   "hybrid's walk in %d-lane "
                   "vectors, its leaves' triangles %s" % (
                       simd["kdgrid"]["isa"], simd["kdgrid"]["lanes"],
                       leaf_lanes_text(simd["kdgrid"])) if simd else "not recorded"),
                  ("SIMD, Embree", "Embree %s, %s kernels (native ray packets of %d)" % (
                      simd["embree"]["version"], simd["embree"]["isa"],
                      simd["embree"]["native_packet"]) if simd else "not recorded"),
                  ("threads used", "%d of %d hardware threads" % (b["meta"]["threads"],
                                                                  b["meta"]["hardware_threads"])),
                  ("date", b["meta"]["date"]),
                  ("primary rays", "%dx%d, one per pixel centre" % (b["meta"]["width"],
                                                                   b["meta"]["height"])),
                  ("repetitions", "%d timed passes per set, median reported" % b["meta"]["reps"])]
    for k in ("commit", "compiler", "kernel", "memory"):
        if k in run:
            facts.append((k, run[k]))
    if "bench_seconds" in run:
        facts.append(("suite wall time", "%.0f s (build + load + all sets, all structures)"
                      % run["bench_seconds"]))
    out = [prose("page", "head", results_dir=os.path.relpath(results_dir, root),
                 machine=table(["", ""], [[k, v] for k, v in facts], ["---", "---"]))]
    if run.get("commands"):
        lines = []
        for c in run["commands"]:
            status = "" if not c.get("exit") else ", exit code %d" % c["exit"]
            if c.get("commit") and c["commit"] != run.get("commit"):
                status += ", at commit %s" % c["commit"]
            lines.append("%s   # %.0f s%s\n" % (c["cmd"], c["seconds"], status))
        out.append(prose("page", "commands", commands="".join(lines)))
    if b:
        out.append(bench_section(b, run, md_dir, img_dir))
    else:
        out.append(prose("page", "no-bench", results_dir=results_dir))
    avx2 = load(os.path.join(results_dir, "bench-avx2.json"))
    if avx2:
        out.append(isa_section(avx2, run))
    out.append(other_cpus_section(results_dir))
    out.append(speed_accuracy_section(results_dir))
    out.append(sweep_section(results_dir, md_dir, img_dir))
    out.append(hybrid_variants_section(results_dir))
    out.append(viewer_section(results_dir))
    out.append(big_scene_section(results_dir, md_dir, img_dir))
    out.append(prose("howto", "howto"))
    return "".join(out)
