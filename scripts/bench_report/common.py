"""Helpers every section uses: loading result files, formatting numbers, Markdown tables and
plot links."""
import json
import os


def load(path):
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f)


def g(v, digits=3):
    """A number with `digits` significant digits, or '-'."""
    if v is None:
        return "-"
    if isinstance(v, str):
        return v
    if v == 0:
        return "0"
    return "%.*g" % (digits, v)


def mib(b):
    return "%.1f" % (b / 2**20)


def ordered_unique(values):
    out = []
    for v in values:
        if v not in out:
            out.append(v)
    return out


def table(header, rows, align=None):
    align = align or ["---"] + ["---:"] * (len(header) - 1)
    out = ["| " + " | ".join(header) + " |", "|" + "|".join(align) + "|"]
    for r in rows:
        out.append("| " + " | ".join(str(c) for c in r) + " |")
    return "\n".join(out) + "\n"


def img(md_dir, img_dir, name, alt):
    path = os.path.join(img_dir, name)
    if not os.path.exists(path):
        return "*(plot %s missing: run scripts/plot)*\n" % name
    return "![%s](%s)\n" % (alt, os.path.relpath(path, md_dir))


def rel_to_suite(path, suite):
    """A scene path relative to the (first) suite file's folder, as the suite lists it."""
    first = suite.split(",")[0] if suite else ""
    if not path or not first:
        return path or "-"
    return os.path.relpath(path, os.path.dirname(os.path.abspath(first)))
