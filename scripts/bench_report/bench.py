"""The suite's sections (bench.json): the suite, throughput, work per ray, agreement, build."""
from .common import g, img, mib, ordered_unique, rel_to_suite, table


def bench_section(b, run, md_dir, img_dir):
    meta = b["meta"]
    results = b["results"]
    builds = b["builds"]
    scenes = ordered_unique(s["scene"] for s in b["scenes"])
    ok_scenes = [s["scene"] for s in b["scenes"] if s.get("ok", True)]
    accels = ordered_unique(x["accel"] for x in builds)
    sets = meta["sets"]
    res = {(r["scene"], r["accel"], r["set"]): r for r in results}
    bld = {(x["scene"], x["accel"]): x for x in builds}
    ref = ordered_unique(r["reference"] for r in results)
    ref = ref[0] if ref else "embree"
    tris = {s["scene"]: s["triangles"] for s in b["scenes"]}
    rays = {s["scene"]: s.get("rays", {}) for s in b["scenes"]}
    out = []

    out.append("\n## The suite\n\n")
    rows = []
    for s in b["scenes"]:
        rows.append([s["scene"], "`%s`" % rel_to_suite(s.get("file", ""), meta["suite"]),
                     s["triangles"], s.get("camera", ""),
                     " / ".join(str(s.get("rays", {}).get(x, "-")) for x in sets),
                     "ok" if s.get("ok", True) else "**failed**: " + s.get("error", "")])
    out.append(table(["scene", "file", "triangles", "camera", "rays (%s)" % " / ".join(sets),
                      "status"], rows, ["---", "---", "---:", "---", "---:", "---"]))
    out.append("\nShadow and diffuse rays start at the primary hits (found with %s), so those "
               "sets are as large as the number of primary rays that hit. Every structure "
               "traces exactly the same rays.\n" % ref)

    out.append("\n## Throughput relative to %s\n\n" % ref)
    out.append("Ratio of each structure's Mrays/s to %s's on the same rays in the same run: "
               "the median over %d repetitions of (structure / %s timed just before it), %d "
               "threads; higher is better; %s = 1. Mrays/s in brackets is the structure's "
               "median.\n" % (ref, meta["reps"], ref, meta["threads"], ref))
    for st in sets:
        out.append("\n**%s rays** (ratio, and Mrays/s in brackets)\n\n" % st)
        rows = []
        for a in accels:
            row = [a + (" (reference)" if a == ref else "")]
            for s in scenes:
                r = res.get((s, a, st))
                row.append("%s (%s)" % (g(r["ratio_to_reference"]), g(r["mrays"])) if r else "-")
            rows.append(row)
        out.append(table(["structure"] + scenes, rows))
    out.append("\n" + img(md_dir, img_dir, "bench_ratio.png", "throughput ratio to " + ref))
    out.append("\n" + img(md_dir, img_dir, "bench_mrays.png", "throughput in Mrays/s"))

    # Generated observations: best non-reference structure per set, averaged over scenes.
    obs = []
    for st in sets:
        best = None
        for a in accels:
            if a == ref:
                continue
            vals = [res[(s, a, st)]["ratio_to_reference"] for s in ok_scenes if (s, a, st) in res]
            if len(vals) != len(ok_scenes) or not vals:
                continue
            gm = 1.0
            for v in vals:
                gm *= max(v, 1e-12)
            gm **= 1.0 / len(vals)
            if best is None or gm > best[1]:
                best = (a, gm, min(vals), max(vals))
        if best:
            obs.append("- %s rays: fastest besides %s is **%s**, %s x %s on average (geometric "
                       "mean over the scenes; %s to %s)." % (st, ref, best[0], g(best[1]), ref,
                                                           g(best[2]), g(best[3])))
    if obs:
        out.append("\n" + "\n".join(obs) + "\n")

    out.append("\n## Work per ray\n\n")
    out.append("Counted traversal (one extra pass, not timed): traversal steps (nodes or cells "
               "visited), leaves or non-empty cells whose triangles were tested, triangle "
               "tests. %s cannot count.\n\n" % ("Embree" if "embree" in accels else "Some structures"))
    for st in sets:
        rows = []
        for a in accels:
            row = [a]
            for s in scenes:
                r = res.get((s, a, st))
                row.append("%s / %s / %s" % (g(r["steps_per_ray"]), g(r["leaves_per_ray"]),
                                            g(r["tests_per_ray"]))
                           if r and r.get("counted") else "n/a")
            rows.append(row)
        out.append("**%s rays** (steps / leaves / tests per ray)\n\n" % st)
        out.append(table(["structure"] + scenes, rows) + "\n")
    out.append(img(md_dir, img_dir, "bench_counts.png", "steps and tests per ray"))

    out.append("\n## Agreement with %s\n\n" % ref)
    out.append("Fraction of rays whose answer matches %s's: the same triangle, both miss, or a "
               "tie (the structure's triangle, intersected on its own, lies at %s's t within "
               "1e-5 relative: the two sides of a shared edge). Shadow rays: the same occluded "
               "answer. %s's own triangle test differs from kdgrid's watertight test, so rays "
               "grazing a silhouette may legitimately differ.\n\n" % (ref, ref, ref))
    rows = []
    for a in accels:
        if a == ref:
            continue
        for st in sets:
            row = [a, st]
            for s in scenes:
                r = res.get((s, a, st))
                if not r or r.get("agreement") is None:
                    row.append("-")
                else:
                    row.append("%.6f (%d)" % (r["agreement"], r["disagreements"]))
            rows.append(row)
    out.append(table(["structure", "set"] + ["%s (rays differing)" % s for s in scenes], rows,
                     ["---", "---"] + ["---:"] * len(scenes)))

    out.append("\n## Build time and memory\n\n")
    out.append("*Bytes* are `BuildStats::bytes`: the structure's own arrays, **excluding the "
               "mesh** (positions and indices, which every structure shares; structures that "
               "keep their own copy of triangle vertices count it, and `parts` shows it). "
               "*Peak RSS* is the process's resident high-water mark (VmHWM, reset after "
               "`malloc_trim` before the build) while that structure was built and traced: it "
               "includes the mesh, the ray sets and the reference's hits; *growth* is that peak "
               "minus the resident memory just before the build, i.e. what building and "
               "tracing this structure added (build scratch included); `process peak` is "
               "`getrusage` `ru_maxrss` for the whole run.\n\n")
    rows = []
    for s in scenes:
        for a in accels:
            x = bld.get((s, a))
            if not x:
                continue
            if not x.get("ok", True):
                rows.append([s, a, "**failed**: " + x.get("error", "")] + [""] * 7)
                continue
            parts = ", ".join("%s %s" % (k, mib(v)) for k, v in x.get("bytes_by_part", {}).items())
            rows.append([s, a, g(x["build_seconds"]), g(x["build_mtris_per_s"]), mib(x["bytes"]),
                         g(x["bytes_per_triangle"]), mib(x["peak_rss_bytes"]),
                         mib(x.get("rss_growth_bytes", 0)), mib(x["process_peak_rss_bytes"]),
                         parts])
    out.append(table(["scene", "structure", "build s", "build Mtris/s", "MiB", "bytes/tri",
                      "peak RSS MiB", "growth MiB", "process peak MiB", "parts (MiB)"], rows,
                     ["---", "---"] + ["---:"] * 7 + ["---"]))
    out.append("\n" + img(md_dir, img_dir, "bench_build.png", "build time and memory"))
    extras = [(s, a, bld[(s, a)].get("extra", {})) for s in scenes for a in accels
              if (s, a) in bld and bld[(s, a)].get("extra")]
    if extras:
        out.append("\nWhat the structures report about themselves (`BuildStats::extra`):\n\n")
        rows = [[s, a, "; ".join("%s: %s" % kv for kv in e.items())] for s, a, e in extras]
        out.append(table(["scene", "structure", "facts"], rows, ["---", "---", "---"]))
    if b.get("errors"):
        out.append("\n## Errors\n\n")
        for e in b["errors"]:
            out.append("- %s%s: %s\n" % (e.get("scene", ""), " / " + e["accel"] if "accel" in e
                                         else "", e["error"]))
    return "".join(out)
