#!/usr/bin/env bash
# Instructions per ray of each structure's closest-hit query, counted by valgrind's callgrind on
# a band of the canonical camera's primary rays (or of another ray set of the same image, SET): the measure to compare a change with its parent
# before timing it. The count does not depend on the machine's load (the same commit gives the
# same figure to a few instructions), where `kdgrid bench` moves by 2-3% between paired runs on
# a shared machine. Instructions are not time: a change that saves instructions but adds a cache
# miss or a dependent load can still be slower, so confirm with `kdgrid bench --reference`.
#
# What is counted: AcceleratorBase<...>::intersect(ray, hit), everything inside it (the ray's
# validation, the traversal, the triangle tests) for the uncounted pass of `kdgrid trace`
# (intersect_counted, the pass that fills the counters, is left out), divided by the band's
# rays. The build and the file I/O are not counted. The band is ROWS rows of the --res image
# centred on the image (default 64 of 1024: 65536 rays, 2-3 minutes per structure on the dragon,
# most of it the build under valgrind).
#
# Builds build/callgrind (preset `callgrind`: x86-64-v3, as valgrind 3.19 decodes no AVX-512)
# the first time, unless KDGRID_BUILD names another build folder to count (one for x86-64-v3
# or older: valgrind 3.19 stops at an AVX-512 instruction).
#
# Usage: scripts/instr-count.sh [SCENE] [ACCELS]
#   SCENE   a scene file (default $KDGRID_SCENES/dragon/dragon_vrip.ply)
#   ACCELS  comma-separated structures of the project (default kdtree,hybrid); not embree, whose
#           counted pass calls its uncounted query, so the two cannot be told apart here
# Environment: KDGRID_SCENES (default ../shared/scenes), RES (1024), ROWS (64), and
#              KDGRID_ARGS (extra options for `kdgrid rays` and `kdgrid trace`, e.g. a camera:
#              "--eye -14,3,0 --target 10,5,0 --fov 60" for the suite's Sponza view), SET
#              (the ray set of `kdgrid rays --set`: primary, the default, shadow or diffuse; one
#              ray per pixel), TRACE_ARGS (extra options for `kdgrid trace` alone, e.g.
#              --hybrid-no-flat-subtrees) and KDGRID_BUILD (above).
me=instr-count
# shellcheck source=scripts/measure-setup.sh
source "$(dirname "$0")/measure-setup.sh"
ray_cost_arguments "$@"
rows="${ROWS:-64}"
[[ "$res" =~ ^[0-9]+$ && "$rows" =~ ^[0-9]+$ && "$rows" -ge 1 && "$rows" -le "$res" ]] ||
  die "RES ($res) and ROWS ($rows) must be whole numbers with 1 <= ROWS <= RES"
set="${SET:-primary}"
[[ "$set" =~ ^(primary|shadow|diffuse)$ ]] || die "SET ($set) must be primary, shadow or diffuse"
source scripts/callgrind-build.sh
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
set_rays "$set" "$work/all.rays"
# The band: rows [res/2 - rows/2, +rows) of the square image (the primary set holds a ray per
# pixel in image order); for the shadow and diffuse sets, which hold a ray per pixel that hits,
# as many rays (or all, if fewer) from the middle of the file.
total=$("$python" scripts/rays_file.py count "$work/all.rays")
if [[ "$set" == primary ]]; then
  ((total == res * res)) || die "$work/all.rays: expected $((res * res)) rays, the header says $total"
  n=$((rows * res)) first=$((((res - rows) / 2) * res))
else
  n=$((rows * res < total ? rows * res : total))
  first=$(((total - n) / 2))
fi
"$python" scripts/rays_file.py cut "$work/all.rays" "$work/band.rays" "$first" "$n"
echo "Instructions per closest-hit ray (callgrind, AcceleratorBase::intersect inclusive), $(basename "$scene"), $([[ "$set" == primary ]] && echo "the middle $rows rows of ${res}x${res} primary rays" || echo "the middle $n of the ${res}x${res} image's $set rays") ($n rays)${TRACE_ARGS:+, trace options $TRACE_ARGS}, at $(git rev-parse --short HEAD)$(git diff --quiet -- src || echo ' (modified)')"
echo
echo "| structure | instructions per ray | hit fraction |"
echo "|---|---:|---:|"
for a in "${accel_list[@]}"; do
  [[ "$a" != embree ]] || die "embree is not counted here (see the usage); docs/CACHE-PROFILE.md has its instructions per ray"
  # shellcheck disable=SC2086
  valgrind --tool=callgrind --toggle-collect='kdgrid::AcceleratorBase<*>::intersect(kdgrid::Ray const&, kdgrid::Hit&) const' \
    --callgrind-out-file="$work/cg.$a" "$kdgrid" trace "$scene" --rays "$work/band.rays" --accel "$a" --threads 1 \
    --repeat 1 ${KDGRID_ARGS:-} ${TRACE_ARGS:-} > "$work/trace.$a" 2> "$work/valgrind.$a" ||
    { cat "$work/trace.$a" "$work/valgrind.$a" >&2; exit 1; }
  ir=$(sed -n 's/^summary: *\([0-9]*\).*/\1/p; s/^totals: *\([0-9]*\).*/\1/p' "$work/cg.$a" | head -1)
  hits=$(sed -n 's/^hit fraction *//p' "$work/trace.$a")
  awk -v a="$a" -v ir="$ir" -v n="$n" -v h="$hits" 'BEGIN { printf "| %s | %.1f | %s |\n", a, ir / n, h }'
done
