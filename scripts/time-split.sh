#!/usr/bin/env bash
# Where a ray's time goes, by ray class, on the build machine's own CPU target (AVX-512 where
# the CPU has it, which valgrind cannot run: scripts/ray-cost-split.sh counts instructions on an
# x86-64-v3 build instead). perf samples the CPU clock while `kdgrid trace` traces each set on
# one thread; the samples of the fast query (the structure's traversal with no counters, its
# triangle tests' out-of-line fallbacks included) are split by the code they fall in: set-up,
# leaf steps, subtrees, tests, mailbox and other, as scripts/walk_parts.py defines them (the
# innermost inlined frame of the sample's address that names one of the walk's functions).
# The samples of `kdgrid trace`'s counted pass (its CountProbe walk) and of the driver around
# the queries are left out. Each row gives the trace's ns a ray (median of its timed passes) and
# each part's share of the query's samples; a share times the ns a ray is that part's time.
# Times depend on the machine and its load; compare rows of one run.
#
# Builds build/perf (preset `perf`: the release flags, -march=native, with line info: the same
# code as the release build) the first time.
#
# Usage: scripts/time-split.sh [SCENE] [ACCELS] [SETS]
#   SCENE   a scene file (default $KDGRID_SCENES/dragon/dragon_vrip.ply)
#   ACCELS  comma-separated structures (default kdtree,hybrid; not embree, which has no line info)
#   SETS    comma-separated ray sets (default primary,shadow,diffuse)
# Environment: KDGRID_SCENES (default ../shared/scenes), RES (1024), REPEAT (timed passes, 10),
#              KDGRID_ARGS (extra options for `kdgrid rays` and `kdgrid trace`, e.g. the suite's
#              Sponza camera "--eye -14,3,0 --target 10,5,0 --fov 60").
me=time-split
# shellcheck source=scripts/measure-setup.sh
source "$(dirname "$0")/measure-setup.sh"
ray_cost_arguments "$@"
repeat="${REPEAT:-10}"
command -v perf >/dev/null || die "perf not found: bash scripts/install-deps.sh (or apt-get install linux-perf)"
command -v addr2line >/dev/null || die "addr2line not found: apt-get install binutils"
[[ "$res" =~ ^[0-9]+$ && "$repeat" =~ ^[0-9]+$ && "$repeat" -ge 1 ]] ||
  die "RES ($res) and REPEAT ($repeat) must be whole numbers, REPEAT >= 1"
perf record -q -e cpu-clock -o /dev/null true 2>/dev/null ||
  die "perf cannot sample here (perf record -e cpu-clock true fails; see /proc/sys/kernel/perf_event_paranoid)"
cmake --preset perf >/dev/null
cmake --build build/perf --target kdgrid -j "${KDGRID_JOBS:-$(nproc)}" >&2
kdgrid="$(pwd)/build/perf/src/cli/kdgrid"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "Time per ray by where it goes (perf cpu-clock samples, one thread, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //'), -march=native), $(basename "$scene") ${KDGRID_ARGS:-}, ${res}x${res} sets, at $(git rev-parse --short HEAD)$(git diff --quiet -- src || echo ' (modified)')"
echo
echo "| structure | rays | ns a ray | setup | steps | subtree | tests | mailbox | other | samples |"
echo "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
for set in "${set_list[@]}"; do
  set_rays "$set" "$work/$set.rays"
  for a in "${accel_list[@]}"; do
    [[ "$a" != embree* ]] || die "$a has no line info to split; use kdtree, hybrid"
    any=()
    [[ "$set" != shadow ]] || any=(--any)
    # shellcheck disable=SC2086
    perf record -q -e cpu-clock -o "$work/perf.$set.$a" -- \
      "$kdgrid" trace "$scene" --rays "$work/$set.rays" --accel "$a" --threads 1 --repeat "$repeat" \
      "${any[@]}" ${KDGRID_ARGS:-} > "$work/trace.$set.$a" 2> "$work/perf.err" ||
      { cat "$work/trace.$set.$a" "$work/perf.err" >&2; exit 1; }
    perf script -i "$work/perf.$set.$a" -F ip,sym,symoff --no-demangle 2>/dev/null > "$work/samples.$set.$a"
    /usr/bin/python3 - "$work/samples.$set.$a" "$work/trace.$set.$a" "$kdgrid" "$a" "$set" <<'EOF'
import re, subprocess, sys
sys.path.insert(0, "scripts")
from walk_parts import PARTS, inline_chains, part
samples, trace, binary, accel, rayset = sys.argv[1:6]
# Static addresses: each sample's symbol (mangled) and offset, and the symbol's address in nm.
nm = subprocess.run(["nm", binary], capture_output=True, text=True).stdout
addr = {}
for l in nm.splitlines():
    f = l.split()
    if len(f) == 3:
        addr[f[2]] = int(f[0], 16)
demangled = {}
def readable(sym):
    if sym not in demangled:
        demangled[sym] = subprocess.run(["c++filt", sym], capture_output=True, text=True).stdout.strip()
    return demangled[sym]
# The fast query: the walk's functions instantiated without counters (NoProbe), the query's
# entry, and the triangle tests' out-of-line fallbacks (resolve, depth_in_double), which the
# counted pass also calls: a small share of theirs is the counted pass's.
def in_query(name):
    if "CountProbe" in name or "TraceProbe" in name:
        return False
    return ("NoProbe" in name or re.search(r"AcceleratorBase<.*>::(intersect|occluded)\(", name)
            or "WatertightWide<" in name and "::resolve" in name or "depth_in_double" in name)
counts, total = {}, 0
for line in open(samples):
    m = re.match(r"\s*[0-9a-f]+\s+(\S+)\+0x([0-9a-f]+)", line)
    if not m or m.group(1) not in addr:
        continue
    sym, off = m.group(1), int(m.group(2), 16)
    if not in_query(readable(sym)):
        continue
    a = addr[sym] + off
    counts[a] = counts.get(a, 0) + 1
    total += 1
if total == 0:
    sys.exit(f"time-split: {accel} {rayset}: perf recorded no samples of the query: raise REPEAT, "
             f"or check that perf samples user code here (/proc/sys/kernel/perf_event_paranoid)")
chains = inline_chains(binary, sorted(counts))
split, other = dict.fromkeys(PARTS, 0), {}
for a, c in counts.items():
    k = part(chains.get(a, []))
    split[k] += c
    if k == "other":  # told on stderr, to see what the rules miss
        f = chains.get(a, [["?", ""]])[-1][0]
        other[f] = other.get(f, 0) + c
for f, c in sorted(other.items(), key=lambda kv: -kv[1])[:3]:
    print(f"time-split: {accel} {rayset}: other: {100.0 * c / total:.1f}% in {f[:150]}", file=sys.stderr)
t = open(trace).read()
m = re.search(r"^speed\s+([\d.]+) Mrays/s", t, re.M)
ns = f"{1000.0 / float(m.group(1)):.0f}" if m and float(m.group(1)) > 0 else "n/a"
cols = " | ".join(f"{100.0 * split[k] / total:.0f}%" for k in PARTS)
print(f"| {accel} | {rayset} | {ns} | {cols} | {total} |")
EOF
  done
done
