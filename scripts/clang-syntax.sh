#!/usr/bin/env bash
# Checks that the core library compiles under clang (syntax and semantics, no code generated),
# in the portable, x86-64-v3 (AVX2) and x86-64-v4 (AVX-512: the hybrid's 16-lane groups)
# flavours (the first two only the files that depend on the target), and the hybrid's files for
# AVX-512 with groups of 8: the ctest
# `Portability.CoreCompilesWithClang`.
# The tests build with GCC; CI's fuzz step builds the core with clang much later, and a
# GCC-only builtin once failed CI there after 40 minutes. This finds it in seconds.
# Exits 77 (ctest's skip) with a message when clang++ is not installed.
set -euo pipefail
cd "$(dirname "$0")/.."
cxx="${CLANGXX:-clang++}"
if ! command -v "$cxx" >/dev/null; then
  echo "SKIPPED: $cxx not found; install it with scripts/install-deps.sh (Debian package clang)"
  exit 77
fi
jobs="${KDGRID_JOBS:-$(nproc)}"
flags=(-fsyntax-only -std=c++20 -Werror -Wall -Wextra -Wno-unused-parameter
       -Wno-missing-field-initializers -Isrc/core -isystem /usr/include/Imath)
status=0
# Every file for the widest target; for the others only the files whose code depends on the
# target (scripts/arch_sources.py): the rest compile to the same code whatever -march says.
every=$(find src/core -name '*.cpp' | sort)
arch_dependent=$(/usr/bin/python3 scripts/arch_sources.py)
flavours=("(portable)")
[ "$(uname -m)" = x86_64 ] && flavours+=("-march=x86-64-v3" "-march=x86-64-v4")
for flavour in "${flavours[@]}"; do
  arch="${flavour#(portable)}"
  files="$arch_dependent"
  [ "$flavour" = "${flavours[-1]}" ] && files="$every"
  echo "== $cxx $flavour: $(echo "$files" | wc -l) files"
  echo "$files" | xargs -P "$jobs" -n 4 "$cxx" "${flags[@]}" $arch || status=1
done
# The hybrid's groups of 8 in a build for AVX-512 (KDGRID_WIDE_LANES=8: the AVX2 form of shared
# corners under the 16-lane packet walk): the files that instantiate its walk.
if [ "$(uname -m)" = x86_64 ]; then
  echo "== $cxx -march=x86-64-v4 -DKDGRID_WIDE_LANES=8 (the hybrid's files)"
  ls src/core/accel/hybrid/*.cpp src/core/accel/factory.cpp |
    xargs -P "$jobs" -n 2 "$cxx" "${flags[@]}" -march=x86-64-v4 -DKDGRID_WIDE_LANES=8 || status=1
fi
[ "$status" = 0 ] && echo "src/core compiles under $("$cxx" --version | head -1)"
exit "$status"
