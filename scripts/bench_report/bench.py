"""The suite's sections (bench.json): the suite, throughput, work per ray, agreement, build."""
from .common import g, img, mib, ordered_unique, prose, rel_to_suite, table


def simd_text(meta):
    """The SIMD each side used, from bench.json's meta.simd (kdgrid bench records it)."""
    simd = meta.get("simd")
    if not simd:
        return "SIMD: not recorded in this bench.json."
    k, e = simd["kdgrid"], simd["embree"]
    return prose("bench", "simd", kdgrid_isa=k["isa"], kdgrid_lanes="%d" % k["lanes"],
                 kdgrid_leaves=leaf_lanes_text(k),
                 embree_version=e["version"], embree_isa=e["isa"],
                 embree_packet="%d" % e["native_packet"])


def leaf_lanes_text(k):
    """How many triangles a hybrid leaf tests at once (bench.json files from builds before the
    leaves held triangle groups have no leaf_lanes: one at a time)."""
    n = k.get("leaf_lanes", 1)
    return "one at a time" if n == 1 else "%d at a time" % n


def structure_rows(accels, scenes, st, res, name, ref, cell):
    """One row per structure (the reference marked), one cell per scene: cell(result or None)."""
    return [[name[a] + (" (reference)" if a == ref else "")] +
            [cell(res.get((s, a, st))) for s in scenes] for a in accels]


def labels(builds):
    """Row labels: the structure's name, and for Embree's configurations the scene flags and
    build quality its builds report (BuildStats::extra)."""
    out = {}
    for x in builds:
        ex = x.get("extra") or {}
        if x["accel"] not in out or "flags" in ex:
            out[x["accel"]] = x["accel"] + (" (%s flags, %s quality)" % (ex["flags"], ex["quality"])
                                            if x["accel"].startswith("embree") and "flags" in ex
                                            and "quality" in ex else "")
    return out


def geomean_of(vals):
    gm = 1.0
    for v in vals:
        gm *= max(v, 1e-12)
    return gm ** (1.0 / len(vals))


def packets_section(b, res, scenes, accels, name, ref, setup, level="##"):
    """kdgrid bench's packet column (results[].packet), or nothing for a bench.json without one;
    `level` is its heading's level."""
    meta = b["meta"]
    sets = [st for st in meta["sets"]
            if any("packet" in res.get((s, a, st), {}) for s in scenes for a in accels)]
    if not sets:
        return ""
    tables = []
    for st in sets:
        def cell(r):
            p = (r or {}).get("packet")
            return "%s (%s; x%s; %d)" % (
                g(p["ratio_to_reference"]), g(p["mrays"]), g(p["speedup_over_single_loop"]),
                p["packet_width"]) if p else "-"
        rows = structure_rows(accels, scenes, st, res, name, ref, cell)
        tables.append(prose("bench", "packets-set", set=st, ref=ref,
                            table=table(["structure"] + scenes, rows)))
    tile = meta.get("packet_tile", 0)
    simd = meta.get("simd") or {}
    return prose("bench", "packets", heading=level + " Packets", ref=ref, tile="%d" % tile,
                 rays="%d" % (tile * tile),
                 embree_packet="%d" % simd.get("embree", {}).get("native_packet", 0),
                 setup=setup, tables="".join(tables))


def renders_section(b, scenes, accels, name, ref, setup, level="##"):
    """kdgrid bench's render column (renders[]), or nothing for a bench.json without one;
    `level` is its heading's level."""
    rnd = {(x["scene"], x["accel"]): x for x in b.get("renders", [])}
    if not rnd:
        return ""

    def cell(x):
        if not x:
            return "-"
        differ = x.get("pixels_differ")
        return "%s (%s s; %s)" % (g(x["ratio_to_reference"]), g(x["seconds"]),
                                  "-" if differ is None else "%d px differ" % differ)
    rows = [[name[a] + (" (reference)" if a == ref else "")] +
            [cell(rnd.get((s, a))) for s in scenes] for a in accels
            if any((s, a) in rnd for s in scenes)]
    rays = ["%s: %s" % (s, " / ".join(str(rnd[(s, ref)]["rays"][k]) for k in (
        "primary", "shadow", "reflection", "refraction"))) for s in scenes if (s, ref) in rnd]
    meta = b["meta"]
    return prose("bench", "renders", heading=level + " The whole render", ref=ref,
                 width="%d" % meta.get("width", 0),
                 height="%d" % meta.get("height", 0), reps="%d" % meta["reps"], setup=setup,
                 rays="; ".join(rays), table=table(["structure"] + scenes, rows))


class Suite:
    """What the sections read from one bench.json: its scenes, structures, sets, results by
    (scene, structure, set), the reference, the rows' labels and the set-up line."""

    def __init__(self, b, run):
        self.b = b
        self.meta = b["meta"]
        self.scenes = ordered_unique(s["scene"] for s in b["scenes"])
        self.ok_scenes = [s["scene"] for s in b["scenes"] if s.get("ok", True)]
        self.accels = ordered_unique(x["accel"] for x in b["builds"])
        self.sets = self.meta["sets"]
        self.res = {(r["scene"], r["accel"], r["set"]): r for r in b["results"]}
        self.bld = {(x["scene"], x["accel"]): x for x in b["builds"]}
        ref = ordered_unique(r["reference"] for r in b["results"])
        self.ref = ref[0] if ref else "embree"
        self.name = labels(b["builds"])
        self.setup = prose("bench", "setup", cpu=run.get("cpu", self.meta["machine"]),
                           threads="%d" % self.meta["threads"], simd=simd_text(self.meta))

    def throughput_tables(self):
        """One table a set: each structure's ratio to the reference and its Mrays/s."""
        tables = []
        for st in self.sets:
            rows = structure_rows(self.accels, self.scenes, st, self.res, self.name, self.ref,
                                  lambda r: "%s (%s)" % (g(r["ratio_to_reference"]), g(r["mrays"]))
                                  if r else "-")
            tables.append(prose("bench", "throughput-set", set=st,
                                table=table(["structure"] + self.scenes, rows)))
        return "".join(tables)

    def bytes_table(self):
        """Bytes a triangle of each structure's build on each scene (BuildStats::bytes)."""
        rows = []
        for a in self.accels:
            rows.append([self.name[a]] + [
                "%.0f" % self.bld[(s, a)]["bytes_per_triangle"]
                if self.bld.get((s, a), {}).get("bytes_per_triangle") is not None else "-"
                for s in self.scenes])
        return table(["structure"] + self.scenes, rows)

    def observations(self):
        """Generated observations: the best non-reference structure per set, and the hybrid,
        averaged over the scenes."""
        obs = []
        ref, res, name, ok_scenes = self.ref, self.res, self.name, self.ok_scenes
        for st in self.sets:
            best = hybrid = None
            for a in self.accels:
                if a == ref:
                    continue
                vals = [res[(s, a, st)]["ratio_to_reference"] for s in ok_scenes
                        if (s, a, st) in res]
                if len(vals) != len(ok_scenes) or not vals:
                    continue
                gm = geomean_of(vals)
                if best is None or gm > best[1]:
                    best = (a, gm, min(vals), max(vals))
                if a == "hybrid":
                    hybrid = (gm, min(vals), max(vals))
            if best:
                obs.append(prose("bench", "observation", set=st, ref=ref, best=name[best[0]],
                                 mean=g(best[1]), lo=g(best[2]), hi=g(best[3])))
            if hybrid:
                obs.append(prose("bench", "hybrid-observation", set=st, ref=name[ref],
                                 mean=g(hybrid[0]), lo=g(hybrid[1]), hi=g(hybrid[2])))
        return "\n" + "\n".join(obs) + "\n" if obs else ""


def isa_section(b, run):
    """The suite run again by a build for another CPU class (bench-avx2.json: kdgrid built for
    x86-64-v3, Embree restricted to AVX2): its throughput, packet and render tables."""
    f = Suite(b, run)
    simd = f.meta.get("simd") or {}
    return prose("bench", "isa", isa=simd.get("kdgrid", {}).get("isa", "?"),
                 embree_isa=simd.get("embree", {}).get("isa", "?"), ref=f.ref,
                 reps="%d" % f.meta["reps"], setup=f.setup, tables=f.throughput_tables(),
                 observations=f.observations(),
                 memory=prose("bench", "isa-memory", table=f.bytes_table()),
                 packets=packets_section(b, f.res, f.scenes, f.accels, f.name, f.ref, f.setup,
                                         "###"),
                 renders=renders_section(b, f.scenes, f.accels, f.name, f.ref, f.setup, "###"))


def bench_section(b, run, md_dir, img_dir):
    f = Suite(b, run)
    meta, scenes, accels, sets, res = f.meta, f.scenes, f.accels, f.sets, f.res
    ref, name, setup = f.ref, f.name, f.setup
    bld = f.bld
    out = []

    rows = []
    for s in b["scenes"]:
        rows.append([s["scene"], "`%s`" % rel_to_suite(s.get("file", ""), meta["suite"]),
                     s["triangles"], s.get("camera", ""),
                     " / ".join(str(s.get("rays", {}).get(x, "-")) for x in sets),
                     "ok" if s.get("ok", True) else "**failed**: " + s.get("error", "")])
    out.append(prose("bench", "suite", ref=ref, scenes=table(
        ["scene", "file", "triangles", "camera", "rays (%s)" % " / ".join(sets), "status"], rows,
        ["---", "---", "---:", "---", "---:", "---"])))

    out.append(prose(
        "bench", "throughput", ref=ref, reps="%d" % meta["reps"], threads="%d" % meta["threads"],
        setup=setup, tables=f.throughput_tables(),
        ratio_plot=img(md_dir, img_dir, "bench_ratio.png", "throughput ratio to " + ref),
        mrays_plot=img(md_dir, img_dir, "bench_mrays.png", "throughput in Mrays/s"),
        observations=f.observations()))

    out.append(packets_section(b, res, scenes, accels, name, ref, setup))
    out.append(renders_section(b, scenes, accels, name, ref, setup))

    tables = []
    for st in sets:
        rows = []
        for a in accels:
            row = [name[a]]
            for s in scenes:
                r = res.get((s, a, st))
                row.append("%s / %s / %s" % (g(r["steps_per_ray"]), g(r["leaves_per_ray"]),
                                            g(r["tests_per_ray"]))
                           if r and r.get("counted") else "n/a")
            rows.append(row)
        tables.append(prose("bench", "work-set", set=st,
                            table=table(["structure"] + scenes, rows)))
    out.append(prose("bench", "work", tables="".join(tables),
                     uncounted="Embree" if any(a.startswith("embree") for a in accels)
                     else "Some structures",
                     counts_plot=img(md_dir, img_dir, "bench_counts.png",
                                     "steps and tests per ray")))

    rows = []
    for a in accels:
        if a == ref:
            continue
        for st in sets:
            row = [name[a], st]
            for s in scenes:
                r = res.get((s, a, st))
                if not r or r.get("agreement") is None:
                    row.append("-")
                else:
                    row.append("%.6f (%d)" % (r["agreement"], r["disagreements"]))
            rows.append(row)
    out.append(prose("bench", "agreement", ref=ref, table=table(
        ["structure", "set"] + ["%s (rays differing)" % s for s in scenes], rows,
        ["---", "---"] + ["---:"] * len(scenes))))

    rows = []
    for s in scenes:
        for a in accels:
            x = bld.get((s, a))
            if not x:
                continue
            if not x.get("ok", True):
                rows.append([s, name[a], "**failed**: " + x.get("error", "")] + [""] * 7)
                continue
            parts = ", ".join("%s %s" % (k, mib(v)) for k, v in x.get("bytes_by_part", {}).items())
            rows.append([s, name[a], g(x["build_seconds"]), g(x["build_mtris_per_s"]), mib(x["bytes"]),
                         g(x["bytes_per_triangle"]), mib(x["peak_rss_bytes"]),
                         mib(x.get("rss_growth_bytes", 0)), mib(x["process_peak_rss_bytes"]),
                         parts])
    extras = [(s, a, bld[(s, a)].get("extra", {})) for s in scenes for a in accels
              if (s, a) in bld and bld[(s, a)].get("extra")]
    errors = "".join("- %s%s: %s\n" % (e.get("scene", ""), " / " + e["accel"] if "accel" in e
                                        else "", e["error"]) for e in b.get("errors") or [])
    out.append(prose(
        "bench", "build", setup=setup,
        table=table(["scene", "structure", "build s", "build Mtris/s", "MiB", "bytes/tri",
                     "peak RSS MiB", "growth MiB", "process peak MiB", "parts (MiB)"], rows,
                    ["---", "---"] + ["---:"] * 7 + ["---"]),
        build_plot=img(md_dir, img_dir, "bench_build.png", "build time and memory"),
        extras=prose("bench", "extras", table=table(
            ["scene", "structure", "facts"],
            [[s, a, "; ".join("%s: %s" % kv for kv in e.items())] for s, a, e in extras],
            ["---", "---", "---"])) if extras else "",
        errors=prose("bench", "errors", errors=errors) if errors else ""))
    return "".join(out)
