#!/usr/bin/env bash
# Where a ray's instructions go, by ray class: per ray of each structure and ray set (primary,
# shadow, diffuse), valgrind's callgrind counts the instructions, simulated cache misses and
# mispredicted branches of the fast query (AcceleratorBase::intersect, or ::occluded for the
# shadow set's any-hit queries) and splits the instructions by the code they come from: set-up,
# leaf steps, subtrees, tests, mailbox and other, as scripts/walk_parts.py defines them (the
# same split as scripts/time-split.sh's of perf's time samples on the native build).
#
# The rays: `kdgrid rays` writes each set at RES x RES (default 1024) with the camera of
# KDGRID_ARGS; the middle COUNT rays of each set (default 32768; for the primary set, rows in
# the image's middle) are traced once on one thread by `kdgrid trace --repeat 1`, whose counted
# pass (steps, leaves, tests per ray) is printed but not collected. Shadow and diffuse sets hold
# only the primary rays that hit, so their middle rays come from the image's middle rows too.
# Counts do not depend on the machine's load. The caches are cache-profile.sh's model (L1d 32
# KiB 8-way, one 2 MiB 16-way last level, no prefetcher) and its per-address branch predictor:
# misses and mispredictions compare structures roughly, they are not the CPU's.
#
# Builds build/callgrind (preset `callgrind`: x86-64-v3, as valgrind 3.19 decodes no AVX-512,
# with line info) the first time. Each structure and set takes 1-3 minutes on the dragon, most
# of it the build under valgrind.
#
# Usage: scripts/ray-cost-split.sh [SCENE] [ACCELS] [SETS]
#   SCENE   a scene file (default $KDGRID_SCENES/dragon/dragon_vrip.ply)
#   ACCELS  comma-separated structures (default kdtree,hybrid; not embree, which has no line info)
#   SETS    comma-separated ray sets (default primary,shadow,diffuse)
# Environment: KDGRID_SCENES (default ../shared/scenes), RES (1024), COUNT (32768), KDGRID_ARGS
#              (extra options for `kdgrid rays` and `kdgrid trace`, e.g. the suite's Sponza
#              camera "--eye -14,3,0 --target 10,5,0 --fov 60"), CACHE_SIM (1: simulate the
#              caches and branches; 0 leaves their columns empty and runs about twice as fast).
me=ray-cost-split
# shellcheck source=scripts/measure-setup.sh
source "$(dirname "$0")/measure-setup.sh"
ray_cost_arguments "$@"
count="${COUNT:-32768}"
sim=()
# shellcheck disable=SC2054  # the commas are valgrind's (size,ways,line)
[[ "${CACHE_SIM:-1}" == 0 ]] || sim=(--cache-sim=yes --branch-sim=yes --I1=32768,8,64 --D1=32768,8,64 --LL=2097152,16,64)
command -v addr2line >/dev/null || die "addr2line not found: apt-get install binutils"
[[ "$res" =~ ^[0-9]+$ && "$count" =~ ^[0-9]+$ && "$count" -ge 1 ]] ||
  die "RES ($res) and COUNT ($count) must be whole numbers, COUNT >= 1"
source scripts/callgrind-build.sh
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "Instructions per ray by where they go (callgrind, x86-64-v3), $(basename "$scene") ${KDGRID_ARGS:-}, the middle $count rays of each ${res}x${res} set, at $(git rev-parse --short HEAD)$(git diff --quiet -- src || echo ' (modified)')"
echo
echo "| structure | rays | instructions | setup | steps | subtree | tests | mailbox | other | D1 misses | LL misses | mispredicted | steps | leaves | tests | hit fraction |"
echo "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
for set in "${set_list[@]}"; do
  set_rays "$set" "$work/$set.all.rays"
  # The middle rays of the set.
  total=$("$python" scripts/rays_file.py count "$work/$set.all.rays")
  n=$((count < total ? count : total))
  "$python" scripts/rays_file.py cut "$work/$set.all.rays" "$work/$set.rays" $(((total - n) / 2)) "$n"
  for a in "${accel_list[@]}"; do
    [[ "$a" != embree* ]] || die "$a has no line info to split; use kdtree, hybrid"
    query=intersect any=()
    [[ "$set" != shadow ]] || { query=occluded; any=(--any); }
    sig='kdgrid::AcceleratorBase<*>::intersect(kdgrid::Ray const&, kdgrid::Hit&) const'
    [[ "$query" == intersect ]] || sig='kdgrid::AcceleratorBase<*>::occluded(kdgrid::Ray const&) const'
    # shellcheck disable=SC2086
    valgrind --tool=callgrind --toggle-collect="$sig" "${sim[@]}" --dump-instr=yes --compress-pos=no \
      --compress-strings=no --callgrind-out-file="$work/cg.$set.$a" \
      "$kdgrid" trace "$scene" --rays "$work/$set.rays" --accel "$a" --threads 1 --repeat 1 "${any[@]}" \
      ${KDGRID_ARGS:-} > "$work/trace.$set.$a" 2> "$work/valgrind.$set.$a" ||
      { cat "$work/trace.$set.$a" "$work/valgrind.$set.$a" >&2; exit 1; }
    /usr/bin/python3 - "$work/cg.$set.$a" "$work/trace.$set.$a" "$kdgrid" "$a" "$set" <<'EOF'
import re, subprocess, sys
cg, trace, binary, accel, rayset = sys.argv[1:6]
events, ob, skip = None, None, False
cost = {}  # (object, address) -> self cost per event
for line in open(cg):
    if line.startswith("events:"):
        events = line.split()[1:]
    elif line.startswith("ob="):
        ob = line[3:].strip()
    elif line.startswith("calls="):
        skip = True  # the next cost line is the call's inclusive cost, counted at its callee
    elif line[:1] == "0" or line[:1].isdigit():
        if skip:
            skip = False
            continue
        f = line.split()
        c = cost.setdefault((ob, int(f[0], 16)), [0] * len(events))
        for i, x in enumerate(f[2:]):
            c[i] += int(x)
ev = {e: i for i, e in enumerate(events)}
# Runtime addresses of the PIE binary: the load base is the one that maps AcceleratorBase's entry
# (the collected function's first address) onto its symbol.
ours = sorted(a for (o, a) in cost if o == binary)
nm = subprocess.run(["nm", "-C", binary], capture_output=True, text=True).stdout
syms = sorted(int(l.split()[0], 16) for l in nm.splitlines()
              if "AcceleratorBase<" in l and ("::intersect(" in l or "::occluded(" in l) and l.split()[0] != "")
base = None
for s in syms:
    if s + 0x108000 in ours or s in ours:
        base = 0x108000 if s + 0x108000 in ours else 0
        break
if base is None:
    base = 0x108000 if ours and ours[0] > 0x108000 else 0
sys.path.insert(0, "scripts")
from walk_parts import inline_chains, part
chains = {a + base: c for a, c in inline_chains(binary, [a - base for a in ours]).items()}
split, other = {}, {}
for (o, a), c in cost.items():
    k = part(chains.get(a, [])) if o == binary else "other"
    split[k] = split.get(k, 0) + c[ev["Ir"]]
    if k == "other":  # told on stderr, to see what the rules miss
        f = chains.get(a, [["?", ""]])[-1][0] if o == binary else o
        other[f] = other.get(f, 0) + c[ev["Ir"]]
tot = [sum(c[i] for c in cost.values()) for i in range(len(events))]
t = open(trace).read()
n = int(re.search(r"^rays\s+(\d+)", t, re.M).group(1))
hit = re.search(r"^hit fraction\s+(\S+)", t, re.M).group(1)
m = re.search(r"per ray\s+([\d.]+) steps, ([\d.]+) leaves, ([\d.]+) triangle tests", t)
st, lv, ts = m.groups() if m else ("n/a",) * 3
g = lambda e: tot[ev[e]] if e in ev else 0
sim = "D1mr" in ev
d1 = f'{(g("D1mr") + g("D1mw")) / n:.2f}' if sim else ""
ll = f'{(g("DLmr") + g("DLmw")) / n:.2f}' if sim else ""
bm = f'{(g("Bcm") + g("Bim")) / n:.1f}' if sim else ""
cols = " | ".join(f"{split.get(k, 0) / n:.0f}" for k in ("setup", "steps", "subtree", "tests", "mailbox", "other"))
for f, c in sorted(other.items(), key=lambda kv: -kv[1])[:3]:
    print(f"ray-cost-split: {accel} {rayset}: other: {c / n:.1f} a ray in {f[:150]}", file=sys.stderr)
print(f"| {accel} | {rayset} | {g('Ir') / n:.0f} | {cols} | {d1} | {ll} | {bm} | {st} | {lv} | {ts} | {hit} |")
EOF
  done
done
