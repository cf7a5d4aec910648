"""The hybrid's variants section, from hybrid-*.json (scripts/hybrid-variants.sh)."""
import os

from .bench import labels
from .common import g, load, ordered_unique, prose, table


HYBRID_VARIANTS = [("default", "default: leaf subtrees (flat where they pay), empty-leaf boxes"),
                   ("plain", "plain leaves (`--hybrid-subtree-min 0`)"),
                   ("paper", "the paper's: plain leaves, kd leaf boxes "
                    "(`--hybrid-subtree-min 0 --hybrid-no-expand-empty`)"),
                   ("dense", "dense matrix (`--hybrid-dense-matrix`)"),
                   ("nocache", "no next-leaf cache (`--hybrid-no-next-leaf-cache`)"),
                   ("kdsub", "every subtree walked by its kd nodes (`--hybrid-no-flat-subtrees`)")]
# Earlier names of the variants' files, read when a results directory has only those.
EARLIER_NAMES = {"nocache": "noguess"}


def load_variant(results_dir, name):
    """hybrid-NAME.json, else the file under the variant's earlier name, else None."""
    for n in (name, EARLIER_NAMES.get(name)):
        b = n and load(os.path.join(results_dir, "hybrid-%s.json" % n))
        if b:
            return b
    return None


def hybrid_variants_section(results_dir):
    """The hybrid's variants against the kd-tree and Embree (scripts/hybrid-variants.sh)."""
    runs = [(name, what, load_variant(results_dir, name)) for name, what in HYBRID_VARIANTS]
    runs = [r for r in runs if r[2]]
    if not runs:
        return prose("hybrid_variants", "not-measured")
    meta = runs[0][2]["meta"]
    rows = []
    for name, what, b in runs:
        for sc in b["scenes"]:
            res = {r["accel"]: r for r in b["results"] if r["scene"] == sc["scene"] and r["set"] == "primary"}
            bld = {r["accel"]: r for r in b["builds"] if r["scene"] == sc["scene"]}
            hs, kds = res.get("hybrid"), res.get("kdtree")
            if not hs:
                continue
            # Through the two ratios to Embree, each paired with Embree rep by rep: the raw
            # medians of Mrays/s were timed minutes apart and move with the machine's load.
            vs_kd = (hs["ratio_to_reference"] / kds["ratio_to_reference"]
                     if kds and hs.get("ratio_to_reference") and kds.get("ratio_to_reference") else None)
            hb = bld.get("hybrid", {})
            rows.append([what, sc["scene"], g(hs.get("ratio_to_reference")),
                         g(kds.get("ratio_to_reference")) if kds else "-", g(vs_kd),
                         g(hs.get("steps_per_ray")), g(hs.get("tests_per_ray")),
                         g(hb.get("bytes_per_triangle")), g(hb.get("build_seconds"))])
    # Which Embree the ratios refer to (its scene flags and build quality), from the runs.
    embree = ordered_unique(labels(b["builds"]).get("embree", "embree") for _, _, b in runs)
    return prose("hybrid_variants", "section", embree=" and ".join("`%s`" % e for e in embree),
                 width="%d" % meta["width"],
                 height="%d" % meta["height"], threads="%d" % meta["threads"],
                 reps="%d" % meta["reps"], clock=meta.get("clock", "wall"),
                 table=table(["variant", "scene", "hybrid / Embree", "kd-tree / Embree",
                              "hybrid / kd-tree", "steps per ray", "tests per ray",
                              "bytes per triangle", "build s"], rows,
                             ["---", "---"] + ["---:"] * 7))
