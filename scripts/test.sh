#!/usr/bin/env bash
# Sets up (Debian packages), builds and runs the whole test suite with ctest.
# Shared scenes are found through $KDGRID_SCENES or ../shared/scenes beside the checkout;
# tests that need a missing scene are skipped and say why.
# With CI=true (as CI services set it) the build treats warnings as errors (KDGRID_WERROR), so
# CI fails on any warning while a user's newer compiler only warns.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
if [ "${CI:-}" = true ]; then
  bash scripts/build.sh release -DKDGRID_WERROR=ON
else
  bash scripts/build.sh release
fi
ctest --test-dir build/release --output-on-failure -j "${KDGRID_JOBS:-$(nproc)}" "$@"
