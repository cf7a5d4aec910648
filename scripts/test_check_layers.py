#!/usr/bin/env python3
"""Tests scripts/check_layers.py: the tree's src/core keeps docs/DESIGN.md's layer rule, and
the check fails, naming the file and line, on an include that runs up the layers or a UI
header in the core."""
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "check_layers.py")


def run(core):
    return subprocess.run([sys.executable, SCRIPT, core], capture_output=True, text=True)


def tree(files):
    root = tempfile.mkdtemp(prefix="check_layers_")
    for rel, text in files.items():
        path = os.path.join(root, rel)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            f.write(text)
    return root


def main():
    failures = []
    real = run(os.path.join(HERE, "..", "src", "core"))
    if real.returncode != 0:
        failures.append("src/core breaks the layer rule:\n" + real.stdout + real.stderr)
    ok = tree({"util/a.h": '#include "util/b.h"\n', "math/v.h": '#include "util/a.h"\n',
               "image/i.cpp": '#include "scene/s.h"\n#include "math/v.h"\n',
               "scene/s.h": '#include "image/i.h"\n', "bench/b.cpp": '#include "render/r.h"\n'})
    if run(ok).returncode != 0:
        failures.append("a tree within the rule was refused: " + run(ok).stdout)
    for name, files, needle in [
        ("image includes render", {"image/io.cpp": 'x\n#include "render/renderer.h"\n'},
         "io.cpp:2: includes render/renderer.h"),
        ("util includes accel", {"util/f.cpp": '#include "accel/guards.h"\n'},
         "f.cpp:1: includes accel/guards.h"),
        ("util includes math", {"util/f.h": '#  include "math/vec.h"\n'},
         "f.h:1: includes math/vec.h"),
        ("core includes ImGui", {"render/r.cpp": "#include <imgui.h>\n"}, "includes imgui.h"),
        ("core includes the viewer", {"bench/b.cpp": '#include "viewer/viewer.h"\n'},
         "includes viewer/viewer.h"),
    ]:
        r = run(tree(files))
        if r.returncode != 1 or needle not in r.stdout:
            failures.append(f"{name}: exit {r.returncode}, expected 1 and '{needle}' in:\n"
                            + r.stdout + r.stderr)
    for f in failures:
        print("FAIL:", f)
    if not failures:
        print("check_layers: every case passed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
