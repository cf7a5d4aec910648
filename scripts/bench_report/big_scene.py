"""The 10M-triangle section, from big-scene.json (scripts/big-scene.sh)."""
import os

from .common import g, img, load, mib, prose, table


def big_scene_section(results_dir, md_dir, img_dir):
    """The 10M-triangle run of scripts/big-scene.sh (docs/results/big-scene.json), if any."""
    big = load(os.path.join(results_dir, "big-scene.json"))
    if not big:
        return ""
    meta, runs = big["meta"], big["runs"]
    n = meta["triangles"]
    fields = dict(
        triangles_grouped="{:,}".format(n), command=meta.get("command", ""), scene=meta["scene"],
        triangles="%d" % n, res="%d" % meta["res"],
        budget=prose("big_scene", "budget-set", mb="%d" % meta["memory_budget_mb"])
        if meta.get("memory_budget_mb") else prose("big_scene", "budget-default"),
        cpu=meta.get("cpu", "?"), cores=meta.get("cores", "?"), memory=meta.get("memory", "?"),
        date=meta.get("date", "?"), commit=meta.get("commit", "?"),
        ply=prose("big_scene", "ply", seconds="%.1f" % meta["ply_write_seconds"],
                  mib="%.0f" % (meta["ply_bytes"] / 2**20)) if meta.get("ply_bytes") else "",
        mesh="", refusals="", tight="", picture="")
    first = next((r["stats"] for r in runs if r.get("stats")), None)
    if first:
        fields["mesh"] = prose("big_scene", "mesh", vertices="%d" % first["vertices"],
                               mib="%.0f" % (first["mesh_bytes"] / 2**20),
                               peak="%.0f" % (first["rss_load_peak_bytes"] / 2**20))
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
    fields["table"] = table(["structure", "build s", "structure MiB", "estimate MiB",
                             "build peak MiB", "process peak MiB", "render s", "Mrays/s",
                             "outcome"], rows)
    if refusals:
        fields["refusals"] = prose("big_scene", "refusals", list="".join(
            prose("big_scene", "refusal", structure=label, message=msg)
            for label, msg in refusals))
    if tight:
        mb = tight[0].get("budget_mb", 0)
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
        fields["tight"] = prose("big_scene", "tight", mb="%d" % mb,
                                triangles_grouped=fields["triangles_grouped"],
                                table=table(["structure", "seconds", "process peak MiB",
                                             "outcome"], trows, ["---", "---:", "---:", "---"]))
    if os.path.exists(os.path.join(img_dir, "big-scene.png")):
        fields["picture"] = img(md_dir, img_dir, "big-scene.png",
                                "the landscape, as rendered above")
    return prose("big_scene", "section", **fields)
