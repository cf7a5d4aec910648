"""The Viewer section, from viewer.json (scripts/viewer-bench.sh)."""
import os

from .common import g, load, mib, ordered_unique, table


def median(xs):
    xs = sorted(xs)
    if not xs:
        return None
    n = len(xs)
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def load_text(run):
    la = run.get("loadavg_1min")
    return "%s / %s" % (g(la[0], 2), g(la[1], 2)) if la else "-"


def viewer_section(results_dir):
    """The interactive viewer's figures, from viewer.json (scripts/viewer-bench.sh)."""
    out = ["\n## Viewer\n\n"]
    v = load(os.path.join(results_dir, "viewer.json"))
    if not v:
        out.append("*Not measured: there is no viewer.json in %s. Run `scripts/viewer-bench.sh` "
                   "(it needs the viewer built and Xvfb) to measure the viewer and regenerate "
                   "this page.*\n" % results_dir)
        return "".join(out)
    m = v.get("meta", {})
    runs = v.get("runs", [])
    gl = ordered_unique(r["stats"]["display"].get("gl_renderer", "?") for r in runs if "stats" in r)
    out.append("Measured by `scripts/viewer-bench.sh` on %s (%s, %s hardware threads, commit %s): "
               "`kdgrid-viewer` in its scripted mode, which runs the same UI loop, render worker "
               "and background builds as an interactive run, writing every frame, pass and "
               "build to `--stats-json`.\n\n" % (m.get("date", "?"), m.get("cpu", "?"),
                                                  m.get("cores", "?"), m.get("commit", "?")))
    disp = ordered_unique("%dx%d window, %dx%d framebuffer, content scale %s, panels %s" % (
        tuple(r["stats"]["display"]["window"]) + tuple(r["stats"]["display"]["framebuffer"]) +
        (g(r["stats"]["display"]["content_scale"][0]),
         "shown" if r["stats"]["display"].get("panel") else "hidden"))
        for r in runs if "stats" in r)
    out.append("**Display: Xvfb with Mesa's software OpenGL** (%s), no GPU. Colouring the image, "
               "the texture upload and drawing the image and the panels all run on the CPU, on "
               "the same cores as the render threads, so the upload and UI figures include "
               "llvmpipe's work and are pessimistic for a desktop with a GPU; the pass times "
               "and Mrays/s are the ray tracer's own. %s; the UI loop is capped at 60 frames "
               "per second as vsync would cap it, and draws only when something changed.\n\n"
               % (", ".join("`%s`" % x for x in gl), "; ".join(disp).capitalize()))

    rows = []
    for r in runs:
        st = r.get("stats")
        if not st or not st.get("passes"):
            continue
        if "rebuild" in r["name"]:
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
        out.append("**Progressive rendering.** A *pass* adds one sample per pixel (with shadow "
                   "rays to the lights, and reflection/refraction rays where materials ask for "
                   "them) over the whole image: it is the time between two refinements of the "
                   "picture. Mrays/s counts every ray of a pass over the pass's wall time. The "
                   "*UI* figures are the UI thread's, over the whole run: it draws a frame when "
                   "something changed (a finished pass, input, a build's progress bar at 10 Hz; "
                   "at most 60 per second) and otherwise sleeps, so *UI frames/s* follows the "
                   "passes; *UI work* is the median time per frame (events, hand-over, upload, "
                   "panels, drawing, swap; in brackets the swap alone, where llvmpipe "
                   "rasterises the frame); *UI busy* is the share of the run's wall time the UI "
                   "thread spent in that work, i.e. what it took from the render threads. "
                   "*Colour + upload* is the CPU time to turn a new pass into sRGB bytes and to "
                   "hand them to GL. Pass figures are the median over the passes of the final "
                   "view (min-max in brackets). *Load* is the machine's 1-minute load average "
                   "before / after the run: above the thread count, other processes were "
                   "competing for the cores and every time here is inflated.\n\n")
        out.append(table(["scene", "triangles", "structure", "image", "threads", "passes",
                          "pass ms", "Mrays/s", "rays per pass (primary / shadow / other)",
                          "UI frames/s", "UI work ms (swap)", "UI busy", "colour + upload ms", "load"],
                         rows, ["---", "---:", "---", "---", "---:", "---:", "---:", "---:", "---:",
                                "---:", "---:", "---:", "---:", "---:"]))
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
        out.append("\n**Live rebuild.** The viewer rebuilds the structure off the UI thread and "
                   "swaps it in when it is ready; the old one renders meanwhile. *build s* is "
                   "`build()` alone, *wall s* from the request to the result being ready (thread "
                   "start-up and queueing included). The render threads had finished their "
                   "single pass, so the build shared the %d threads only with the UI thread, "
                   "which redraws the progress bar 10 times a second. The start-up load "
                   "(parsing the file and the first build) is shown for comparison.\n\n"
                   % m.get("threads", 0))
        out.append(table(["run", "scene", "triangles", "structure", "cell size", "build s", "wall s",
                          "MiB", "start-up load + build s", "load"], rows,
                         ["---", "---", "---:", "---", "---:", "---:", "---:", "---:", "---:", "---:"]))
        secs = [float(x[5]) for x in rows if x[5] not in ("", "-")]
        if len(secs) > 1:
            out.append("\nMedian rebuild over the %d runs: **%s s** (%s to %s).\n"
                       % (len(secs), g(median(secs)), g(min(secs)), g(max(secs))))
    failed = [r for r in runs if r.get("exit") or "stats" not in r]
    for r in failed:
        out.append("\n- `%s` exited with code %s%s.\n" % (r["command"], r.get("exit"),
                                                         "" if "stats" in r else " and wrote no statistics"))
    out.append("\nCommands (each under `xvfb-run -a -s \"-screen 0 1920x1080x24\"`, "
               "`LIBGL_ALWAYS_SOFTWARE=1`):\n\n```sh\n")
    for r in runs:
        out.append(r["command"] + "\n")
    out.append("```\n")
    return "".join(out)
