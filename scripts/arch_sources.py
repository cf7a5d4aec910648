#!/usr/bin/env python3
"""Lists the .cpp files of src/core whose code depends on the target CPU: those that test an
instruction-set macro (__AVX512F__, __SSE2__, ...), KDGRID_WIDE_LANES or include <immintrin.h>,
themselves or through the project's headers they include. scripts/clang-syntax.sh compiles
only these for its portable and x86-64-v3 flavours; every file compiles for x86-64-v4.

Usage: scripts/arch_sources.py [SRC_CORE_DIR]   (default: src/core of this checkout); prints
one path a line, relative to the checkout.
"""
import os
import re
import sys

INCLUDE = re.compile(r'^\s*#\s*include\s*"([^"]+)"', re.M)
ARCH = re.compile(r"__(AVX|SSE|FMA|BMI|F16C)\w*__|KDGRID_WIDE_LANES|immintrin")


def arch_sources(core):
    texts = {}
    for root, _, names in os.walk(core):
        for name in names:
            if name.endswith((".h", ".cpp")):
                path = os.path.join(root, name)
                with open(path, encoding="utf-8", errors="replace") as f:
                    texts[os.path.relpath(path, core)] = f.read()
    known = {}

    def depends(rel, seen):
        if rel in known:
            return known[rel]
        if rel not in texts or rel in seen:
            return False
        seen.add(rel)
        result = bool(ARCH.search(texts[rel])) or any(
            depends(inc, seen) for inc in INCLUDE.findall(texts[rel]))
        known[rel] = result
        return result

    return sorted(rel for rel in texts if rel.endswith(".cpp") and depends(rel, set()))


if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    core = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "..", "src", "core")
    for rel in arch_sources(core):
        print(os.path.join("src/core", rel))
