#!/usr/bin/env bash
# The big-scene test: a generated 10-million-triangle landscape must build and
# render within memory with every structure, or fail fast with a clear message.
#
# For each structure, in its own process (so each peak resident set is its own):
#   kdgrid render gen:landscape:N --accel X --res R --spp 1 --stats-json ...
# recording build seconds, structure bytes, the estimate the memory guard made before
# allocating, the peak RSS of the load and of the build (VmHWM, reset between phases), the
# process's max RSS as /usr/bin/time sees it, and the render time, or the refusal message and
# how long it took to come. Brute force is first asked for the full resolution (it must refuse
# by its work limit), then renders a tiny image. The scene is generated in memory; the PLY
# writer is timed separately with `kdgrid gen`.
#
# Usage: scripts/big-scene.sh [OUT_JSON]          (default docs/results/big-scene.json)
# Environment:
#   BIG_TRIANGLES   triangles (default 10000000)
#   BIG_RES         render resolution, pixels per side (default 256)
#   BIG_BRUTE_RES   brute force's resolution after its refusal (default 16)
#   BIG_ACCELS      structures (default: brute bvh kdtree grid hybrid irregular embree)
#   BIG_TIMEOUT     seconds allowed per structure (default 1800)
#   BIG_BUDGET_MB   --memory-budget-mb for every run (default 0 = half of physical memory)
#   BIG_TIGHT_MB    then every structure again with this budget (default 512; 0 = skip), to
#                   show which refuse and how fast (res BIG_TIGHT_RES, default 64)
#   BIG_IMAGE       structure whose render is kept as docs/img/big-scene.png (default bvh;
#                   empty = none)
#   SKIP_BUILD=1    use the existing build/release
#   SKIP_PLY=1      do not time the PLY writer
# Then scripts/bench-report docs/results shows the figures in docs/RESULTS.md.
me=big-scene
# shellcheck source=scripts/measure-setup.sh
source "$(dirname "$0")/measure-setup.sh"
out_json="${1:-docs/results/big-scene.json}"
kdgrid="$root/build/release/src/cli/kdgrid"
n="${BIG_TRIANGLES:-10000000}"
res="${BIG_RES:-256}"
brute_res="${BIG_BRUTE_RES:-16}"
accels="${BIG_ACCELS:-brute bvh kdtree grid hybrid irregular embree}"
limit="${BIG_TIMEOUT:-1800}"
budget="${BIG_BUDGET_MB:-0}"
tight="${BIG_TIGHT_MB:-512}"
tight_res="${BIG_TIGHT_RES:-64}"
keep_image="${BIG_IMAGE-bvh}"

build_release OFF
need_built "$kdgrid"
tmp=$(mktemp -d "${TMPDIR:-/tmp}/kdgrid-big.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$(dirname "$out_json")"
scene="gen:landscape:$n"
runs="$tmp/runs.jsonl"
: >"$runs"

mem_available() { awk '/MemAvailable/ {print $2}' /proc/meminfo; }  # kB

# One render in its own process. Writes one JSON line to $runs with what happened.
measure() {
  local accel=$1 r=$2 tag=$3 mb=${4:-$budget}
  local stats="$tmp/$tag.json" log="$tmp/$tag.log" timefile="$tmp/$tag.time" png="$tmp/$tag.png"
  local avail t0 t1 rc=0
  avail=$(mem_available)
  echo "== $tag: kdgrid render $scene --accel $accel --res $r --spp 1 --memory-budget-mb $mb" >&2
  t0=$(date +%s.%N)
  /usr/bin/time -f '%M %e' -o "$timefile" timeout "$limit" "$kdgrid" render "$scene" \
    --accel "$accel" --res "$r" --spp 1 --memory-budget-mb "$mb" -o "$png" \
    --stats-json "$stats" >"$log" 2>&1 || rc=$?
  t1=$(date +%s.%N)
  tr '\r' '\n' <"$log" | grep -v '^\[' | grep -v '^$' >&2 || true
  if [[ -n "$keep_image" && "$tag" == "$keep_image" && -f "$png" ]]; then
    mkdir -p docs/img
    cp "$png" docs/img/big-scene.png
  fi
  "$python" - "$accel" "$r" "$tag" "$rc" "$t0" "$t1" "$avail" "$stats" "$log" "$timefile" \
    "$limit" "$mb" >>"$runs" <<'EOF'
import json, os, sys
accel, res, tag, rc, t0, t1, avail, stats, log, timefile, limit, mb = sys.argv[1:]
rec = {"accel": accel, "tag": tag, "res": int(res), "exit": int(rc), "budget_mb": int(mb),
       "wall_seconds": float(t1) - float(t0), "mem_available_before_bytes": int(avail) * 1024}
try:
    kb, _ = open(timefile).read().split()[-2:]
    rec["time_max_rss_bytes"] = int(kb) * 1024
except Exception:
    pass
if os.path.exists(stats) and int(rc) == 0:
    rec["stats"] = json.load(open(stats))
text = open(log, errors="replace").read().replace("\r", "\n")
errors = [l[len("kdgrid: error: "):] for l in text.splitlines() if l.startswith("kdgrid: error: ")]
if errors:
    rec["error"] = errors[-1]
elif int(rc) in (124, 137):
    rec["error"] = "timed out after %s s" % limit
elif int(rc) != 0:
    rec["error"] = "exit code %s: %s" % (rc, text.strip().splitlines()[-1] if text.strip() else "")
print(json.dumps(rec))
EOF
}

# The PLY writer and its file, timed once.
gen_seconds=0
ply_bytes=0
if [[ "${SKIP_PLY:-0}" != 1 ]]; then
  echo "== kdgrid gen landscape --triangles $n -o landscape.ply" >&2
  t0=$(date +%s.%N)
  "$kdgrid" gen landscape --triangles "$n" -o "$tmp/landscape.ply" >&2
  t1=$(date +%s.%N)
  gen_seconds=$(echo "$t1 - $t0" | bc)
  ply_bytes=$(stat -c %s "$tmp/landscape.ply")
  rm -f "$tmp/landscape.ply"
fi

for a in $accels; do
  if [[ "$a" == brute ]]; then
    measure brute "$res" brute-full      # must refuse: rays x triangles above the work limit
    measure brute "$brute_res" brute     # and render a tiny image instead
  else
    measure "$a" "$res" "$a"
  fi
done
# The same scene under a tight budget: the structures that cannot fit must say so quickly.
if [[ "$tight" != 0 ]]; then
  for a in $accels; do
    [[ "$a" == brute ]] && continue
    measure "$a" "$tight_res" "$a-tight" "$tight"
  done
fi

"$python" - "$runs" "$out_json" "$n" "$res" "$brute_res" "$gen_seconds" "$ply_bytes" \
  "$budget" "$root" <<'EOF'
import datetime, json, os, platform, subprocess, sys
runs_path, out_path, n, res, brute_res, gen_s, ply_bytes, budget, root = sys.argv[1:]
runs = [json.loads(l) for l in open(runs_path) if l.strip()]

def sh(cmd):
    try:
        return subprocess.check_output(cmd, shell=True, text=True, cwd=root).strip()
    except Exception:
        return ""

cpu = ""
for line in open("/proc/cpuinfo"):
    if line.startswith("model name"):
        cpu = line.split(":", 1)[1].strip()
        break
mem = ""
for line in open("/proc/meminfo"):
    if line.startswith("MemTotal"):
        mem = "%.1f GiB" % (int(line.split()[1]) / 2**20)
meta = {"scene": "gen:landscape:%s" % n, "triangles": int(n), "res": int(res),
        "brute_res": int(brute_res), "spp": 1, "memory_budget_mb": int(budget),
        "ply_write_seconds": float(gen_s), "ply_bytes": int(ply_bytes),
        "date": datetime.datetime.now().isoformat(timespec="seconds"), "cpu": cpu,
        "cores": os.cpu_count(), "memory": mem, "kernel": platform.release(),
        "commit": sh("git rev-parse --short HEAD") + (" (modified)" if sh("git status --porcelain --untracked-files=no -- src tests scripts CMakeLists.txt") else ""),
        "command": "scripts/big-scene.sh"}
with open(out_path, "w") as f:
    json.dump({"meta": meta, "runs": runs}, f, indent=2)
    f.write("\n")

def mib(b):
    return "%.0f" % (b / 2**20) if b is not None else "-"

print("\n%s triangles, %sx%s, 1 spp (brute: %sx%s)\n" % (n, res, res, brute_res, brute_res))
print("%-10s %6s %6s %9s %9s %11s %11s %11s %9s  %s" % ("structure", "budget", "res", "build s", "MiB",
      "estim. MiB", "build peak", "max RSS", "render s", "outcome"))
for r in runs:
    s = r.get("stats", {})
    peak = (s["rss_build_peak_bytes"] - s["rss_before_build_bytes"]) if s else None
    outcome = "ok" if "error" not in r else "refused after %.1f s: %s" % (r["wall_seconds"], r["error"][:90])
    print("%-10s %6s %6d %9s %9s %11s %11s %11s %9s  %s" % (
        r["accel"], r["budget_mb"] or "auto", r["res"], "%.2f" % s["build_seconds"] if s else "-",
        mib(s.get("bytes")) if s else "-", mib(s.get("peak_estimate_bytes")) if s else "-",
        mib(peak), mib(r.get("time_max_rss_bytes")),
        "%.2f" % s["render_seconds"] if s else "-", outcome))
print("\nwrote", out_path)
EOF
