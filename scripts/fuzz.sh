#!/usr/bin/env bash
# Builds the libFuzzer harnesses with clang (ASan+UBSan) and runs each for a bounded time
# (default 30 s each; first argument overrides). Seeds come from fuzz/corpus/<target>/; a
# crash leaves its input in build/fuzz/crashes/ and fails the script. Turn every crash into a
# regression test by copying its input to tests/data/fuzz/<target>/ (replayed by ctest).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-30}"
targets=(ply obj gltf rays)
CC=clang CXX=clang++ cmake -S . -B build/fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DKDGRID_FUZZ=ON -DKDGRID_BUILD_VIEWER=OFF -DKDGRID_BUILD_TESTS=OFF -DKDGRID_NATIVE=OFF >/dev/null
cmake --build build/fuzz -j "${KDGRID_JOBS:-$(nproc)}" --target "${targets[@]/#/fuzz_}"
mkdir -p build/fuzz/crashes
status=0
for t in "${targets[@]}"; do
  work="build/fuzz/corpus-$t"
  mkdir -p "$work"
  echo "== fuzz_$t for ${seconds}s"
  seeds=()
  [ -d "fuzz/corpus/$t" ] && seeds=("fuzz/corpus/$t")
  if ! build/fuzz/fuzz/fuzz_$t -max_total_time="$seconds" -timeout=10 -rss_limit_mb=3072 \
      -print_final_stats=1 -artifact_prefix="build/fuzz/crashes/$t-" "$work" "${seeds[@]}" \
      2> "build/fuzz/fuzz_$t.log"; then
    echo "fuzz_$t FAILED: see build/fuzz/fuzz_$t.log and build/fuzz/crashes/" >&2
    tail -40 "build/fuzz/fuzz_$t.log" >&2
    status=1
  else
    grep -E "stat::number_of_executed_units|stat::peak_rss_mb" "build/fuzz/fuzz_$t.log" || true
  fi
done
exit $status
