#!/usr/bin/env bash
# Sets up (Debian packages), builds and runs the whole test suite with ctest.
# Shared scenes are found through $KDGRID_SCENES or ../shared/scenes beside the checkout;
# tests that need a missing scene are skipped and say why.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh release
ctest --test-dir build/release --output-on-failure -j "${KDGRID_JOBS:-$(nproc)}" "$@"
