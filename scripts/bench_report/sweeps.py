"""The Sweeps section: cell size, grid density, kd cost, triangle test, samples per pixel."""
import os

from .common import g, img, load, mib, ordered_unique, prose, table


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
    # The columns of each parameter sweep's table and their headings; the prose is the block
    # of templates/sweeps.md named after the kind.
    param = [("cellsize",
              ["label", "cell_size", "grid", "build_s", "bytes", "mrays", "ratio_to_embree",
               "steps_per_ray", "leaves_per_ray", "tests_per_ray", "sah_cost"],
              ["cell", "size", "lattice", "build s", "MiB", "Mrays/s", "x embree", "steps/ray",
               "leaves/ray", "tests/ray", "SAH cost"]),
             ("lambda",
              ["lambda", "resolution", "build_s", "bytes", "mrays", "ratio_to_embree",
               "steps_per_ray", "tests_per_ray"],
              ["lambda", "resolution", "build s", "MiB", "Mrays/s", "x embree", "steps/ray",
               "tests/ray"]),
             ("kdcost",
              ["cost_ratio", "build_s", "bytes", "mrays", "ratio_to_embree", "steps_per_ray",
               "leaves_per_ray", "tests_per_ray", "nodes"],
              ["K_I/K_T", "build s", "MiB", "Mrays/s", "x embree", "steps/ray", "leaves/ray",
               "tests/ray", "nodes"])]
    for kind, cols, heads in param:
        sw = load(os.path.join(results_dir, "sweep-%s.json" % kind))
        if not sw:
            continue
        m = sw["meta"]
        n = m.get("notes", {})
        fields = dict(scene=os.path.basename(m["scene"]), triangles=n.get("triangles", "?"),
                      rays=n.get("rays", ""), reps="%d" % m["reps"], threads="%d" % m["threads"],
                      embree=prose("sweeps", "embree", mrays=g(float(n["embree_mrays"])))
                      if "embree_mrays" in n else "",
                      table=sweep_table(sw, cols, heads),
                      plot=img(md_dir, img_dir, "sweep_%s.png" % kind, kind + " sweep"))
        if kind == "cellsize":
            fields["auto"] = (prose("sweeps", "auto", size=n.get("auto_cell_size"),
                                    rule=n["auto_rule"]) if "auto_rule" in n else "")
        out.append(prose("sweeps", kind, **fields))

    sw = load(os.path.join(results_dir, "sweep-triangle.json"))
    if sw:
        thr = [r for r in sw["rows"] if r.get("part") == "throughput"]
        leak = [r for r in sw["rows"] if r.get("part") == "leak"]
        throughput = leaks = ""
        if thr:
            rows = [[r["accel"], r["test"], g(r.get("mrays")), g(r.get("tests_per_ray")),
                     g(r.get("speedup_vs_watertight")), g(r.get("ratio_to_embree"))]
                    for r in thr if "error" not in r]
            throughput = prose("sweeps", "triangle-throughput", rays=g(thr[0].get("rays")),
                               mesh=thr[0]["mesh"], table=table(
                                   ["structure", "test", "Mrays/s", "tests/ray",
                                    "speed vs watertight", "x embree"], rows,
                                   ["---", "---", "---:", "---:", "---:", "---:"]))
        if leak:
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
            leaks = prose("sweeps", "triangle-leaks", table=table(
                ["structure", "test"] + ["%s x%s" % gk for gk in groups], rows,
                ["---", "---"] + ["---:"] * len(groups)))
        out.append(prose("sweeps", "triangle", throughput=throughput, leaks=leaks,
                         plot=img(md_dir, img_dir, "sweep_triangle.png", "triangle test sweep")))

    sw = load(os.path.join(results_dir, "sweep-spp.json"))
    if sw:
        m = sw["meta"]
        n = m.get("notes", {})
        out.append(prose(
            "sweeps", "spp", reference=n.get("reference", "high-spp"),
            scene=os.path.basename(m["scene"]), width="%d" % m["width"], height="%d" % m["height"],
            accel=n.get("accel", ""),
            table=sweep_table(sw, ["spp", "seconds", "rmse", "rmse_display", "mrays"],
                              ["spp", "seconds", "linear RMSE", "display RMSE", "Mrays/s"]),
            plot=img(md_dir, img_dir, "sweep_spp.png", "spp sweep")))
    if not out:
        return ""
    return prose("sweeps", "section", sweeps="".join(out))
