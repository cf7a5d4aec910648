#!/usr/bin/env bash
# Downloads the benchmark suite's public scenes (the bunny, the dragon at full resolution and
# at Stanford's decimation level 2, the Dabrovic Sponza) from their original sites, checks
# each file's sha256, and writes the suite.json that `kdgrid bench --suite` reads.
#
# Usage: scripts/get-scenes.sh [DIR]
#   DIR: where the scenes go (default: $KDGRID_SCENES, else ../shared/scenes beside the
#   checkout, where kdgrid looks for them). A file already there with the right checksum is
#   kept; a file with another checksum is left alone and reported.
# Needs curl (or wget), tar, unzip (or python3) and sha256sum. Without a network connection it
# stops at the first download with a message naming the URL and what to do.
#
# The files and their terms (README.md, "Scenes"):
#   bunny/bun_zipper.ply, dragon/dragon_vrip.ply, dragon/dragon_vrip_res2.ply: the Stanford 3D
#     Scanning Repository (research use; credit the Stanford Computer Graphics Laboratory).
#   sponza_dabrovic/sponza.obj: the Sponza Atrium by Marko Dabrovic (CC BY-NC), the 66K-triangle
#     Max2Obj export of 2005, from the copy that the checksum below pins (the model's original
#     site is gone; Morgan McGuire's archive distributes a different export).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
if [[ $# -ge 1 ]]; then
  scenes="$1"
else
  source scripts/scenes-dir.sh
fi
say() { echo "get-scenes: $*" >&2; }

# name | URL | member to extract ("" = the download itself) | sha256 of the extracted file
files=(
  "bunny/bun_zipper.ply|http://graphics.stanford.edu/pub/3Dscanrep/bunny.tar.gz|bunny/reconstruction/bun_zipper.ply|b1acc63bece78444aa2e15bdcc72371a201279b98c6f5d4b74c993d02f0566fe"
  "dragon/dragon_vrip.ply|http://graphics.stanford.edu/pub/3Dscanrep/dragon/dragon_recon.tar.gz|dragon_recon/dragon_vrip.ply|fea87ff48f2aba22fb53e7b67c3ff3f7b8c2a3b3a0653af62c48bba67c6d5744"
  "dragon/dragon_vrip_res2.ply|http://graphics.stanford.edu/pub/3Dscanrep/dragon/dragon_recon.tar.gz|dragon_recon/dragon_vrip_res2.ply|f64cd2d043551ec82643d9987d1d26d35018238d501b346481e3b89d6e224da4"
  "sponza_dabrovic/sponza.obj|https://raw.githubusercontent.com/YangYuchu/cg/c16837cf16cc4afaafa920c609cd0291044ffb0a/sponza.zip|sponza.obj|5b4f8bc4f847aef7f0bd20bc3647f1d72843188c0a650d52ac8e0700c2e5f092"
)

for tool in tar sha256sum; do
  command -v "$tool" >/dev/null || { say "needs $tool; install it (scripts/install-deps.sh)"; exit 1; }
done
if command -v curl >/dev/null; then
  fetch() { curl -fsSL --retry 2 --connect-timeout 20 -o "$2" "$1"; }
elif command -v wget >/dev/null; then
  fetch() { wget -q --tries=2 --timeout=20 -O "$2" "$1"; }
else
  say "needs curl or wget to download the scenes; install one (apt-get install curl)"
  exit 1
fi
unzip_member() {  # zip member out
  if command -v unzip >/dev/null; then
    unzip -p "$1" "$2" >"$3"
  else
    python3 -c 'import sys, zipfile; sys.stdout.buffer.write(zipfile.ZipFile(sys.argv[1]).read(sys.argv[2]))' "$1" "$2" >"$3"
  fi
}
sha() { sha256sum "$1" | cut -d' ' -f1; }

mkdir -p "$scenes"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
declare -A downloaded=()
status=0
for entry in "${files[@]}"; do
  IFS='|' read -r name url member sum <<<"$entry"
  dest="$scenes/$name"
  if [[ -f "$dest" ]]; then
    if [[ "$(sha "$dest")" == "$sum" ]]; then
      say "$name: present, checksum ok"
      continue
    fi
    say "$dest exists with another sha256 than $sum; left alone: move it away and run again"
    status=1
    continue
  fi
  archive="${downloaded[$url]:-}"
  if [[ -z "$archive" ]]; then
    archive="$tmp/download.$(( ${#downloaded[@]} + 1 ))"
    say "downloading $url"
    if ! fetch "$url" "$archive"; then
      say "cannot download $url (no network connection, or the site is down): download it by" \
        "hand and extract $member to $dest, or set KDGRID_SCENES to a folder that holds the" \
        "scenes (README.md, \"Scenes\")"
      exit 1
    fi
    downloaded[$url]="$archive"
  fi
  out="$tmp/$(basename "$name")"
  case "$url" in
    *.tar.gz) tar -xzOf "$archive" "$member" >"$out" ;;
    *.zip) unzip_member "$archive" "$member" "$out" ;;
    *) cp "$archive" "$out" ;;
  esac
  got=$(sha "$out")
  if [[ "$got" != "$sum" ]]; then
    say "$name from $url has sha256 $got, not $sum: the download is not the file the suite" \
      "was measured on; not installed"
    status=1
    continue
  fi
  mkdir -p "$(dirname "$dest")"
  mv "$out" "$dest.part" && mv "$dest.part" "$dest"
  say "$name: installed, checksum ok"
done

if [[ ! -f "$scenes/suite.json" ]]; then
  cat >"$scenes/suite.json.part" <<'EOF'
{
  "about": "kdgrid benchmark suite: scene files relative to this folder; camera null = the canonical primary camera of docs/RAYSETS.md, else eye/target (up is +y), vertical fov in degrees",
  "scenes": [
    {"name": "bunny",  "file": "bunny/bun_zipper.ply",        "camera": null},
    {"name": "dragon", "file": "dragon/dragon_vrip.ply",      "camera": null},
    {"name": "dragon-200k", "file": "dragon/dragon_vrip_res2.ply", "camera": null},
    {"name": "sponza", "file": "sponza_dabrovic/sponza.obj",  "camera": {"eye": [-14, 3, 0], "target": [10, 5, 0], "fov": 60}}
  ]
}
EOF
  mv "$scenes/suite.json.part" "$scenes/suite.json"
  say "wrote $scenes/suite.json"
fi
[[ $status -eq 0 ]] && say "the suite's scenes are in $scenes (export KDGRID_SCENES=$scenes)"
exit $status
