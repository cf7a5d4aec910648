#!/usr/bin/env python3
"""Checks docs/DESIGN.md's layer rule on src/core: includes run one way,
util <- math <- scene, image <- accel <- render <- bench, and nothing in src/core includes a
UI header (GLFW, GL, ImGui) or the programs' code (cli/, viewer/).

Usage: scripts/check_layers.py [SRC_CORE_DIR]   (default: src/core of this checkout)
Prints one line per include that runs up the layers (file:line: the include, its layer and the
file's) and exits 1 when there is any; exits 0 with a one-line summary otherwise.
"""
import os
import re
import sys

# Rank of each layer: a file may include its own layer and those of lower rank. scene and image
# share a rank (a loader reads textures, image I/O names no scene type).
LAYERS = {"util": 0, "math": 1, "scene": 2, "image": 2, "accel": 3, "render": 4, "bench": 5}
# Headers a core file must never include, whatever its layer.
FORBIDDEN = re.compile(r"^(GLFW/|GL/|glad/|imgui|cli/|viewer/)")
INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]([^">]+)[">]')


def check(core):
    problems = []
    files = 0
    for root, _, names in os.walk(core):
        for name in sorted(names):
            if not name.endswith((".h", ".cpp")):
                continue
            path = os.path.join(root, name)
            rel = os.path.relpath(path, core)
            layer = rel.split(os.sep)[0]
            if layer not in LAYERS:
                problems.append(f"{path}: not in a known layer ({', '.join(LAYERS)}); add "
                                "its directory to scripts/check_layers.py and docs/DESIGN.md")
                continue
            files += 1
            with open(path, encoding="utf-8", errors="replace") as f:
                for number, line in enumerate(f, 1):
                    m = INCLUDE.match(line)
                    if not m:
                        continue
                    inc = m.group(1)
                    if FORBIDDEN.match(inc):
                        problems.append(f"{path}:{number}: includes {inc}: src/core includes no "
                                        "UI or program header (docs/DESIGN.md)")
                        continue
                    target = inc.split("/")[0]
                    if "/" in inc and target in LAYERS and LAYERS[target] > LAYERS[layer]:
                        problems.append(f"{path}:{number}: includes {inc}: {layer}/ may not "
                                        f"include {target}/, which is above it (docs/DESIGN.md, "
                                        "util <- math <- scene, image <- accel <- render <- "
                                        "bench)")
    return files, problems


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    core = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "..", "src", "core")
    if not os.path.isdir(core):
        print(f"check_layers: {core} is not a directory; pass src/core", file=sys.stderr)
        return 2
    files, problems = check(core)
    for p in problems:
        print(p)
    if problems:
        print(f"check_layers: {len(problems)} include(s) break the layer rule", file=sys.stderr)
        return 1
    print(f"check_layers: {files} files of {core}, every include within the layer rule")
    return 0


if __name__ == "__main__":
    sys.exit(main())
