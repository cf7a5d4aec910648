#!/usr/bin/env bash
# Measures the interactive viewer for docs/RESULTS.md ("Viewer"): pass (progressive frame)
# time, UI frame time and Mrays/s at 1280x720 on the bunny and Sponza with the viewer's
# default structure, 2 threads, one sample per pixel per pass with shadows; the live
# rebuild of the full dragon with the hybrid at its automatic cell size; and the UI thread's
# frames on the full dragon under each overlay.
#
# kdgrid-viewer runs in its scripted mode under xvfb-run, so the OpenGL side is Mesa's
# llvmpipe (software): uploads and drawing run on the CPU. Each run writes --stats-json; this
# script gathers them into RESULTS_DIR/viewer.json and regenerates docs/RESULTS.md with
# scripts/bench-report over the results already there (it reruns nothing else).
#
# Usage: scripts/viewer-bench.sh [RESULTS_DIR]        (default docs/results)
# Environment:
#   KDGRID_SCENES    shared scenes (default ../shared/scenes beside the checkout)
#   VIEWER_PASSES    progressive passes per scene (default 16)
#   VIEWER_THREADS   render and build threads (default 2)
#   VIEWER_REBUILDS  dragon rebuild runs (default 3)
#   SKIP_BUILD=1     use the existing build/release
#   SKIP_REPORT=1    only write viewer.json
me="viewer-bench"
# shellcheck source=scripts/measure-setup.sh
source "$(dirname "$0")/measure-setup.sh"
results="${1:-docs/results}"
viewer="$root/build/release/src/viewer/kdgrid-viewer"
passes="${VIEWER_PASSES:-16}"
threads="${VIEWER_THREADS:-2}"

build_release ON
[[ -x "$viewer" ]] || die "$viewer not built (configure with the viewer on: cmake --preset release)"
command -v xvfb-run >/dev/null || die "xvfb-run missing (scripts/install-deps.sh)"
mkdir -p "$results"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
runs="$work/runs.tsv"
: >"$runs"

# One scripted viewer run on a fresh virtual display: NAME SCENE ARGS...
# The settings directory is a scratch one so no remembered user settings leak in.
run() {
  local name=$1 scene=$2
  shift 2
  if [[ ! -f "$scene" ]]; then
    echo "viewer-bench: $scene missing; skipping $name" >&2
    return 0
  fi
  local args=("$scene" --width 1280 --height 720 --threads "$threads" --timeout 900
              --stats-json "$work/$name.json" "$@")
  local shown="kdgrid-viewer ${args[*]}"
  shown="${shown//$scenes/\$KDGRID_SCENES}"
  shown="${shown//$work\//}"
  echo "== xvfb-run $shown" >&2
  local rc=0 load_before load_after
  # The machine may be shared: record its load next to each run.
  load_before=$(cut -d' ' -f1 /proc/loadavg)
  XDG_CONFIG_HOME="$work/config" LIBGL_ALWAYS_SOFTWARE=1 \
    xvfb-run -a -s "-screen 0 1920x1080x24" "$viewer" "${args[@]}" || rc=$?
  load_after=$(cut -d' ' -f1 /proc/loadavg)
  printf '%s\t%s\t%s\t%s\t%s\n' "$name" "$rc" "$load_before" "$load_after" "$shown" >>"$runs"
}

# The camera the benchmark suite uses for a scene (suite.json), as viewer flags; nothing for
# the canonical camera (which, for Sponza, would look at the outside of the building).
suite_camera() {
  "$python" - "$scenes/suite.json" "$1" <<'PY'
import json, sys
try:
    suite = json.load(open(sys.argv[1]))
except OSError:
    sys.exit(0)
for s in suite.get("scenes", []):
    c = s.get("camera")
    if s.get("name") == sys.argv[2] and c:
        print("--eye %s --target %s --fov %s" % (",".join(map(str, c["eye"])),
                                               ",".join(map(str, c["target"])), c["fov"]))
PY
}

# Throughput: the viewer's default structure, N passes of one sample per pixel each, from
# the suite's camera. The camera flags are meant to split into words.
# shellcheck disable=SC2046
run bunny "$scenes/bunny/bun_zipper.ply" --frames 1 --min-samples "$passes" --max-samples "$passes" \
  $(suite_camera bunny)
# shellcheck disable=SC2046
run sponza "$scenes/sponza_dabrovic/sponza.obj" --frames 1 --min-samples "$passes" --max-samples "$passes" \
  $(suite_camera sponza)
# Rebuild: after the first image the viewer rebuilds the hybrid at the automatic cell size
# off the UI thread. One pass only, so the render threads are idle during the rebuild.
# Repeated, as a build of 871K triangles is at the mercy of a shared machine's load.
for i in $(seq "${VIEWER_REBUILDS:-3}"); do
  run "dragon-rebuild-$i" "$scenes/dragon/dragon_vrip.ply" --accel hybrid --cell-size auto \
    --rebuild-cell-size auto --frames 1 --min-samples 1 --max-samples 1
done

# UI frames: the full dragon with the hybrid, a pick at the window's centre and each overlay
# in turn (none, split planes, cells, boxes, the steps heat map): how long the UI thread's
# frames take (frames.ui_ms) and which phase of its loop the longest ones spent it in
# (frames.phases).
for overlay in none splits cells boxes heatmap; do
  case "$overlay" in
    none) extra=() ;;
    heatmap) extra=(--heatmap steps) ;;
    *) extra=(--overlay "$overlay") ;;
  esac
  run "dragon-ui-$overlay" "$scenes/dragon/dragon_vrip.ply" --accel hybrid --pick 640,360 \
    --frames 60 --min-samples 2 --max-samples 2 "${extra[@]}"
done
"$python" - "$results/viewer.json" "$runs" "$work" "$threads" "$passes" <<'EOF'
import datetime, json, os, platform, subprocess, sys
out, runs, work, threads, passes = sys.argv[1:6]
def sh(cmd):
    try:
        return subprocess.run(cmd, shell=True, capture_output=True, text=True).stdout.strip()
    except Exception:
        return ""
doc = {
    "meta": {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "cpu": sh("lscpu | sed -n 's/^Model name: *//p' | head -1") or "unknown",
        "cores": sh("nproc"),
        "kernel": platform.release(),
        "commit": sh("git rev-parse --short HEAD") + (" (with local changes)" if sh("git status --porcelain --untracked-files=no") else ""),
        "display": "xvfb-run (Xvfb 1920x1080x24), LIBGL_ALWAYS_SOFTWARE=1",
        "threads": int(threads),
        "passes": int(passes),
    },
    "runs": [],
}
with open(runs) as f:
    for line in f:
        name, rc, load0, load1, cmd = line.rstrip("\n").split("\t", 4)
        path = os.path.join(work, name + ".json")
        entry = {"name": name, "command": cmd, "exit": int(rc),
                 "loadavg_1min": [float(load0), float(load1)]}
        if os.path.exists(path):
            with open(path) as s:
                entry["stats"] = json.load(s)
        doc["runs"].append(entry)
with open(out, "w") as f:
    json.dump(doc, f, indent=1)
print("wrote", out)
EOF

if [[ "${SKIP_REPORT:-0}" != 1 ]]; then
  "$python" scripts/bench-report "$results" --img-dir docs/img --out docs/RESULTS.md
fi
