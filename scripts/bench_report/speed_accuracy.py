"""The Speed vs accuracy section: each option's speed beside the error rate it costs."""
import os

from .common import g, load, ordered_unique, prose, table


def geomean(vals):
    vals = [max(v, 1e-12) for v in vals]
    if not vals:
        return None
    p = 1.0
    for v in vals:
        p *= v
    return p ** (1.0 / len(vals))


def pct(n, d):
    return "-" if not d else "%s / %s (%s%%)" % (int(n), int(d), g(100.0 * n / d))


def embree_flag_rows(bench, chk):
    """Embree's scene flags as a speed/accuracy option: its default flags (`embree`, the
    bench's reference) and RTC_SCENE_FLAG_ROBUST (`embree-robust`), their primary-ray speed
    from bench.json beside their unambiguous disagreements in the extreme-ray suite."""
    if not bench:
        return []
    prim = [r for r in bench["results"] if r["set"] == "primary" and r.get("mrays")]
    if not any(r["accel"] == "embree-robust" for r in prim):
        return []
    scenes = ordered_unique(r["scene"] for r in prim)
    rows = []
    for accel, label in (("embree", "default flags (`embree`)"),
                         ("embree-robust", "`RTC_SCENE_FLAG_ROBUST` (`embree-robust`)")):
        mine = {r["scene"]: r for r in prim if r["accel"] == accel}
        speeds = ", ".join("%s %s" % (s, g(mine[s]["mrays"])) for s in scenes if s in mine)
        # Paired ratios to the reference; the default flags are the reference when the bench
        # ran with its default reference.
        ratios = [mine[s]["ratio_to_reference"] for s in scenes
                  if s in mine and mine[s].get("reference") == "embree"]
        gm = geomean(ratios) if len(ratios) == len(scenes) else None
        vs = "-" if gm is None else (g(gm) if accel == "embree" else "%s (%s to %s)" % (
            g(gm), g(min(ratios)), g(max(ratios))))
        rate = "not measured"
        if chk and chk.get("check"):
            mc = [r for r in chk["check"] if r["structure"] == accel]
            if mc:
                rate = "%s (%d ambiguous)" % (pct(sum(r["disagree"] for r in mc),
                                                  sum(r["rays"] for r in mc)),
                                              sum(r["ambiguous"] for r in mc))
        rows.append(["Embree scene flags", label + (" (default)" if accel == "embree" else ""),
                     "primary rays of the suite, Mrays/s: " + speeds, vs,
                     "extreme-ray suite disagreements", rate])
    return rows


def speed_accuracy_section(results_dir):
    """Each option's speed next to its accuracy figure (leaks, acne), from the result files."""
    tri = load(os.path.join(results_dir, "sweep-triangle.json"))
    chk = load(os.path.join(results_dir, "check.json"))
    cell = load(os.path.join(results_dir, "sweep-cellsize.json"))
    bench = load(os.path.join(results_dir, "bench.json"))
    if not (tri or chk):
        return ""
    rows = []
    if tri:
        thr = {(r["accel"], r["test"]): r for r in tri["rows"]
               if r.get("part") == "throughput" and "error" not in r}
        leak = [r for r in tri["rows"] if r.get("part") == "leak" and "error" not in r]
        tests = ordered_unique([k[1] for k in thr] + [r["test"] for r in leak])
        accels = ordered_unique(k[0] for k in thr)
        for t in tests:
            speeds = ", ".join("%s %s" % (a, g(thr[(a, t)]["mrays"])) for a in accels
                               if (a, t) in thr)
            ratios = [thr[(a, t)]["speedup_vs_watertight"] for a in accels if (a, t) in thr]
            # Leaks per structure (brute isolates the test); the worst structure is shown.
            per = {}
            for r in leak:
                if r["test"] == t:
                    n, d = per.get(r["accel"], (0, 0))
                    per[r["accel"]] = (n + r["leaks"], d + r["rays"])
            worst = max(per.values(), key=lambda x: x[0] / x[1] if x[1] else 0, default=None)
            same = len(set(per.values())) == 1
            rate = "-" if worst is None else pct(*worst) + (
                ", every structure" if same else ", worst structure")
            gm = geomean(ratios)
            vs = "-" if gm is None else "%s (%s to %s)" % (g(gm), g(min(ratios)), g(max(ratios)))
            rows.append(["triangle test", t + (" (default)" if t == "watertight" else ""),
                         "primary rays of `%s`, Mrays/s: %s" % (
                             thr[(accels[0], t)]["mesh"] if accels and (accels[0], t) in thr
                             else "-", speeds),
                         vs, "leaks", rate])
    if chk and chk.get("acne"):
        acne = chk["acne"]
        meta = chk.get("meta", {})
        rays = sum(r["rays"] for r in acne)
        for key, label, default in (("robust", "robust offset", True),
                                    ("epsilon", "fixed tmin = %s" % g(acne[0].get("epsilon")),
                                     False)):
            hits = sum(r["%s_self_hits" % key] for r in acne)
            secs = sum(r.get("%s_seconds" % key, 0) for r in acne)
            base = sum(r.get("robust_seconds", 0) for r in acne)
            # Worst (scale, translation) of the study, for the rate's spread.
            worst = max(acne, key=lambda r: r["%s_self_hits" % key] / r["rays"] if r["rays"]
                        else 0)
            spread = ("" if not worst["rays"] or not worst["%s_self_hits" % key] else
                      "; worst: %s at scale %s, translation %s" % (
                          pct(worst["%s_self_hits" % key], worst["rays"]), g(worst["scale"]),
                          g(worst["translation"])))
            speed = ("%s Mrays/s (secondary rays of the study, %s, %s thread%s)" % (
                g(rays / secs / 1e6), meta.get("acne_scene", "acne scenes"),
                meta.get("acne_threads", 1), "" if meta.get("acne_threads", 1) == 1 else "s")
                if secs else "not measured (check.json predates the timing)")
            rows.append(["secondary-ray offset", label + (" (default)" if default else ""),
                         speed, g(base / secs) if secs and base else "-", "acne",
                         pct(hits, rays) + spread])
    rows += embree_flag_rows(bench, chk)
    if cell:
        ok = [r for r in cell["rows"] if "error" not in r and r.get("mrays")]
        auto = next((r for r in ok if r.get("label") == "auto"), None)
        if ok and auto:
            lo = min(ok, key=lambda r: r["mrays"])
            hi = max(ok, key=lambda r: r["mrays"])
            rows.append(["hybrid cell size", "auto (default); %s to %s x auto" % (
                g(min(r["multiplier"] for r in ok)), g(max(r["multiplier"] for r in ok))),
                "primary rays of `%s`, Mrays/s: auto %s; from %s (%s x) to %s (%s x)" % (
                    os.path.splitext(os.path.basename(cell["meta"]["scene"]))[0],
                    g(auto["mrays"]), g(lo["mrays"]), g(lo["multiplier"]), g(hi["mrays"]),
                    g(hi["multiplier"])),
                "%s to %s" % (g(lo["mrays"] / auto["mrays"]), g(hi["mrays"] / auto["mrays"])),
                "not measured", "-"])
    notes = []
    if cell:
        notes.append(prose("speed_accuracy", "cellsize-note"))
    if chk and chk.get("check"):
        per = {}
        for r in chk["check"]:
            n = per.setdefault(r["structure"], [0, 0, 0, 0])
            n[0] += r["rays"]
            n[1] += r["ambiguous"]
            n[2] += r["disagree"]
            n[3] += 1 if r.get("error") else 0
        notes.append(prose(
            "speed_accuracy", "check-note",
            scenes=len(ordered_unique(r["scene"] for r in chk["check"])),
            structures="; ".join("%s %d of %d rays (%d ambiguous)%s" % (
                a, v[2], v[0], v[1], ", %d errors" % v[3] if v[3] else "")
                for a, v in per.items())))
    return prose("speed_accuracy", "section",
                 table=table(["option", "setting", "speed", "vs default", "accuracy figure",
                              "rate"], rows, ["---", "---", "---", "---:", "---", "---"]),
                 notes="\n" + "\n\n".join(notes) + "\n" if notes else "")
