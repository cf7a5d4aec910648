#!/usr/bin/env bash
# Measures the viewer's live picture while flying (docs/VIEWER.md, "Measured: previews while
# flying"): the viewer in a WxH window on Xvfb (Mesa llvmpipe), W held for SECONDS by xdotool,
# then the preview passes recorded in --stats-json are summarised: previews shown per second,
# motion to photon (input to the upload of the first picture that shows it), preview pass time
# and width. Extra flags go to the viewer: `--rebuild-cell-size auto` starts a rebuild once the
# first picture is shown, so the flight runs on the old structure while it builds.
#
# Usage: scripts/viewer-flight.sh SCENE [ACCEL] [extra viewer flags...]
# Environment: RES (default 1280x720), THREADS (default 2), SECONDS_HELD (default 2),
#              WAIT (seconds between the scene showing and the flight; default 1),
#              OUT (folder for stats.json and the log; default a temporary one)
set -euo pipefail
cd "$(dirname "$0")/.."
scene="${1:?usage: scripts/viewer-flight.sh SCENE [ACCEL] [viewer flags...]}"
accel="${2:-bvh}"
shift $(( $# >= 2 ? 2 : 1 ))
res="${RES:-1280x720}"
threads="${THREADS:-2}"
held="${SECONDS_HELD:-2}"
out="${OUT:-$(mktemp -d)}"
mkdir -p "$out"
viewer="$PWD/build/release/src/viewer/kdgrid-viewer"
[ -x "$viewer" ] || { echo "build first: bash scripts/build.sh release" >&2; exit 2; }
w="${res%x*}"
h="${res#*x}"
title="kdgrid-viewer - $(basename "$scene")"
cat > "$out/drive.sh" <<EOF
#!/bin/bash
set -u
cd '$out'
'$viewer' '$scene' --accel $accel --threads $threads --width $w --height $h --hide-ui --hold 300 \
  --stats-json stats.json $* > viewer.log 2>&1 &
pid=\$!
wid=\$(timeout 120 xdotool search --sync --name '$title' | head -1)
xdotool windowfocus --sync "\$wid"
sleep ${WAIT:-1}
xdotool keydown w; sleep $held; xdotool keyup w
sleep 0.5
xdotool key --clearmodifiers ctrl+q
wait \$pid
EOF
LIBGL_ALWAYS_SOFTWARE=1 XDG_CONFIG_HOME="$out" timeout -k 10 600 \
  xvfb-run -a -s "-screen 0 ${w}x${h}x24 -noreset" bash "$out/drive.sh"
/usr/bin/python3 - "$out/stats.json" "$held" <<'EOF'
import json, statistics, sys
s = json.load(open(sys.argv[1]))
held = float(sys.argv[2])
prev = [p for p in s.get("passes", []) if p.get("preview")]
if not prev:
    sys.exit("no preview passes recorded: was the window focused?")
def q(v, f):
    v = sorted(v); return v[min(len(v) - 1, int(f * len(v)))]
shown = sorted(p["shown_at"] for p in prev if "shown_at" in p)
span = shown[-1] - shown[0] if len(shown) > 1 else held
lat = [p["latency_ms"] for p in prev if p.get("latency_ms") is not None]
ps = [1000 * p["seconds"] for p in prev if "seconds" in p]
wd = [p["width"] for p in prev if "width" in p]
print(f"previews {len(prev)}, {(len(shown) - 1) / span if span > 0 else 0:.1f} per second")
if lat: print(f"motion to photon median {statistics.median(lat):.0f} ms (p90 {q(lat, 0.9):.0f})")
if ps: print(f"preview pass median {statistics.median(ps):.0f} ms")
if wd: print(f"preview width median {statistics.median(wd):.0f} ({min(wd)}-{max(wd)})")
EOF
