"""The Viewer section, from viewer.json (scripts/viewer-bench.sh)."""
import os

from .common import g, load, mib, ordered_unique, prose, table


def median(xs):
    xs = sorted(xs)
    if not xs:
        return None
    n = len(xs)
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def load_text(run):
    la = run.get("loadavg_1min")
    return "%s / %s" % (g(la[0], 2), g(la[1], 2)) if la else "-"


def ui_frames(runs):
    """The UI thread's frames on the full dragon, one row per overlay (dragon-ui-* runs)."""
    rows = []
    for r in runs:
        st = r.get("stats")
        if not st or not r["name"].startswith("dragon-ui-"):
            continue
        fr = st["frames"]
        ui = fr.get("ui_ms_summary", {})
        phases = fr.get("phases", {})
        # The swap is not in UI ms (llvmpipe rasterises there); the phases of the work are.
        work = [kv for kv in phases.items() if kv[0] != "swap"]
        top = sorted(work, key=lambda kv: -kv[1]["max_ms"])[:2]
        rows.append([r["name"][len("dragon-ui-"):], fr["count"], g(ui.get("p50")), g(ui.get("p95")),
                     "**%s**" % g(ui.get("max")),
                     ", ".join("%s %s (frame %d)" % (k, g(v["max_ms"]), v["frame"]) for k, v in top),
                     load_text(r)])
    if not rows:
        return ""
    return prose("viewer", "frames", table=table(
        ["overlay", "frames", "UI ms median", "95th percentile", "largest", "largest phases",
         "load"], rows, ["---", "---:", "---:", "---:", "---:", "---", "---:"]))


def viewer_section(results_dir):
    """The interactive viewer's figures, from viewer.json (scripts/viewer-bench.sh)."""
    v = load(os.path.join(results_dir, "viewer.json"))
    if not v:
        return prose("viewer", "not-measured", results_dir=results_dir)
    m = v.get("meta", {})
    runs = v.get("runs", [])
    gl = ordered_unique(r["stats"]["display"].get("gl_renderer", "?") for r in runs if "stats" in r)
    disp = ordered_unique("%dx%d window, %dx%d framebuffer, content scale %s, panels %s" % (
        tuple(r["stats"]["display"]["window"]) + tuple(r["stats"]["display"]["framebuffer"]) +
        (g(r["stats"]["display"]["content_scale"][0]),
         "shown" if r["stats"]["display"].get("panel") else "hidden"))
        for r in runs if "stats" in r)
    fields = dict(date=m.get("date", "?"), cpu=m.get("cpu", "?"), cores=m.get("cores", "?"),
                  commit=m.get("commit", "?"), renderers=", ".join("`%s`" % x for x in gl),
                  display="; ".join(disp).capitalize(), progressive="", rebuild="", frames="")

    rows = []
    for r in runs:
        st = r.get("stats")
        if not st or not st.get("passes"):
            continue
        if "rebuild" in r["name"] or r["name"].startswith("dragon-ui-"):
            continue
        s = st["state"]
        job = st["passes"][-1]["job"]
        ps = [p for p in st["passes"] if p["job"] == job]
        ms = [1e3 * p["seconds"] for p in ps]
        mr = [p["mrays"] for p in ps]
        prim = median([p["primary"] for p in ps])
        shad = median([p["shadow"] for p in ps])
        other = median([p["reflection"] + p["refraction"] for p in ps])
        fr = st["frames"]
        rows.append([r["name"], s.get("triangles", "-"), s.get("accel", "-"),
                     "%dx%d" % tuple(st["display"]["image"]), st["settings"]["threads"], len(ps),
                     "%s (%s-%s)" % (g(median(ms)), g(min(ms)), g(max(ms))),
                     "%s (%s-%s)" % (g(median(mr)), g(min(mr)), g(max(mr))),
                     "%s / %s / %s" % (g(prim), g(shad), g(other)),
                     g(1e3 * len(fr["interval_ms"]) / max(sum(fr["interval_ms"]), 1e-9)),
                     "%s (%s)" % (g(median(fr["work_ms"])), g(median(fr.get("swap_ms", [])))),
                     "%.0f%%" % (100.0 * sum(fr["work_ms"]) / max(sum(fr["interval_ms"]), 1e-9)),
                     "%s + %s" % (g(median(st.get("colorize_ms", []))),
                                  g(median(st.get("upload_ms", [])))),
                     load_text(r)])
    if rows:
        fields["progressive"] = prose("viewer", "progressive", table=table(
            ["scene", "triangles", "structure", "image", "threads", "passes", "pass ms",
             "Mrays/s", "rays per pass (primary / shadow / other)", "UI frames/s",
             "UI work ms (swap)", "UI busy", "colour + upload ms", "load"],
            rows, ["---", "---:", "---", "---", "---:", "---:", "---:", "---:", "---:", "---:",
                   "---:", "---:", "---:", "---:"]))
    rows = []
    for r in runs:
        st = r.get("stats")
        if not st:
            continue
        for b in st.get("builds", []):
            if b.get("kind") != "rebuild":
                continue
            if "error" in b:
                rows.append([r["name"], os.path.basename(b.get("scene", "")), "", b.get("accel", "-"),
                             "**failed**: " + b["error"]] + [""] * 5)
                continue
            ex = b.get("stats", {}).get("extra", {})
            first = next((x for x in st["builds"] if x.get("kind") == "load" and "error" not in x), None)
            rows.append([r["name"], os.path.basename(b["scene"]), st["state"].get("triangles", "-"),
                         b["accel"],
                         ex.get("cell_size", "auto") + (" (auto)" if b.get("requested_cell_size", 0) == 0 else ""),
                         g(b["build_seconds"]), g(b["wall_seconds"]),
                         mib(b["stats"]["bytes"]),
                         g(first["wall_seconds"]) if first else "-", load_text(r)])
    if rows:
        secs = [float(x[5]) for x in rows if x[5] not in ("", "-")]
        fields["rebuild"] = prose(
            "viewer", "rebuild", threads="%d" % m.get("threads", 0),
            table=table(["run", "scene", "triangles", "structure", "cell size", "build s",
                         "wall s", "MiB", "start-up load + build s", "load"], rows,
                        ["---", "---", "---:", "---", "---:", "---:", "---:", "---:", "---:",
                         "---:"]),
            median=prose("viewer", "median", runs=len(secs), median=g(median(secs)),
                         lo=g(min(secs)), hi=g(max(secs))) if len(secs) > 1 else "")
    fields["frames"] = ui_frames(runs)
    failed = [r for r in runs if r.get("exit") or "stats" not in r]
    fields["failed"] = "".join(
        prose("viewer", "failed", command=r["command"], code=r.get("exit"),
              no_stats="" if "stats" in r else prose("viewer", "no-stats")) for r in failed)
    fields["commands"] = "".join(r["command"] + "\n" for r in runs)
    return prose("viewer", "section", **fields)
