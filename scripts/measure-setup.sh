# shellcheck shell=bash disable=SC2154  # $me is set by the caller
# Sourced first by the measurement scripts, as `source "$(dirname "$0")/measure-setup.sh"`:
# sets bash's strict mode, goes to the checkout and sets $root to it, $scenes (scenes-dir.sh) and
# $python (Debian's, which has python3-matplotlib), and defines die, build_release, build_avx2,
# has_avx2, measured_commit, need_built, need_scenes, ray_cost_arguments and set_rays. Needs $me, the calling script's name for its
# errors.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck disable=SC2034  # read by scenes-dir.sh and the callers
root=$(pwd) python=/usr/bin/python3
source scripts/scenes-dir.sh

# Prints "$me: MESSAGE" on standard error and exits 1.
die() {
  echo "$me: $*" >&2
  exit 1
}

# Builds build/release with the viewer ON or OFF ($1), unless SKIP_BUILD=1.
build_release() {
  [[ "${SKIP_BUILD:-0}" == 1 ]] || bash scripts/build.sh release -DKDGRID_BUILD_VIEWER="$1"
}

# Builds the CLI of build/avx2 (preset avx2: x86-64-v3, as a CPU without AVX-512 runs it),
# unless SKIP_BUILD=1.
build_avx2() {
  [[ "${SKIP_BUILD:-0}" == 1 ]] && return 0
  cmake --preset avx2 >/dev/null
  cmake --build build/avx2 -j "${KDGRID_JOBS:-$(nproc)}" --target kdgrid
}

# True when this CPU runs the avx2 preset's code (AVX2 and FMA).
has_avx2() {
  grep -qw avx2 /proc/cpuinfo && grep -qw fma /proc/cpuinfo
}

# Prints the commit measured: HEAD, marked "(with local changes)" when a tracked file outside
# docs/ differs from it (the pages and results the scripts write are not what is measured).
measured_commit() {
  local c
  c="$(git rev-parse --short HEAD)"
  if [[ -n "$(git status --porcelain --untracked-files=no -- . ':!docs')" ]]; then
    c+=" (with local changes)"
  fi
  echo "$c"
}

# The arguments of the scripts that measure a ray's cost by structure and ray set, SCENE ACCELS
# SETS: $scene (default the full dragon, which must exist), $accel_list and $set_list (from
# comma-separated lists; default kdtree,hybrid and primary,shadow,diffuse); and $res, the side
# of their ray sets' images ($RES, default 1024).
ray_cost_arguments() {
  scene="${1:-$scenes/dragon/dragon_vrip.ply}"
  res="${RES:-1024}"
  IFS=, read -ra accel_list <<< "${2:-kdtree,hybrid}"
  IFS=, read -ra set_list <<< "${3:-primary,shadow,diffuse}"
  [[ -f "$scene" ]] || die "scene $scene not found; pass a scene file or set KDGRID_SCENES"
}

# Stops unless $1, a program of the build, has been built.
need_built() {
  [[ -x "$1" ]] || die "$1 not built: bash scripts/build.sh release"
}

# Stops unless $1, a file or folder of the shared scenes, exists.
need_scenes() {
  [[ -e "$1" ]] || die "$1 not found; set KDGRID_SCENES to the shared scenes"
}

# Writes ray set $1 of $scene at $res x $res, with the camera options of $KDGRID_ARGS, to the
# .rays file $2 with the CLI $kdgrid.
set_rays() {
  # shellcheck disable=SC2086
  "$kdgrid" rays "$scene" --set "$1" --res "$res" -o "$2" ${KDGRID_ARGS:-} >/dev/null
}
