#!/usr/bin/env bash
# Seek latency of a debrief on a 61 s recording, in a private loopback
# namespace (deploy/netns-run.sh): a real-time ligament session driven by
# the scripted station along bench/debrief-60s.path is recorded, played with
# `cutsim-server --replay FILE --live`, and 20 seeks to random times (seed
# fixed) are sent on its standard input while a viewer renders at 60 Hz with
# a frame log. A seek's latency is from the command written to the first
# rendered frame at the target (± one 5 ms frame). Prints one line per seek,
# then a JSON line: median and largest latency, the pre-pass's time, the
# debrief's own summary (hash checks against the live session).
#
#   bench/debrief_seek.sh [BUILD_BIN_DIR] [OUT_DIR]     (default build/ci/bin)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bin="$(cd "${1:-$root/build/ci/bin}" && pwd)"
if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$root/deploy/netns-run.sh" "$0" "$@"
fi
out="${2:-$(mktemp -d /tmp/cutsim-debrief-seek.XXXXXX)}"
mkdir -p "$out"
cd "$root"
url="udpm://239.255.76.67:7953?ttl=0"

"$bin/cutsim-server" --scene scenes/ligament.pbtxt --session rec --duration 61 --no-rt --lcm-url "$url" \
  --record "$out/session.lcm" >"$out/live.json" 2>"$out/live.log" &
live=$!
sleep 1
"$bin/cutsim-haptic" --device scripted --path bench/debrief-60s.path --session rec --lcm-url "$url" --no-rt \
  >"$out/haptic.json" 2>"$out/haptic.log"
wait "$live"

rm -f "$out/commands"
mkfifo "$out/commands"
"$bin/cutsim-server" --replay "$out/session.lcm" --live --session seek --lcm-url "$url" --viewer-fps 60 \
  <"$out/commands" >"$out/debrief.json" 2>"$out/debrief.log" &
debrief=$!
exec 3>"$out/commands"
"$bin/cutsim-viewer" --session seek --fps 60 --frame-log "$out/frames.log" --width 320 --height 240 \
  >"$out/viewer.out" 2>"$out/viewer.log" &
viewer=$!
for _ in $(seq 3000); do grep -q 'to observers on DDS' "$out/debrief.log" 2>/dev/null && break; sleep 0.2; done
sleep 2
python3 - "$out" <<'PY'
import json, random, sys, time
out = sys.argv[1]
cmd = open(f"{out}/commands", "w")
def send(line):
    t = time.monotonic_ns()  # CLOCK_MONOTONIC, as the frame log's mono_ns
    cmd.write(line + "\n"); cmd.flush()
    return t
def frames():
    return [l.split() for l in open(f"{out}/frames.log") if l.strip()]
send("pause"); time.sleep(0.5)
random.seed(7)
lat = []
for t in [round(random.uniform(0, 61), 2) for _ in range(20)]:
    since = send(f"seek {t}")
    hit, end = None, time.time() + 5
    while hit is None and time.time() < end:
        hit = next(((int(f[4]) - since) / 1e6 for f in frames()
                    if int(f[4]) > since and abs(float(f[3]) - t) <= 0.0051), None)
        time.sleep(0.005)
    lat.append(hit if hit is not None else float("inf"))
    print(f"seek {t:6.2f} s: {hit} ms", flush=True)
    time.sleep(0.3)
s = sorted(lat)
prepass = next(l for l in open(f"{out}/debrief.log") if "pre-pass " in l and "debrief of" in l)
print(json.dumps({"seeks": len(lat), "median_ms": round(s[len(s) // 2], 1), "max_ms": round(s[-1], 1),
                  "prepass": prepass.split("[info] ")[1].strip()}))
PY
exec 3>&-
kill -INT "$debrief"; wait "$debrief" || true
kill -INT "$viewer"; wait "$viewer" || true
tail -1 "$out/debrief.json"
