#!/usr/bin/env bash
# Installs every Debian 12 package kdgrid needs to build, test, run the viewer
# headless (Xvfb + Mesa) and plot benchmark results. Non-interactive and idempotent:
# packages already present are left alone, and apt is only called when one is missing.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config git
  # core
  libtbb-dev libembree-dev libopenimageio-dev openimageio-tools
  libtinygltf-dev libtinyobjloader-dev nlohmann-json3-dev libstb-dev
  libcli11-dev libglm-dev
  # tests
  libgtest-dev googletest
  # viewer
  libglfw3-dev libimgui-dev libepoxy-dev libgl-dev
  xvfb xauth libgl1-mesa-dri libglx-mesa0 mesa-utils
  # viewer input tests: xdotool drives the window, xrdb sets Xft.dpi for the HiDPI test
  xdotool x11-xserver-utils
  # fuzzing and sanitizers (clang's libFuzzer runtime)
  clang libclang-rt-14-dev
  # scripts/format.sh (checked in CI)
  clang-format-14
  # scripts/cache-profile.sh: callgrind's cache and branch simulation
  valgrind
  # scripts/time-split.sh: perf's samples of the native build
  linux-perf
  # plots
  python3-matplotlib python3-numpy
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages already installed"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "install-deps: need root (or sudo) to install: ${missing[*]}" >&2; exit 1; fi
fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
