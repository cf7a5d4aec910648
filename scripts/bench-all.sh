#!/usr/bin/env bash
# Measures everything docs/BENCHMARKS.md shows and regenerates that page from the results:
# the benchmark suite (kdgrid bench), the sweeps (kdgrid sweep), the plots (scripts/plot) and
# the page (scripts/bench-report). Numbers are never copied by hand. The page's "Viewer"
# section comes from RESULTS_DIR/viewer.json, measured on its own by scripts/viewer-bench.sh
# (it needs the viewer and Xvfb); this script leaves that file as it is.
#
# Usage: scripts/bench-all.sh [RESULTS_DIR]        (default docs/results)
# Environment:
#   KDGRID_SCENES   shared scenes (default ../shared/scenes beside the checkout)
#   BENCH_RES       primary rays per side for the suite (default 1024, BENCHMARK.md)
#   BENCH_REPS      timed repetitions per set (default 5)
#   BENCH_THREADS   threads, 0 = all (default 0)
#   SWEEP_SCENE     scene of the cellsize/lambda/kdcost/triangle sweeps (default dragon-200k)
#   SKIP_BUILD=1    use the existing build/release
#   SKIP_SWEEPS=1   only the suite (plots and page are still regenerated)
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
results="${1:-docs/results}"
kdgrid="$root/build/release/src/cli/kdgrid"
python=/usr/bin/python3  # Debian's, which has python3-matplotlib
# Shared scenes: $KDGRID_SCENES, else ../shared/scenes beside the checkout (or beside a parent
# folder, as util/paths.h looks for it).
scenes="${KDGRID_SCENES:-}"
if [[ -z "$scenes" ]]; then
  for base in "$root" "$root/.." "$root/../.."; do
    if [[ -d "$base/../shared/scenes" ]]; then
      scenes=$(cd "$base/../shared/scenes" && pwd)
      break
    fi
  done
fi
scenes="${scenes:-$root/../shared/scenes}"
res="${BENCH_RES:-1024}"
reps="${BENCH_REPS:-5}"
threads="${BENCH_THREADS:-0}"
sweep_scene="${SWEEP_SCENE:-$scenes/dragon/dragon_vrip_res2.ply}"

if [[ "${SKIP_BUILD:-0}" != 1 ]]; then
  bash scripts/build.sh release -DKDGRID_BUILD_VIEWER=OFF
fi
if [[ ! -f "$scenes/suite.json" ]]; then
  echo "bench-all: $scenes/suite.json not found; set KDGRID_SCENES to the shared scenes" >&2
  exit 1
fi
mkdir -p "$results"
commands="$results/commands.tsv"
: >"$commands"

# Runs a command, shows its progress, and records its wall time and its text for the page.
# Paths are written relative to the checkout so the page shows commands anyone can rerun.
run() {
  local shown="$*"
  shown="${shown//$root\//}"
  shown="${shown//$scenes/\$KDGRID_SCENES}"
  echo "== $shown" >&2
  local t0 t1 rc=0
  t0=$(date +%s.%N)
  "$@" || rc=$?
  t1=$(date +%s.%N)
  printf '%s\t%s\t%s\n' "$(echo "$t1 - $t0" | bc)" "$rc" "$shown" >>"$commands"
  return 0  # a failed scene is reported in the results; keep going
}

export KDGRID_SCENES="$scenes"
run "$kdgrid" bench --suite "$scenes/suite.json" --res "$res" --reps "$reps" --threads "$threads" \
  --json "$results/bench.json" --md "$results/bench.md"

if [[ "${SKIP_SWEEPS:-0}" != 1 ]]; then
  run "$kdgrid" sweep cellsize "$sweep_scene" --threads "$threads" --out "$results/sweep-cellsize"
  run "$kdgrid" sweep lambda "$sweep_scene" --threads "$threads" --out "$results/sweep-lambda"
  run "$kdgrid" sweep kdcost "$sweep_scene" --threads "$threads" --out "$results/sweep-kdcost"
  run "$kdgrid" sweep triangle "$sweep_scene" --threads "$threads" --out "$results/sweep-triangle"
  run "$kdgrid" sweep spp assets/cornell.gltf --threads "$threads" --out "$results/sweep-spp"
fi

# The machine and the commands, for the page.
"$python" - "$results" "$commands" <<'EOF'
import json, os, platform, subprocess, sys
results, commands = sys.argv[1], sys.argv[2]
def sh(cmd):
    try:
        return subprocess.run(cmd, shell=True, capture_output=True, text=True).stdout.strip()
    except Exception:
        return ""
run = {
    "cpu": sh("lscpu | sed -n 's/^Model name: *//p' | head -1") or "unknown",
    "cores": sh("nproc"),
    "kernel": platform.release(),
    "compiler": sh("c++ --version | head -1"),
    "commit": sh("git rev-parse --short HEAD") + (" (with local changes)" if sh("git status --porcelain --untracked-files=no") else ""),
    "memory": sh("free -g | awk '/^Mem:/ {print $2 \" GiB\"}'"),
    "commands": [],
}
with open(commands) as f:
    for line in f:
        sec, rc, cmd = line.rstrip("\n").split("\t", 2)
        run["commands"].append({"cmd": cmd, "seconds": float(sec), "exit": int(rc)})
        if " bench " in cmd:
            run["bench_seconds"] = float(sec)
with open(os.path.join(results, "run.json"), "w") as f:
    json.dump(run, f, indent=2)
EOF

"$python" scripts/plot "$results" --out docs/img
"$python" scripts/bench-report "$results" --img-dir docs/img --out docs/BENCHMARKS.md
