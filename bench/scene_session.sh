#!/usr/bin/env bash
# A real-time session on a shipped scene: cutsim-server (real-time loop,
# normal priority) and cutsim-haptic with the scripted device on the scene's
# cut path, in a private loopback namespace (deploy/netns-run.sh). Prints one
# JSON line with the server's frame overruns, frame times and tool-pose-to-
# model latency, the cuts made, and the targets; exits 1 when a target is
# missed, 77 when no namespace can be made.
#   bench/scene_session.sh BIN_DIR OUT_DIR SCENE PATH SECONDS
# SCENE and PATH are relative to scenes/ (../bench/scenes/organ_large.pbtxt
# for the ~109k-tet organ, which has no timing target: reported, must cut).
# Targets: block — no overruns after the session's first second and
# pose-to-model p99 ≤ 6 ms; organ — ≤ 1 % overruns, frame p99 ≤ 25 ms,
# pose-to-model p99 ≤ one frame + 2 ms and ≥ 8 cut steps; both cut.
set -euo pipefail
bin="$1"; out="$2"; scene="$3"; path="$4"; seconds="$5"
root="$(cd "$(dirname "$0")/.." && pwd)"
# shellcheck source=bench/wait_for_server.sh
source "$root/bench/wait_for_server.sh"
if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$root/deploy/netns-run.sh" "$0" "$@"
fi
name="$(basename "$scene" .pbtxt)"
log="$out/session_$name"
"$bin/cutsim-server" --scene "$root/scenes/$scene" --session "bench-$name" --no-rt --duration "$seconds" \
  --stats-json "$log-server.json" >/dev/null 2>"$log-server.log" &
server=$!
# The client starts once the server's session is up (its start-up log line;
# the organ's mesh is generated and settled first).
wait_for_server "$log-server.log" "$server" 300
"$bin/cutsim-haptic" --session "bench-$name" --device scripted --no-rt --path "$root/scenes/$path" \
  >"$log-haptic.json" 2>"$log-haptic.log"
wait "$server" || true
/usr/bin/python3 - "$log" "$name" <<'PY'
import json, sys
log, name = sys.argv[1], sys.argv[2]
srv = json.load(open(f"{log}-server.json"))
frames = max(1, srv["frames"])
frame_ms = 1e3 * srv["sim_time"] / frames
overrun = 100.0 * srv["frame_overruns"] / frames
p99 = srv["pose_to_model_p99_ms"]
late = srv.get("frame_overruns_after_first_second", 0)
if name == "organ":
    targets = {"overrun_percent_max": 1.0, "frame_p99_ms_max": 25.0,
               "pose_to_model_p99_ms_max": frame_ms + 2.0, "cuts_min": 8}
    met = overrun <= targets["overrun_percent_max"] and srv["frame_time_p99_ms"] <= targets["frame_p99_ms_max"]
elif name == "organ_large":
    # Reported, no timing target: the session must run and cut.
    targets = {"cuts_min": 1}
    met = True
else:
    targets = {"overruns_after_first_second_max": 0, "pose_to_model_p99_ms_max": 6.0, "cuts_min": 1}
    met = late <= targets["overruns_after_first_second_max"]
met = met and p99 <= targets.get("pose_to_model_p99_ms_max", p99) and srv.get("cuts", 0) >= targets["cuts_min"] \
    and srv.get("status") == "ok"
print(json.dumps({
    "kind": "scene_session", "scene": name, "frame_ms": round(frame_ms, 3), "frames": srv["frames"],
    "overrun_percent": round(overrun, 2), "overruns_after_first_second": late,
    "frame_time_ms": {"p50": srv["frame_time_p50_ms"], "p99": srv["frame_time_p99_ms"],
                      "max": srv["frame_time_max_ms"]},
    "pose_to_model_ms": {"p50": srv["pose_to_model_p50_ms"], "p99": p99},
    "cuts": srv.get("cuts", 0), "status": srv.get("status"), "targets": targets, "met": met,
    "implicit": {k: srv.get(k, 0) for k in ("out_of_time_steps", "over_budget_steps", "max_residual_out_of_time",
                                            "recovered_steps", "factor_corrections", "pcg_iterations",
                                            "factorizations")},
    # Where the frames went (server/frame_profile.h): each stage's mean and
    # largest time, the overrunning frames it led, and the slowest frame.
    "stages_ms": {e["stage"]: {"mean": round(e.get("mean_ms", 0), 3), "max": round(e.get("max_ms", 0), 1),
                               "overruns_led": e.get("overruns_led", 0)}
                  for e in srv.get("frame_stages", []) if e.get("max_ms", 0) >= 0.05},
    "slowest_frame": (srv.get("slowest_frames") or [None])[0],
    "loadavg_1min": float(open("/proc/loadavg").read().split()[0]),
}))
sys.exit(0 if met else 1)
PY
