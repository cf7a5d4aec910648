"""The 10M-triangle section, from big-scene.json (scripts/big-scene.sh)."""
import os

from .common import g, img, load, mib, table


def big_scene_section(results_dir, md_dir, img_dir):
    """The 10M-triangle run of scripts/big-scene.sh (docs/results/big-scene.json), if any."""
    big = load(os.path.join(results_dir, "big-scene.json"))
    if not big:
        return ""
    meta, runs = big["meta"], big["runs"]
    n = meta["triangles"]
    out = ["\n## A %s-triangle scene (`%s`)\n\n" % ("{:,}".format(n), meta.get("command", ""))]
    out.append(
        "Every structure must build and render a 10-million-triangle generated scene within "
        "memory, or fail fast with a clear message. The scene is "
        "`%s`: an fBm terrain with clusters of spheres and tori and empty sky "
        "(`kdgrid gen landscape --triangles %d` writes it as PLY). Each structure runs in its "
        "own process, `kdgrid render %s --accel X --res %d --spp 1 --stats-json ...`, with the "
        "memory budget %s. Run on %s (%s cores, %s), %s, commit %s.\n\n"
        % (meta["scene"], n, meta["scene"], meta["res"],
           "of %d MiB" % meta["memory_budget_mb"] if meta.get("memory_budget_mb")
           else "at its default (half of physical memory)",
           meta.get("cpu", "?"), meta.get("cores", "?"), meta.get("memory", "?"),
           meta.get("date", "?"), meta.get("commit", "?")))
    if meta.get("ply_bytes"):
        out.append("Writing the scene as binary PLY took %.1f s (%.0f MiB).\n\n"
                   % (meta["ply_write_seconds"], meta["ply_bytes"] / 2**20))
    first = next((r["stats"] for r in runs if r.get("stats")), None)
    if first:
        out.append("The mesh holds %d vertices in %.0f MiB; generating it in the process peaks "
                   "at %.0f MiB resident (libraries included).\n\n"
                   % (first["vertices"], first["mesh_bytes"] / 2**20,
                      first["rss_load_peak_bytes"] / 2**20))
    tight = [r for r in runs if r.get("tag", "").endswith("-tight")]
    runs = [r for r in runs if not r.get("tag", "").endswith("-tight")]
    rows, refusals = [], []
    for r in runs:
        s = r.get("stats")
        label = r["accel"] + ("" if r["res"] == meta["res"] else " (%dx%d)" % (r["res"], r["res"]))
        if s:
            peak = s["rss_build_peak_bytes"] - s["rss_before_build_bytes"]
            mrays = s["rays"] / s["render_seconds"] / 1e6 if s["render_seconds"] > 0 else None
            rows.append([label, "%.1f" % s["build_seconds"], mib(s["bytes"]),
                         mib(s["peak_estimate_bytes"]) if s.get("peak_estimate_bytes") else "-",
                         mib(peak), mib(s["rss_peak_bytes"]),
                         "%.2f" % s["render_seconds"], g(mrays), "renders"])
        else:
            rows.append([label, "-", "-", "-", "-",
                         mib(r["time_max_rss_bytes"]) if r.get("time_max_rss_bytes") else "-",
                         "-", "-", "refused after %.1f s" % r["wall_seconds"]])
            refusals.append((label, r.get("error", "exit code %d" % r["exit"])))
    out.append(table(["structure", "build s", "structure MiB", "estimate MiB", "build peak MiB",
                      "process peak MiB", "render s", "Mrays/s", "outcome"], rows))
    out.append(
        "\n*structure MiB*: what the finished structure holds (`BuildStats::bytes`, mesh "
        "excluded). *estimate MiB*: the peak the memory guard predicted before allocating "
        "(`BuildStats::peak_estimate`; a build refuses when it is above the budget). *build "
        "peak MiB*: growth of the resident set during the build (VmHWM reset before it, minus "
        "the RSS before it), so it includes the build's temporaries and what the allocator "
        "keeps. *process peak MiB*: the whole process at its highest (the mesh, the libraries "
        "and the structure). *render s*: one pass of %dx%d primary and shadow rays "
        "(the renderer's Whitted shading, all threads).\n\n" % (meta["res"], meta["res"]))
    if refusals:
        out.append("Refusals, as the command printed them:\n\n")
        for label, msg in refusals:
            out.append("- **%s**: `%s`\n" % (label, msg))
        out.append("\n")
    if tight:
        mb = tight[0].get("budget_mb", 0)
        out.append("The same scene with `--memory-budget-mb %d`: a structure whose estimate is "
                   "above the budget must refuse before it allocates. *seconds* is the whole "
                   "command, most of it generating the %s triangles in memory (the refusal "
                   "itself comes before any allocation that grows with the scene).\n\n"
                   % (mb, "{:,}".format(n)))
        trows = []
        for r in tight:
            s = r.get("stats")
            if s:
                what = "builds (%s MiB structure, %s MiB estimate) and renders" % (
                    mib(s["bytes"]), mib(s["peak_estimate_bytes"]))
            else:
                what = "`%s`" % r.get("error", "exit code %d" % r["exit"])
            trows.append([r["accel"], "%.1f" % r["wall_seconds"],
                          mib(r["time_max_rss_bytes"]) if r.get("time_max_rss_bytes") else "-",
                          what])
        out.append(table(["structure", "seconds", "process peak MiB", "outcome"], trows,
                         ["---", "---:", "---:", "---"]))
        out.append("\n")
    if os.path.exists(os.path.join(img_dir, "big-scene.png")):
        out.append(img(md_dir, img_dir, "big-scene.png", "the landscape, as rendered above"))
    return "".join(out)
