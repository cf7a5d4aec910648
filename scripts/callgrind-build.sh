# shellcheck shell=bash disable=SC2154  # $me is set by the caller
# Sourced by the callgrind scripts (instr-count.sh, cache-profile.sh, ray-cost-split.sh): checks
# that valgrind runs here and that the CPU runs x86-64-v3 code, builds build/callgrind (preset
# `callgrind`: x86-64-v3 with line info, as valgrind 3.19 decodes no AVX-512; a few minutes the
# first time) and sets $kdgrid to its CLI. Needs $me, the calling script's name for its errors,
# and the checkout as the working directory.
command -v valgrind >/dev/null || { echo "$me: valgrind not found: bash scripts/install-deps.sh (or apt-get install valgrind)" >&2; exit 1; }
grep -qw avx2 /proc/cpuinfo && grep -qw fma /proc/cpuinfo ||
  { echo "$me: the callgrind preset targets x86-64-v3 (AVX2, FMA); this CPU lacks them" >&2; exit 1; }
# KDGRID_BUILD: a build folder of the caller's choice, counted as it is (not rebuilt here).
if [[ -n "${KDGRID_BUILD:-}" ]]; then
  kdgrid="$(cd "$KDGRID_BUILD" && pwd)/src/cli/kdgrid"
  [[ -x "$kdgrid" ]] || { echo "$me: $kdgrid not built (KDGRID_BUILD=$KDGRID_BUILD)" >&2; exit 1; }
else
  cmake --preset callgrind >/dev/null
  cmake --build build/callgrind --target kdgrid -j "${KDGRID_JOBS:-$(nproc)}" >&2
  # shellcheck disable=SC2034  # read by the caller
  kdgrid="$(pwd)/build/callgrind/src/cli/kdgrid"
fi
# Highway (libhwy, loaded with OpenImageIO's image codecs) times the CPU's counter with RDTSCP
# while the library loads; valgrind 3.19 cannot run that instruction on a CPU whose flags do not
# list rdtscp, and stops the process before main ("unhandled instruction bytes: 0xF 0x1 0xF9").
# Where that happens, a one-function library preloaded in front of Highway's timer calibration
# keeps the instruction from running (kdgrid never uses Highway's timers).
if ! (valgrind --tool=none -q "$kdgrid" --help; exit $?) >/dev/null 2>&1; then
  shim="$(dirname "$(dirname "$(dirname "$kdgrid")")")/hwy-timer-shim.so"
  echo 'namespace hwy { namespace platform { unsigned long long TimerResolution() { return 1; } } }' |
    c++ -x c++ -shared -fPIC -O2 -o "$shim" -
  export LD_PRELOAD="$shim${LD_PRELOAD:+:$LD_PRELOAD}"
  (valgrind --tool=none -q "$kdgrid" --help; exit $?) >/dev/null 2>&1 ||
    { echo "$me: valgrind cannot run $kdgrid here (valgrind --tool=none $kdgrid --help shows why)" >&2; exit 1; }
  echo "$me: preloading $shim: valgrind cannot run Highway's RDTSCP on this CPU" >&2
fi
