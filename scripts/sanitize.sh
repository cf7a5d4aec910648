#!/usr/bin/env bash
# Sanitizer runs for CI and developers.
#   scripts/sanitize.sh address   the whole test suite under ASan+UBSan (viewer not built)
#   scripts/sanitize.sh thread    the render/upload hand-over and the live rebuild under TSan:
#                                 a scripted viewer run (render worker, UI thread, rebuild
#                                 thread, a load through the drop handler, cancel on every
#                                 change, wake-ups of the sleeping UI) with a pick under Xvfb
# Brute-force references are shared with the release build's cache when it exists (CI runs
# the release suite first, so no reference is recomputed under a sanitizer).
# Sanitizer builds are -O1 (CMakeLists.txt). Cost on 2 cores with no compiler cache (measured):
# address, build 551 s and suite 958 s of wall time, about 25 minutes (at -O3 the build alone
# took 31 CPU-min); thread, build and a 15 s viewer run 112 s. The
# address run is the whole suite but the viewer tests (the viewer is not built): it fits CI's
# budget, so nothing is left out; big scanned meshes (bunny, dragon) cost the most there, in
# kd-tree builds, not in brute force.
set -euo pipefail
cd "$(dirname "$0")/.."
kind="${1:?usage: scripts/sanitize.sh address|thread}"
jobs="${KDGRID_JOBS:-$(nproc)}"
if [ -d build/release/reference-cache ]; then
  export KDGRID_REFERENCE_CACHE="$PWD/build/release/reference-cache"
fi
case "$kind" in
  address)
    cmake --preset asan >/dev/null
    cmake --build build/asan -j "$jobs" --target kdgrid_tests kdgrid
    # ctest starts the costliest tests first when it knows their cost; the release run's times
    # rank the tests as they rank under ASan, so the longest ones do not start last.
    costs=Testing/Temporary/CTestCostData.txt
    if [ -f "build/release/$costs" ] && [ ! -f "build/asan/$costs" ]; then
      mkdir -p "$(dirname "build/asan/$costs")"
      cp "build/release/$costs" "build/asan/$costs"
    fi
    # intercept_tls_get_addr=0: Debian 12's LeakSanitizer can read a bogus dynamic-TLS range of
    # a library loaded at run time (the OpenImageIO module's threads) and crash at exit
    # ("Tracer caught signal 11", "DTLS ... at 0x2d8d"), depending on the test binary's layout;
    # leaks are still found, dynamic TLS is just not scanned as a root.
    export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1:intercept_tls_get_addr=0" \
      UBSAN_OPTIONS="print_stacktrace=1"
    # Embree's own code is not instrumented: its extreme-ray instances add nothing here.
    ctest --test-dir build/asan --output-on-failure -j "$jobs" \
      -E '^(Viewer|Portability)\.|^AllStructures/ExtremeRayFamilies\..*/embree$'
    ;;
  thread)
    cmake --preset tsan >/dev/null
    cmake --build build/tsan -j "$jobs" --target kdgrid-viewer
    # Debian's oneTBB is not instrumented, so TSan cannot see a parallel_for join; the
    # threads under test are the render worker, the UI thread and the rebuild thread, which
    # are exercised with one TBB worker.
    export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 suppressions=$PWD/src/viewer/tsan.supp"
    LIBGL_ALWAYS_SOFTWARE=1 xvfb-run -a -s '-screen 0 1280x1024x24' \
      build/tsan/src/viewer/kdgrid-viewer assets/cornell.gltf --threads 1 --accel bvh \
      --width 320 --height 240 --frames 10 --min-samples 3 --rebuild-cell-size 0.5 \
      --pick 160,120 --overlay boxes --heatmap steps --drop assets/cornell.gltf \
      --screenshot build/tsan/tsan-viewer.png
    echo "tsan: viewer run with live rebuild and a dropped scene: no data races reported"
    ;;
  *) echo "usage: scripts/sanitize.sh address|thread" >&2; exit 2 ;;
esac
