#!/usr/bin/env bash
# The hybrid against Embree on this CPU, in each build a user of this CPU could run: the release
# build (-march=native) against Embree's best kernels, when the CPU has AVX-512, and the avx2
# preset (-march=x86-64-v3) against Embree restricted to AVX2. Each build runs the suite RUNS
# times (kdgrid bench: single rays, packets and the whole render, the hybrid and Embree only),
# into docs/results/cpus/NAME/, with cpu.json saying which CPU it was; bench-report shows every
# such folder in docs/RESULTS.md, "On other CPUs", as the ranges over the runs. docs/RESULTS.md's
# own run (bench-all.sh) is one CPU; this script adds the others without replacing it.
#
# Usage: scripts/bench-cpu.sh [NAME]   (default: vendor-family-model, e.g. amd-25-17)
# Environment:
#   RUNS            runs of the suite per build (default 3)
#   BENCH_REPS      timed repetitions per set within a run (default 5)
#   BENCH_THREADS   threads, 0 = all (default 0)
#   SKIP_BUILD=1    use the existing build/release and build/avx2
#   SKIP_REPORT=1   leave docs/RESULTS.md as it is
me=bench-cpu
# shellcheck source=scripts/measure-setup.sh
source "$(dirname "$0")/measure-setup.sh"
runs="${RUNS:-3}"
reps="${BENCH_REPS:-5}"
threads="${BENCH_THREADS:-0}"
[[ "$runs" =~ ^[1-9][0-9]*$ ]] || die "RUNS=$runs: a positive whole number"
[[ "$reps" =~ ^[1-9][0-9]*$ ]] || die "BENCH_REPS=$reps: a positive whole number"
[[ "$threads" =~ ^[0-9]+$ ]] || die "BENCH_THREADS=$threads: a whole number (0 = all)"
need_scenes "$scenes/suite.json"
has_avx2 || die "this CPU has no AVX2 and FMA: neither build this script compares can run on it"

cpuinfo_field() { sed -n "s/^$1[[:space:]]*: *//p" /proc/cpuinfo | head -1; }
vendor="$(cpuinfo_field vendor_id)"
family="$(cpuinfo_field 'cpu family')"
model="$(cpuinfo_field model)"
case "$vendor" in
  AuthenticAMD) short=amd ;;
  GenuineIntel) short=intel ;;
  *) short="$(echo "$vendor" | tr -cd '[:alnum:]' | tr '[:upper:]' '[:lower:]')" ;;
esac
name="${1:-$short-$family-$model}"
[[ "$name" =~ ^[A-Za-z0-9._-]+$ ]] || die "NAME '$name': letters, digits, '.', '_' and '-' only"
out="docs/results/cpus/$name"

builds=()
if grep -qw avx512f /proc/cpuinfo; then builds+=(avx512); fi
builds+=(avx2)
if [[ ${builds[0]} == avx512 ]]; then
  build_release OFF
  need_built build/release/src/cli/kdgrid
fi
build_avx2
need_built build/avx2/src/cli/kdgrid

commit="$(measured_commit)"
# The runs go to a hidden folder beside the old measurement (bench-report skips names starting
# with '.'), which they replace as a whole once all are done: runs of two commits never mix, and
# a failed or interrupted run leaves the old measurement as it was.
work="docs/results/cpus/.$name.partial"
rm -rf "$work"
mkdir -p "$work"
export KDGRID_SCENES="$scenes"
commands=()
# The builds in turn within each run, so that a change in the machine's load shows in both.
for ((r = 1; r <= runs; r++)); do
  for b in "${builds[@]}"; do
    if [[ $b == avx512 ]]; then
      cmd=(build/release/src/cli/kdgrid bench --suite "$scenes/suite.json" --accel hybrid)
    else
      cmd=(build/avx2/src/cli/kdgrid bench --suite "$scenes/suite.json" --accel hybrid
        --embree-isa avx2)
    fi
    cmd+=(--reps "$reps" --threads "$threads" --packet-tile 8 --render -q --json "$work/$b.$r.json")
    shown="${cmd[*]}"
    shown="${shown//$scenes/\$KDGRID_SCENES}"
    shown="${shown//$work/$out}"
    echo "== run $r of $runs: $shown" >&2
    "${cmd[@]}" || die "run $r of the $b build failed: $shown"
    [[ $r == 1 ]] && commands+=("${shown//.1.json/.RUN.json}")
  done
done

"$python" - "$work/cpu.json" "$commit" "$runs" "$vendor" "$family" "$model" "${commands[@]}" <<'EOF'
import json, platform, subprocess, sys
path, commit, runs, vendor, family, model, *commands = sys.argv[1:]
def sh(cmd):
    return subprocess.run(cmd, shell=True, capture_output=True, text=True).stdout.strip()
flags = sh("sed -n 's/^flags[[:space:]]*: *//p' /proc/cpuinfo | head -1").split()
cpu = {
    "model_name": sh("lscpu | sed -n 's/^Model name: *//p' | head -1") or "unknown",
    "vendor": vendor, "family": int(family), "model": int(model),
    "avx512": "avx512f" in flags,
    "cores": int(sh("nproc") or 0),
    "l2": sh("lscpu | sed -n 's/^L2 cache: *//p' | head -1"),
    "l3": sh("lscpu | sed -n 's/^L3 cache: *//p' | head -1"),
    "kernel": platform.release(),
    "compiler": sh("c++ --version | head -1"),
    "commit": commit, "runs": int(runs), "commands": commands,
}
with open(path, "w") as f:
    json.dump(cpu, f, indent=2)
    f.write("\n")
EOF
rm -rf "$out"
mv "$work" "$out"
echo "bench-cpu: $out" >&2
if [[ "${SKIP_REPORT:-0}" != 1 ]]; then
  "$python" scripts/bench-report docs/results --img-dir docs/img --out docs/RESULTS.md
fi
