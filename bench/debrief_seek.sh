#!/usr/bin/env bash
# Start and seek latency of a debrief on a 61 s recording, in a private
# loopback namespace (deploy/netns-run.sh): a real-time ligament session
# driven by the scripted station along bench/debrief-60s.path is recorded,
# then played with `cutsim-server --replay FILE --live` while a viewer
# renders at 60 Hz with a frame log. The start latency is from the debrief's
# launch to the first rendered frame of the recording (its checkpoints are
# made meanwhile). Once they are all made, 20 seeks to random times (seed
# fixed) are sent on its standard input; a seek's latency is from the
# command written to the first rendered frame at the target (± one 5 ms
# frame). Prints one line per seek, then a JSON line (kind debrief_seek):
# the start latency, the median and largest seek latency, the time the
# checkpoints took, and the targets. Exits 1 when a target is missed: the
# first picture within 2 s of the launch, every seek within 1 s.
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

rm -f "$out/commands" "$out/frames.log"
mkfifo "$out/commands"
# The viewer first: the start latency counts the debrief, not the viewer's.
"$bin/cutsim-viewer" --session seek --fps 60 --frame-log "$out/frames.log" --width 320 --height 240 \
  >"$out/viewer.out" 2>"$out/viewer.log" &
viewer=$!
sleep 1
launch_ns="$(python3 -c 'import time; print(time.monotonic_ns())')"
"$bin/cutsim-server" --replay "$out/session.lcm" --live --session seek --lcm-url "$url" --viewer-fps 60 \
  <"$out/commands" >"$out/debrief.json" 2>"$out/debrief.log" &
debrief=$!
exec 3>"$out/commands"
rc=0
python3 - "$out" "$launch_ns" <<'PY' || rc=$?
import json, random, sys, time
out, launch_ns = sys.argv[1], int(sys.argv[2])
cmd = open(f"{out}/commands", "w")
def send(line):
    t = time.monotonic_ns()  # CLOCK_MONOTONIC, as the frame log's mono_ns
    cmd.write(line + "\n"); cmd.flush()
    return t
def frames():
    try:
        return [l.split() for l in open(f"{out}/frames.log") if l.strip()]
    except FileNotFoundError:
        return []
def log_line(text):
    try:
        return next((l for l in open(f"{out}/debrief.log") if text in l), None)
    except FileNotFoundError:
        return None
# The first picture: the first frame the viewer rendered after the launch.
first, end = None, time.time() + 60
while first is None and time.time() < end:
    first = next(((int(f[4]) - launch_ns) / 1e9 for f in frames() if int(f[4]) > launch_ns), None)
    time.sleep(0.01)
print(f"first picture {first} s after the launch", flush=True)
# The seeks once every checkpoint is made (the producer's log line).
end = time.time() + 600
while log_line("checkpoints complete") is None and time.time() < end:
    time.sleep(0.2)
made = log_line("checkpoints complete")
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
targets = {"first_picture_s": 2.0, "seek_max_ms": 1000.0}
first_ok = first is not None and first <= targets["first_picture_s"]
seek_ok = s[-1] <= targets["seek_max_ms"]
print(json.dumps({"kind": "debrief_seek", "first_picture_s": None if first is None else round(first, 3),
                  "seeks": len(lat), "median_ms": round(s[len(s) // 2], 1), "max_ms": round(s[-1], 1),
                  "checkpoints": made.split("[info] ")[1].strip() if made else None,
                  "targets": targets, "pass": first_ok and seek_ok}))
sys.exit(0 if first_ok and seek_ok else 1)
PY
exec 3>&-
kill -INT "$debrief"; wait "$debrief" || true
kill -INT "$viewer"; wait "$viewer" || true
tail -1 "$out/debrief.json" >&2
exit "$rc"
