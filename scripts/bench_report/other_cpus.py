"""The hybrid against Embree on other CPUs, from docs/results/cpus/NAME/ (scripts/bench-cpu.sh):
one table per CPU, each cell the range of the hybrid's ratio to Embree over the runs."""
import os
import re

from .common import load, ordered_unique, prose, table

# The builds bench-cpu.sh runs, in the order the tables show them.
BUILDS = ("avx512", "avx2")
RUN_FILE = re.compile(r"^(avx512|avx2)\.([0-9]+)\.json$")


def ratio_range(vals):
    """'lo-hi' over the runs to two decimals ('x' when they round alike), '-' without a value."""
    vals = [v for v in vals if v is not None]
    if not vals:
        return "-"
    lo, hi = "%.2f" % min(vals), "%.2f" % max(vals)
    return lo if lo == hi else "%s-%s" % (lo, hi)


def load_runs(folder):
    """{build: [bench.json, ...]} in run order, from FOLDER's avx512.N.json and avx2.N.json."""
    found = {}
    for f in os.listdir(folder):
        m = RUN_FILE.match(f)
        if m:
            b = load(os.path.join(folder, f))
            if b:
                found.setdefault(m.group(1), []).append((int(m.group(2)), b))
    return {k: [b for _, b in sorted(v, key=lambda x: x[0])] for k, v in found.items()}


def hybrid_result(b, scene, st):
    for r in b["results"]:
        if r["scene"] == scene and r["set"] == st and r["accel"] == "hybrid":
            return r
    return None


def build_rows(runs, scenes):
    """The rows of one build's runs: single rays by set, packets, the render, bytes a triangle."""
    meta = runs[0]["meta"]
    simd = meta.get("simd") or {}
    k, e = simd.get("kdgrid", {}), simd.get("embree", {})
    packet = e.get("native_packet", 0)
    tile = meta.get("packet_tile", 0)
    rows = [["**%s build (groups of %s), Embree's %s kernels**" % (
        k.get("isa", "?"), k.get("leaf_lanes", "?"), e.get("isa", "?"))] + [""] * len(scenes)]

    def row(label, value):
        rows.append([label] + [ratio_range(value(b, s) for b in runs) for s in scenes])

    def single(st):
        return lambda b, s: (hybrid_result(b, s, st) or {}).get("ratio_to_reference")

    def packets(st):
        return lambda b, s: ((hybrid_result(b, s, st) or {}).get("packet") or {}).get(
            "ratio_to_reference")

    def render(b, s):
        for x in b.get("renders", []):
            if x["scene"] == s and x["accel"] == "hybrid":
                return x.get("ratio_to_reference")
        return None

    def bytes_ratio(b, s):
        got = {x["accel"]: x.get("bytes_per_triangle") for x in b["builds"] if x["scene"] == s}
        h, r = got.get("hybrid"), got.get("embree")
        return h / r if h is not None and r else None

    for st in meta["sets"]:
        row("%s rays" % st, single(st))
    for st, call in (("primary", "rtcIntersect"), ("shadow", "rtcOccluded")):
        if st not in meta["sets"] or not tile:
            continue
        # A tile's rays, and how many of them the hybrid's packet walk holds at once.
        widths = ordered_unique(r["packet"]["packet_width"] for b in runs for r in b["results"]
                                if r["accel"] == "hybrid" and r["set"] == st and "packet" in r)
        walked = "" if widths in ([], [tile * tile]) else ", walked %s at a time" % " or ".join(
            "%d" % w for w in widths)
        row("%s packets (%d rays%s) / `%s%d`" % (st, tile * tile, walked, call, packet),
            packets(st))
    if any(b.get("renders") for b in runs):
        row("the whole render", render)
    row("bytes a triangle, hybrid / Embree", bytes_ratio)
    return rows


def cpu_table(name, cpu, by_build):
    """One CPU's table and the facts above it."""
    first = by_build[[b for b in BUILDS if b in by_build][0]][0]
    scenes = ordered_unique(s["scene"] for s in first["scenes"])
    rows = []
    for build in BUILDS:
        if build in by_build:
            rows += build_rows(by_build[build], scenes)
    meta = first["meta"]
    commands = "".join("%s\n" % c for c in cpu.get("commands", []))
    return prose("other_cpus", "cpu", name=name, cpu=cpu.get("model_name", "unknown"),
                 vendor=cpu.get("vendor", "?"), family="%s" % cpu.get("family", "?"),
                 model="%s" % cpu.get("model", "?"),
                 avx512="with AVX-512" if cpu.get("avx512") else "without AVX-512",
                 caches="L2 %s, L3 %s" % (cpu.get("l2", "?"), cpu.get("l3", "?")),
                 threads="%d" % meta["threads"], reps="%d" % meta["reps"],
                 runs="%d" % min(len(v) for v in by_build.values()),
                 commit=cpu.get("commit", "?"), date=meta.get("date", "?"),
                 commands=commands,
                 table=table(["hybrid / Embree"] + scenes, rows,
                             ["---"] + ["---:"] * len(scenes)))


def other_cpus_section(results_dir):
    """Every docs/results/cpus/NAME/ folder that holds runs, by name; nothing without one."""
    top = os.path.join(results_dir, "cpus")
    if not os.path.isdir(top):
        return prose("other_cpus", "not-measured")
    parts = []
    for name in sorted(os.listdir(top)):
        folder = os.path.join(top, name)
        # bench-cpu.sh's runs in progress (or cut short) are in a hidden folder.
        if name.startswith(".") or not os.path.isdir(folder):
            continue
        by_build = load_runs(folder)
        if by_build:
            parts.append(cpu_table(name, load(os.path.join(folder, "cpu.json")) or {}, by_build))
    if not parts:
        return prose("other_cpus", "not-measured")
    return prose("other_cpus", "section", cpus="".join(parts))
