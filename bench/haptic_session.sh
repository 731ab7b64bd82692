#!/usr/bin/env bash
# Haptic loop timing and link latency with the real server's physics loading
# the other core, beside a bare clock_nanosleep loop measured in the same run.
# Runs inside a private loopback namespace (deploy/netns-run.sh).
#   bench/haptic_session.sh BIN_DIR OUT_DIR SECONDS
set -euo pipefail
bin="$1"; out="$2"; seconds="${3:-20}"
root="$(cd "$(dirname "$0")/.." && pwd)"
# shellcheck source=bench/wait_for_server.sh
source "$root/bench/wait_for_server.sh"
if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$root/deploy/netns-run.sh" "$0" "$@"
fi
# Back-and-forth strokes across the ligament's top (cutting it on the way).
/usr/bin/python3 - "$out/strokes.path" "$seconds" <<'PY'
import sys
path, seconds = sys.argv[1], float(sys.argv[2])
with open(path, "w") as f:
    f.write("# t tip_x tip_y tip_z dir_x dir_y dir_z\n")
    t, k = 0.0, 0
    while t <= seconds:
        y = -0.008 if k % 2 == 0 else 0.008
        f.write(f"{t:.3f} 0.0151 {y} -0.006 0 0 1\n")
        t += 2.0
        k += 1
PY
"$bin/cutsim-server" --scene "$root/scenes/ligament.pbtxt" --threads 1 --duration 86400 \
  --stats-json "$out/haptic_server.json" >/dev/null 2>"$out/haptic_server.log" &
server=$!
# The client starts once the server's session is up (its start-up log line).
wait_for_server "$out/haptic_server.log" "$server" 60
"$bin/cutsim-haptic" --device scripted --path "$out/strokes.path" --csv "$out/haptic.csv" \
  >"$out/haptic_loop.json" 2>"$out/haptic_loop.log"
kill -TERM "$server"; wait "$server" || true
# The bare loop with a busy thread on the other core, for reference.
"$bin/cutsim-haptic-loop-bench" --seconds "$seconds" --hog >"$out/haptic_bare.json" 2>"$out/haptic_bare.log"
# One JSON line: the numbers bench/README.md quotes. pose_to_model_ms is the
# target's metric: the device read of a pose (client CLOCK_MONOTONIC) to the
# client's LCM thread accepting the model the server computed from that pose
# (same clock, one host); pose_to_use_ms runs on to the first haptic tick that
# renders it (+ up to one 1 ms tick). The server's own view beside them, and
# the 1-minute load average at the end (the machine is shared).
/usr/bin/python3 - "$out" <<'PY'
import json, sys
out = sys.argv[1]
srv = json.load(open(f"{out}/haptic_server.json"))
hap = json.load(open(f"{out}/haptic_loop.json"))
bare = json.load(open(f"{out}/haptic_bare.json"))
def q(d, k):
    v = d.get(k, {})
    return {p: v.get(p) for p in ("p50", "p99", "max") if isinstance(v, dict)}
frames = max(1, srv["frames"])
print(json.dumps({
    "kind": "haptic_session",
    "pose_to_model_ms": q(hap, "pose_to_model_ms"),
    "pose_to_use_ms": q(hap, "pose_to_use_ms"),
    "model_age_ms": q(hap, "model_age_ms"),
    "server_pose_to_model_ms": {"p50": srv.get("pose_to_model_p50_ms"), "p99": srv.get("pose_to_model_p99_ms")},
    "server_receive_to_model_ms": {"p50": srv.get("receive_to_model_p50_ms"), "p99": srv.get("receive_to_model_p99_ms")},
    "server_frame_ms": {"p50": srv["frame_time_p50_ms"], "p99": srv["frame_time_p99_ms"], "max": srv["frame_time_max_ms"]},
    "overrun_percent": round(100.0 * srv["frame_overruns"] / frames, 2),
    "haptic_jitter_us": q(hap, "jitter_us"),
    "bare_jitter_us": q(bare, "jitter_us"),
    "missed_deadlines": hap.get("missed_deadlines"),
    "loadavg_1min": float(open("/proc/loadavg").read().split()[0]),
}))
PY
