#!/usr/bin/env bash
# Measures everything docs/RESULTS.md shows and regenerates that page from the results:
# the benchmark suite (kdgrid bench, with the whole-render column), the suite again built for
# AVX2 CPUs against Embree restricted to AVX2 (build/avx2), the sweeps (kdgrid sweep), the extreme-ray suite with the
# acne study (kdgrid check --acne, the accuracy side of the secondary-ray offset), the plots
# (scripts/plot) and the page (scripts/bench-report). Numbers are never copied by hand. The
# page's "Viewer", "10M-triangle" and "hybrid's variants" sections come from viewer.json,
# big-scene.json and hybrid-*.json, measured on their own by scripts/viewer-bench.sh (needs
# the viewer and Xvfb), scripts/big-scene.sh and scripts/hybrid-variants.sh; this script
# leaves those files as they are.
#
# Usage: scripts/bench-all.sh [RESULTS_DIR]        (default docs/results)
# Environment:
#   KDGRID_SCENES   shared scenes (default ../shared/scenes beside the checkout)
#   BENCH_RES       primary rays per side for the suite (default 1024, docs/RAYSETS.md)
#   BENCH_REPS      timed repetitions per set (default 5)
#   BENCH_THREADS   threads, 0 = all (default 0)
#   SWEEP_SCENE     scene of the cellsize/lambda/kdcost/triangle sweeps (default dragon-200k)
#   SKIP_BUILD=1    use the existing build/release
#   SKIP_SWEEPS=1   no sweeps (plots and page are still regenerated)
#   ONLY=PARTS      only these comma-separated parts: suite, avx2, sweeps, check (default: all). The
#                   results of the parts not run are kept, and so are their lines in
#                   commands.tsv; each command's line records the commit it ran at.
me=bench-all
# Shared scenes: $KDGRID_SCENES, else ../shared/scenes beside the checkout (or beside a parent
# folder, as util/paths.h looks for it).
# shellcheck source=scripts/measure-setup.sh
source "$(dirname "$0")/measure-setup.sh"
results="${1:-docs/results}"
kdgrid="$root/build/release/src/cli/kdgrid"
res="${BENCH_RES:-1024}"
reps="${BENCH_REPS:-5}"
threads="${BENCH_THREADS:-0}"
sweep_scene="${SWEEP_SCENE:-$scenes/dragon/dragon_vrip_res2.ply}"

build_release OFF
need_scenes "$scenes/suite.json"
only="${ONLY:-suite,avx2,sweeps,check}"
part() { [[ ",$only," == *",$1,"* ]]; }
for p in ${only//,/ }; do
  case "$p" in
    suite | avx2 | sweeps | check) ;;
    *) echo "bench-all: ONLY=$only: unknown part '$p' (use suite, avx2, sweeps, check)" >&2; exit 2 ;;
  esac
done
# The commit measured, and whether the tree differs from it, before this script writes a file.
commit="$(measured_commit)"
mkdir -p "$results"
commands="$results/commands.tsv"
# A full run starts the command list afresh; a partial one (ONLY) replaces only its own lines.
if [[ -z "${ONLY:-}" ]]; then : >"$commands"; else touch "$commands"; fi

# Runs a command, shows its progress, and records its wall time and its text for the page.
# Paths are written relative to the checkout so the page shows commands anyone can rerun.
# With RUN_LOG=FILE the command's output is also kept in FILE.
run() {
  local shown="$*"
  shown="${shown//$root\//}"
  shown="${shown//$scenes/\$KDGRID_SCENES}"
  echo "== $shown" >&2
  local t0 t1 rc=0
  t0=$(date +%s.%N)
  if [[ -n "${RUN_LOG:-}" ]]; then
    "$@" | tee "$RUN_LOG" || rc=${PIPESTATUS[0]}
  else
    "$@" || rc=$?
  fi
  t1=$(date +%s.%N)
  # Columns: seconds, exit code, command, commit. An earlier line of the same command is
  # replaced (partial runs).
  awk -F'\t' -v c="$shown" '$3 != c' "$commands" >"$commands.tmp"
  printf '%s\t%s\t%s\t%s\n' "$(echo "$t1 - $t0" | bc)" "$rc" "$shown" "$commit" >>"$commands.tmp"
  mv "$commands.tmp" "$commands"
  return 0  # a failed scene is reported in the results; keep going
}

export KDGRID_SCENES="$scenes"
if part suite; then
  run "$kdgrid" bench --suite "$scenes/suite.json" --res "$res" --reps "$reps" --threads "$threads" \
    --render --json "$results/bench.json" --md "$results/bench.md"
fi

# The suite again as it runs on a CPU without AVX-512: kdgrid built for x86-64-v3 (preset avx2,
# build/avx2) against Embree restricted to AVX2. Skipped, saying so, on a CPU without AVX2.
if part avx2; then
  if has_avx2; then
    build_avx2
    run "$root/build/avx2/src/cli/kdgrid" bench --suite "$scenes/suite.json" --res "$res" \
      --reps "$reps" --threads "$threads" --embree-isa avx2 --render \
      --json "$results/bench-avx2.json" --md "$results/bench-avx2.md"
  else
    echo "bench-all: this CPU has no AVX2 and FMA: the AVX2 suite is not run" >&2
  fi
fi

if part sweeps && [[ "${SKIP_SWEEPS:-0}" != 1 ]]; then
  run "$kdgrid" sweep cellsize "$sweep_scene" --threads "$threads" --out "$results/sweep-cellsize"
  run "$kdgrid" sweep lambda "$sweep_scene" --threads "$threads" --out "$results/sweep-lambda"
  run "$kdgrid" sweep kdcost "$sweep_scene" --threads "$threads" --out "$results/sweep-kdcost"
  run "$kdgrid" sweep triangle "$sweep_scene" --threads "$threads" --out "$results/sweep-triangle"
  run "$kdgrid" sweep spp assets/cornell.gltf --threads "$threads" --out "$results/sweep-spp"
fi
# The extreme-ray suite and the acne study (self-hits and secondary-ray speed of the robust
# offset and of a fixed epsilon), the same suite as CI's; check.txt is the printed report that
# docs/ACCURACY.md shows.
if part check; then
  RUN_LOG="$results/check.txt" run "$kdgrid" check --rays 150 --acne --acne-rays 3000 \
    --threads "$threads" --json "$results/check.json"
fi

# The machine and the commands, for the page.
"$python" - "$results" "$commands" "$commit" <<'EOF'
import json, os, platform, subprocess, sys
results, commands, commit = sys.argv[1], sys.argv[2], sys.argv[3]
def sh(cmd):
    try:
        return subprocess.run(cmd, shell=True, capture_output=True, text=True).stdout.strip()
    except Exception:
        return ""
# Lines written before commits were recorded per command ran at the previous run's commit.
old = {}
if os.path.exists(os.path.join(results, "run.json")):
    with open(os.path.join(results, "run.json")) as f:
        old = json.load(f)
run = {
    "cpu": sh("lscpu | sed -n 's/^Model name: *//p' | head -1") or "unknown",
    "cores": sh("nproc"),
    "kernel": platform.release(),
    "compiler": sh("c++ --version | head -1"),
    "commit": commit,
    "memory": sh("free -g | awk '/^Mem:/ {print $2 \" GiB\"}'"),
    "commands": [],
}
with open(commands) as f:
    for line in f:
        parts = line.rstrip("\n").split("\t")
        sec, rc, cmd = parts[:3]
        c = {"cmd": cmd, "seconds": float(sec), "exit": int(rc),
             "commit": parts[3] if len(parts) > 3 else old.get("commit", commit)}
        run["commands"].append(c)
        if " bench " in cmd:
            run["bench_seconds"] = float(sec)
            # The page's commit is the suite's: the figures most of it shows.
            run["commit"] = c["commit"]
with open(os.path.join(results, "run.json"), "w") as f:
    json.dump(run, f, indent=2)
EOF

"$python" scripts/plot "$results" --out docs/img
"$python" scripts/bench-report "$results" --img-dir docs/img --out docs/RESULTS.md
