#!/usr/bin/env bash
# The hybrid's forms for CPUs without AVX-512 (groups of 8 with shared corners, flat subtrees in
# two 8-lane halves, packets of 8 rays), tested where they run: builds the `avx2` preset
# (x86-64-v3, build/avx2) and runs the tests of the hybrid, its triangle groups and the packet
# queries there. The main build is -march=native, which on an AVX-512 machine compiles only the
# 16-lane forms, and Portability.CoreCompilesWithClang only compiles these.
# On a CPU without AVX2 and FMA it says so and runs nothing.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! grep -qw avx2 /proc/cpuinfo || ! grep -qw fma /proc/cpuinfo; then
  echo "SKIPPED: this CPU has no AVX2 and FMA, so the avx2 preset's tests cannot run here"
  exit 0
fi
jobs="${KDGRID_JOBS:-$(nproc)}"
cmake --preset avx2 >/dev/null
cmake --build build/avx2 -j "$jobs" --target kdgrid_tests
ctest --test-dir build/avx2 --output-on-failure -j "$jobs" -R 'WideLeaves|Packets|Hybrid|hybrid|Flat'
