#!/usr/bin/env bash
# Sets up (Debian packages), builds, and runs kdgrid's main job on the default scene
# assets/cornell.gltf: the interactive viewer when a display is available, otherwise a
# headless progressive render to out/cornell.png. Extra arguments go to the program.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh release
scene="${KDGRID_SCENE:-assets/cornell.gltf}"
if [ -x build/release/src/viewer/kdgrid-viewer ] && { [ -n "${DISPLAY:-}" ] || [ -n "${WAYLAND_DISPLAY:-}" ]; }; then
  exec build/release/src/viewer/kdgrid-viewer "$scene" "$@"
fi
echo "run: no display found (DISPLAY/WAYLAND_DISPLAY unset): rendering headless instead" >&2
mkdir -p out
build/release/src/cli/kdgrid render "$scene" -o out/cornell.png --spp 16 --res 640x480 "$@"
echo "run: wrote out/cornell.png"
