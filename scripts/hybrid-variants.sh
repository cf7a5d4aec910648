#!/usr/bin/env bash
# Measures the hybrid's variants side by side with the SAH kd-tree and Embree on the shared
# suite's primary rays, for docs/RESULTS.md ("The hybrid's variants"): the default (leaf
# subtrees, empty-leaf boxes, bricked matrix), plain leaves (--hybrid-subtree-min 0), the paper's
# hybrid (plain leaves stepping over kd leaf boxes: --hybrid-subtree-min 0
# --hybrid-no-expand-empty), the dense matrix of the paper (--hybrid-dense-matrix), the
# default without the next-leaf cache (--hybrid-no-next-leaf-cache), and every leaf subtree
# walked by its kd nodes (--hybrid-no-flat-subtrees).
# Tracing is timed with the threads' CPU clocks (--clock cpu) because this machine is shared;
# every figure is also given as a ratio to Embree and to the kd-tree measured in the same run.
#
# Usage: scripts/hybrid-variants.sh [RESULTS_DIR]    (default docs/results)
# Environment: KDGRID_SCENES (default ../shared/scenes), BENCH_RES (1024), BENCH_REPS (3),
#              BENCH_THREADS (0 = all).
me=hybrid-variants
# shellcheck source=scripts/measure-setup.sh
source "$(dirname "$0")/measure-setup.sh"
results="${1:-docs/results}"
kdgrid="build/release/src/cli/kdgrid"
need_built "$kdgrid"
need_scenes "$scenes/suite.json"
mkdir -p "$results"
common=(bench --suite "$scenes/suite.json" --sets primary --accel hybrid,kdtree --clock cpu
        --res "${BENCH_RES:-1024}" --reps "${BENCH_REPS:-3}" --threads "${BENCH_THREADS:-0}")
variant() {
  local name="$1"; shift
  echo "== hybrid variant $name: kdgrid ${common[*]} $*" >&2
  "$kdgrid" "${common[@]}" "$@" --json "$results/hybrid-$name.json" -q
}
variant default
variant plain --hybrid-subtree-min 0
variant paper --hybrid-subtree-min 0 --hybrid-no-expand-empty
variant dense --hybrid-dense-matrix
variant nocache --hybrid-no-next-leaf-cache
variant kdsub --hybrid-no-flat-subtrees
echo "hybrid-variants: wrote $results/hybrid-{default,plain,paper,dense,nocache,kdsub}.json" >&2
