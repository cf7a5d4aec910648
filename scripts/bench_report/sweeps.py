"""The Sweeps section: cell size, grid density, kd cost, triangle test, samples per pixel."""
import os

from .common import g, img, load, mib, ordered_unique, table


def sweep_table(sw, cols, heads=None):
    rows = []
    for r in sw["rows"]:
        if "error" in r:
            rows.append([r.get(cols[0], "")] + ["**failed**: " + r["error"]] +
                        [""] * (len(cols) - 2))
            continue
        row = []
        for c in cols:
            v = r.get(c)
            if c == "bytes" and v is not None:
                row.append(mib(v))
            else:
                row.append(g(v) if not isinstance(v, str) else v)
        rows.append(row)
    return table(heads or cols, rows)


def sweep_section(results_dir, md_dir, img_dir):
    out = []
    param = [("cellsize", "Hybrid cell size",
              "The hybrid's basic cell size as a multiple of its automatic size (the `auto` row). "
              "A finer lattice gives the SAH more candidate planes and tighter leaves but a "
              "larger cell matrix and a slower build.",
              ["label", "cell_size", "grid", "build_s", "bytes", "mrays", "ratio_to_embree",
               "steps_per_ray", "leaves_per_ray", "tests_per_ray", "sah_cost"],
              ["cell", "size", "lattice", "build s", "MiB", "Mrays/s", "x embree", "steps/ray",
               "leaves/ray", "tests/ray", "SAH cost"]),
             ("lambda", "Uniform grid density",
              "Cells per triangle (lambda) of the uniform grid: more cells mean fewer triangle "
              "tests but more steps and memory.",
              ["lambda", "resolution", "build_s", "bytes", "mrays", "ratio_to_embree",
               "steps_per_ray", "tests_per_ray"],
              ["lambda", "resolution", "build s", "MiB", "Mrays/s", "x embree", "steps/ray",
               "tests/ray"]),
             ("kdcost", "kd-tree cost ratio",
              "SAH intersection cost relative to one traversal step: a higher ratio makes the "
              "builder split further, trading steps and memory for triangle tests.",
              ["cost_ratio", "build_s", "bytes", "mrays", "ratio_to_embree", "steps_per_ray",
               "leaves_per_ray", "tests_per_ray", "nodes"],
              ["K_I/K_T", "build s", "MiB", "Mrays/s", "x embree", "steps/ray", "leaves/ray",
               "tests/ray", "nodes"])]
    for kind, title, text, cols, heads in param:
        sw = load(os.path.join(results_dir, "sweep-%s.json" % kind))
        if not sw:
            continue
        m = sw["meta"]
        n = m.get("notes", {})
        out.append("\n### %s (`sweep %s`)\n\n%s Scene `%s` (%s triangles), %s, median of %d, "
                   "%d threads.%s\n\n" % (
                       title, kind, text, os.path.basename(m["scene"]), n.get("triangles", "?"),
                       n.get("rays", ""), m["reps"], m["threads"],
                       (" Embree on the same rays: %s Mrays/s." % g(float(n["embree_mrays"])))
                       if "embree_mrays" in n else ""))
        if kind == "cellsize" and "auto_rule" in n:
            out.append("Auto cell size %s (%s).\n\n" % (n.get("auto_cell_size"), n["auto_rule"]))
        out.append(sweep_table(sw, cols, heads))
        out.append("\n" + img(md_dir, img_dir, "sweep_%s.png" % kind, kind + " sweep"))

    sw = load(os.path.join(results_dir, "sweep-triangle.json"))
    if sw:
        out.append("\n### Watertight vs Möller-Trumbore (`sweep triangle`)\n\n")
        thr = [r for r in sw["rows"] if r.get("part") == "throughput"]
        leak = [r for r in sw["rows"] if r.get("part") == "leak"]
        if thr:
            out.append("Primary-ray speed with each triangle test (%s rays of `%s`):\n\n"
                       % (g(thr[0].get("rays")), thr[0]["mesh"]))
            rows = [[r["accel"], r["test"], g(r.get("mrays")), g(r.get("tests_per_ray")),
                     g(r.get("speedup_vs_watertight")), g(r.get("ratio_to_embree"))]
                    for r in thr if "error" not in r]
            out.append(table(["structure", "test", "Mrays/s", "tests/ray",
                              "speed vs watertight", "x embree"], rows,
                             ["---", "---", "---:", "---:", "---:", "---:"]))
        if leak:
            out.append("\nLeaks: rays aimed from outside exactly at points on shared edges (at "
                       "1/4, 1/2, 3/4) and at vertices of closed meshes (an icosphere of 1280 "
                       "triangles and a torus of 2304), from directions on the outer side of "
                       "every adjacent face, ending just past the target. A ray that hits "
                       "nothing has slipped between triangles. `brute` isolates the triangle "
                       "test; the other rows add each structure's traversal.\n\n")
            groups = ordered_unique((r["mesh"], r["scale"]) for r in leak)
            accels = ordered_unique(r["accel"] for r in leak)
            tests = ordered_unique(r["test"] for r in leak)
            rows = []
            for a in accels:
                for t in tests:
                    row = [a, t]
                    for gk in groups:
                        r = next((x for x in leak if x["accel"] == a and x["test"] == t and
                                  (x["mesh"], x["scale"]) == gk), None)
                        if r is None or "error" in r:
                            row.append("-")
                        else:
                            row.append("%d / %d" % (r["leaks"], r["rays"]))
                    rows.append(row)
            out.append(table(["structure", "test"] + ["%s x%s" % gk for gk in groups], rows,
                             ["---", "---"] + ["---:"] * len(groups)))
        out.append("\n" + img(md_dir, img_dir, "sweep_triangle.png", "triangle test sweep"))

    sw = load(os.path.join(results_dir, "sweep-spp.json"))
    if sw:
        m = sw["meta"]
        n = m.get("notes", {})
        out.append("\n### Progressive rendering (`sweep spp`)\n\nSamples per pixel against the "
                   "RMSE from a %s reference and render time, `%s` at %dx%d with %s. "
                   "`rmse_display` clamps both images to [0, 1] first (the emissive panel is "
                   "far brighter than 1 and dominates the linear RMSE).\n\n" % (
                       n.get("reference", "high-spp"), os.path.basename(m["scene"]), m["width"],
                       m["height"], n.get("accel", "")))
        out.append(sweep_table(sw, ["spp", "seconds", "rmse", "rmse_display", "mrays"],
                               ["spp", "seconds", "linear RMSE", "display RMSE", "Mrays/s"]))
        out.append("\n" + img(md_dir, img_dir, "sweep_spp.png", "spp sweep"))
    if not out:
        return ""
    return "\n## Sweeps\n\n" + "".join(out)
