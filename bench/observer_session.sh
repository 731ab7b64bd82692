#!/usr/bin/env bash
# Browser observers under load: cutsim-server on a shipped scene (real-time
# loop, normal priority), cutsim-viewer --serve relaying it, one observer page
# in headless chromium and WS_CLIENTS plain WebSocket clients
# (bench/observer_bench.mjs), while the scripted scalpel cuts along PATH_FILE.
# Runs in a private loopback namespace (deploy/netns-run.sh).
#
#   bench/observer_session.sh BIN_DIR OUT_DIR SCENE PATH_FILE SECONDS [WS_CLIENTS]
#
# The window opens once the page draws and every client has its first mesh
# frame; the scalpel starts then, and the window lasts SECONDS. Prints one
# JSON line: the page's glass-to-glass latency (server publish → end of the
# draw that shows the frame, the window's first second discarded), bytes and
# frames per second per observer, the server's and the viewer's CPU time over
# the window (/proc/PID/stat) and the server's per physics frame, the
# viewer's and the server's summaries, and `met` for the goal (latency p99
# ≤ 100 ms). Exits 1 when the goal is missed or something failed, 77 when
# chromium, node or the page's npm packages are missing or no namespace can
# be made. OUT_DIR keeps the logs and samples.json (every latency); use one
# OUT_DIR per run.
set -uo pipefail

usage="usage: $0 BIN_DIR OUT_DIR SCENE PATH_FILE SECONDS [WS_CLIENTS]"
[ $# -ge 5 ] || { echo "$usage" >&2; exit 2; }
bin="$(cd "$1" && pwd)" || exit 2
out="$2"; scene="$3"; path="$4"; seconds="$5"; ws_clients="${6:-0}"
root="$(cd "$(dirname "$0")/.." && pwd)"
web="$root/web/observer"
skip() { echo "observer_session: SKIP: $*" >&2; exit 77; }
[ -x /usr/bin/chromium ] || skip "chromium is not installed"
command -v node >/dev/null || skip "node is not installed"
for module in three/build/three.module.js playwright-core/package.json ws/package.json; do
  [ -f "$web/node_modules/$module" ] || skip "the page's npm packages are not installed (deploy/install-deps.sh)"
done

if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$root/deploy/netns-run.sh" "$0" "$@"
fi
# shellcheck source=bench/wait_for_server.sh
source "$root/bench/wait_for_server.sh"

mkdir -p "$out"
out="$(cd "$out" && pwd)"
rm -f "$out/bench.json" "$out/samples.json" "$out/server-stats.json" "$out/viewer.json"
name="$(basename "$scene" .pbtxt)"
session="observer-bench-$name"
port=18090
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  wait 2>/dev/null
}
trap cleanup EXIT
fail() { echo "observer_session: $*" >&2; exit 1; }

# CPU time of a process, clock ticks (utime + stime, /proc/PID/stat fields
# 14 and 15, counted after the parenthesised command name).
cpu_ticks() {
  local stat
  stat="$(<"/proc/$1/stat")" || return 1
  stat="${stat##*) }"
  # shellcheck disable=SC2086
  set -- $stat
  echo $(( ${12} + ${13} ))
}
now_ns() { date +%s%N; }
# The benchmark marks the window's start and end on a FIFO (held open here
# for reading and writing, so that its writes never block); a blocking read
# wakes at the mark, where polling a file would lag it on a loaded machine.
# wait_for_mark WORD LIMIT: the next mark is WORD, within LIMIT seconds.
marks="$out/marks"
rm -f "$marks"
mkfifo "$marks" || fail "cannot make the FIFO $marks"
exec 3<>"$marks"
wait_for_mark() {
  local word stamp
  read -r -t "$2" word stamp <&3 && [ "$word" = "$1" ] && [ -n "$stamp" ]
}

cd "$root" || exit 1
# The server runs until stopped after the window; the duration is a cap.
"$bin/cutsim-server" --scene "scenes/$scene" --session "$session" --duration 3600 --no-rt \
  --stats-json "$out/server-stats.json" >"$out/server.out" 2>"$out/server.log" &
server=$!
pids+=("$server")
wait_for_server "$out/server.log" "$server" 120

"$bin/cutsim-viewer" --serve "127.0.0.1:$port" --session "$session" --summary "$out/viewer.json" \
  >"$out/viewer.out" 2>"$out/viewer.log" &
viewer=$!
pids+=("$viewer")
for _ in $(seq 200); do grep -q '^observers:' "$out/viewer.out" 2>/dev/null && break; sleep 0.05; done
grep -q '^observers:' "$out/viewer.out" || fail "the bridge did not start (see $out/viewer.log)"

node "$root/bench/observer_bench.mjs" --url "http://127.0.0.1:$port/" --browsers 1 --ws-clients "$ws_clients" \
  --seconds "$seconds" --mark-file "$marks" --samples "$out/samples.json" >"$out/bench.json" 2>"$out/bench.log" &
bench=$!
pids+=("$bench")
wait_for_mark start 90 || fail "the observers did not start (see $out/bench.log, $out/bench.json)"
{ server_t0="$(cpu_ticks "$server")" && viewer_t0="$(cpu_ticks "$viewer")"; } || fail "the server or the viewer died"
wall_t0="$(now_ns)"
# SIGUSR1 makes the server log its statistics ("stats: {…}") at its next
# frame; the frames and simulated time between the two give the window's
# CPU time per physics frame. The real-time loop catches up when it falls
# behind, so its CPU time alone also depends on how much of the machine the
# other processes leave it.
kill -USR1 "$server"

# The scalpel starts with the window, so the window sees the cut.
"$bin/cutsim-haptic" --session "$session" --device scripted --path "scenes/$path" --no-rt --csv - \
  >"$out/haptic.json" 2>"$out/haptic.log" &
pids+=($!)

wait_for_mark end $(( ${seconds%.*} + 60 )) || fail "the window did not close (see $out/bench.log)"
{ server_t1="$(cpu_ticks "$server")" && viewer_t1="$(cpu_ticks "$viewer")"; } || fail "the server or the viewer died"
wall_t1="$(now_ns)"
kill -USR1 "$server"
wait "$bench"
bench_rc=$?
for _ in $(seq 100); do [ "$(grep -c '\] stats: {' "$out/server.log")" -ge 2 ] && break; sleep 0.05; done

# Stop the rest; the viewer writes its summary and the server its
# statistics on SIGTERM.
for p in "$viewer" "$server"; do kill -TERM "$p" 2>/dev/null; done
wait "$viewer"
viewer_rc=$?
wait "$server"
server_rc=$?
pids=()
for p in $(jobs -p); do kill -TERM "$p" 2>/dev/null; done
wait 2>/dev/null

/usr/bin/python3 - "$out" "$name" "$ws_clients" "$(getconf CLK_TCK)" \
  "$server_t0" "$server_t1" "$viewer_t0" "$viewer_t1" "$wall_t0" "$wall_t1" \
  "$bench_rc" "$viewer_rc" "$server_rc" <<'PY'
import json, sys
out, name = sys.argv[1], sys.argv[2]
ws_clients, tck = int(sys.argv[3]), float(sys.argv[4])
s0, s1, v0, v1, w0, w1 = (int(x) for x in sys.argv[5:11])
bench_rc, viewer_rc, server_rc = (int(x) for x in sys.argv[11:14])

def load(name):
    try:
        with open(f"{out}/{name}") as f:
            return json.load(f)
    except (OSError, ValueError):
        return None

bench, srv, viewer = load("bench.json"), load("server-stats.json"), load("viewer.json")
# The server's statistics at the window's start and end (SIGUSR1).
stats_at = []
with open(f"{out}/server.log") as f:
    for line in f:
        if "] stats: {" in line:
            stats_at.append(json.loads(line[line.index("{"):]))
problems = []
if bench is None:
    problems.append("no benchmark result (bench.json)")
    bench = {}
problems += bench.get("errors", [])
if bench_rc != 0 and not bench.get("errors"):
    problems.append(f"observer_bench exited {bench_rc}")
if viewer is None or viewer_rc != 0:
    problems.append(f"viewer exited {viewer_rc}" + ("" if viewer else ", no summary"))
if srv is None or server_rc != 0:
    problems.append(f"server exited {server_rc}" + ("" if srv else ", no statistics"))
viewer, srv = viewer or {}, srv or {}
if srv and srv.get("cuts", 0) == 0:
    problems.append("the scalpel made no cut")

wall = (w1 - w0) / 1e9
server_cpu = (s1 - s0) / tck
viewer_cpu = (v1 - v0) / tck
window = {}
if len(stats_at) >= 2:
    frames_in_window = stats_at[1]["frames"] - stats_at[0]["frames"]
    window = {"frames": frames_in_window,
              "realtime_factor": round((stats_at[1]["sim_time"] - stats_at[0]["sim_time"]) / wall, 3),
              "cpu_ms_per_frame": round(1e3 * server_cpu / frames_in_window, 3) if frames_in_window else None}
else:
    problems.append("the server logged no statistics for the window (SIGUSR1)")
latency = bench.get("latency_ms", {})
goal = {"latency_p99_ms_max": 100.0}
p99 = latency.get("p99")
met = p99 is not None and latency.get("n", 0) > 0 and p99 <= goal["latency_p99_ms_max"]
frames = max(1, srv.get("frames", 0))
print(json.dumps({
    "kind": "observer_session", "scene": name, "browsers": bench.get("browsers", 1), "ws_clients": ws_clients,
    "window_s": round(wall, 3),
    "latency_ms": latency,
    "ws_receive_latency_ms": bench.get("ws_receive_latency_ms"),
    "bytes_per_s_per_observer": {"page": bench.get("page_bytes_per_s"), "ws": bench.get("ws_bytes_per_s")},
    "bytes_per_frame": {"page": bench.get("page_bytes_per_frame"), "ws": bench.get("ws_bytes_per_frame")},
    "frames_per_s": {"page": bench.get("page_frames_per_s"), "page_draws": bench.get("page_draws_per_s"),
                     "ws": bench.get("ws_frames_per_s")},
    "page_dropped_frames": bench.get("page_dropped_frames"),
    "server_cpu_s": round(server_cpu, 2), "server_cpu_percent": round(100 * server_cpu / wall, 1),
    "server_window": window,
    "viewer_cpu_s": round(viewer_cpu, 2), "viewer_cpu_percent": round(100 * viewer_cpu / wall, 1),
    "viewer": {k: viewer.get(k, 0) for k in ("browser_frames", "browsers_accepted", "browsers_refused",
                                            "browsers_closed", "browser_bytes_sent", "gaps", "exit_reason")},
    "server": {"frames": srv.get("frames"), "overrun_percent": round(100 * srv.get("frame_overruns", 0) / frames, 2),
               "frame_time_ms": {k: round(srv.get(f"frame_time_{k}_ms", 0), 2) for k in ("p50", "p99", "max")},
               "viewer_frames": srv.get("viewer_frames"), "cuts": srv.get("cuts", 0), "status": srv.get("status")},
    "goal": goal, "met": met, "errors": problems,
    "loadavg_1min": float(open("/proc/loadavg").read().split()[0]),
}))
sys.exit(0 if met and not problems else 1)
PY
