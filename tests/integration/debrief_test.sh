#!/usr/bin/env bash
# The debrief end to end, in a private loopback namespace
# (deploy/netns-run.sh):
#  1. a keyed real-time session on the ligament, cut by the scripted station
#     and recorded (--record; every 20th frame carries the state's hash);
#  2. `cutsim-server --headless --replay` checks the recording;
#  3. `cutsim-server --replay FILE --live` plays it as session "debrief",
#     commands on its standard input (a FIFO); a viewer renders it with a
#     frame log and a second one bridges it to browsers with an observers'
#     and an instructor's token;
#  4. web/observer/test/debrief_test.mjs drives it: CLI seeks, steps and
#     speed checked on the rendered frames (with the seek latency), control
#     over the WebSocket (refused without the instructor token, bad
#     commands refused by field), and the page in Debian's chromium
#     (timeline and cursor, pause at the force peak, next cut step;
#     screenshots in OUT_DIR);
#  5. the debrief's summary: every frame it showed that the recording hashed
#     equals the live session's (hash_checks > 0, hash_mismatches 0).
#
#   tests/integration/debrief_test.sh BIN_DIR [OUT_DIR]
#
# Exits 77 (skip) when chromium, node or the page's npm packages are absent.
set -uo pipefail

bin="$(cd "${1:?usage: $0 BIN_DIR [OUT_DIR]}" && pwd)"
src="$(cd "$(dirname "$0")/../.." && pwd)"
web="$src/web/observer"
skip() { echo "debrief_test: SKIP: $*" >&2; exit 77; }
[ -x /usr/bin/chromium ] || skip "chromium is not installed"
command -v node >/dev/null || skip "node is not installed"
[ -f "$web/node_modules/three/build/three.module.js" ] && [ -d "$web/node_modules/playwright-core" ] &&
  [ -d "$web/node_modules/ws" ] || skip "the page's npm packages are not installed (deploy/install-deps.sh)"

if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$src/deploy/netns-run.sh" "$0" "$@"
fi

out="${2:-$(mktemp -d /tmp/cutsim-debrief.XXXXXX)}"
mkdir -p "$out"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  wait 2>/dev/null
}
trap cleanup EXIT
fail() { echo "debrief_test: FAIL: $*; logs in $out" >&2; exit 1; }

cd "$src"
url="udpm://239.255.76.67:7917?ttl=0"
(umask 077; head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$out/session.key")
(umask 077; head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$out/observers.token")
(umask 077; head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$out/instructor.token")

# 1. The live session, recorded.
"$bin/cutsim-server" --scene scenes/ligament.pbtxt --session live --duration 4 --no-rt --lcm-url "$url" \
  --key-file "$out/session.key" --record "$out/session.lcm" >"$out/live.json" 2>"$out/live.log" &
live=$!
# The station starts once the server runs (its "session 'live': physics … Hz" line).
for _ in $(seq 600); do grep -q "session 'live': physics" "$out/live.log" && break; sleep 0.05; done
grep -q "session 'live': physics" "$out/live.log" || fail "the live server did not start (live.log)"
"$bin/cutsim-haptic" --device scripted --path scenes/ligament-cut.path --session live --lcm-url "$url" \
  --key-file "$out/session.key" --no-rt >"$out/haptic.json" 2>"$out/haptic.log" ||
  fail "the scripted station failed"
wait "$live" || fail "the live session failed"

# 2. The recording replays headless, frame hashes included.
"$bin/cutsim-server" --headless --replay "$out/session.lcm" --log-level warn >"$out/replay.json" 2>"$out/replay.log" ||
  fail "the recording does not replay (replay.json)"

# 3. The debrief, its viewers.
mkfifo "$out/commands"
"$bin/cutsim-server" --replay "$out/session.lcm" --live --session debrief --key-file "$out/session.key" \
  --viewer-fps 60 <"$out/commands" >"$out/debrief.json" 2>"$out/debrief.log" &
debrief=$!
pids+=($debrief)
exec 3>"$out/commands"  # held open: the server's standard input stays open between commands
"$bin/cutsim-viewer" --session debrief --key-file "$out/session.key" --fps 60 --frame-log "$out/frames.log" \
  --width 320 --height 240 >"$out/viewer.out" 2>"$out/viewer.log" &
pids+=($!)
port=18095
"$bin/cutsim-viewer" --session debrief --key-file "$out/session.key" --serve "127.0.0.1:$port" \
  --token-file "$out/observers.token" --instructor-token-file "$out/instructor.token" \
  >"$out/bridge.out" 2>"$out/bridge.log" &
pids+=($!)
for _ in $(seq 100); do grep -q '^instructor:' "$out/bridge.out" 2>/dev/null && break; sleep 0.1; done
grep -q '^instructor:' "$out/bridge.out" || fail "the bridge did not start"
for _ in $(seq 600); do grep -q 'to observers on DDS' "$out/debrief.log" 2>/dev/null && break; sleep 0.1; done
grep -q 'to observers on DDS' "$out/debrief.log" || fail "the debrief did not start (debrief.log)"
# The debrief plays at once while its checkpoints are made; the seek checks
# time seeks from checkpoints, so they start once all are made.
for _ in $(seq 1200); do grep -q 'checkpoints complete' "$out/debrief.log" 2>/dev/null && break; sleep 0.1; done
grep -q 'checkpoints complete' "$out/debrief.log" || fail "the debrief's checkpoints were not made (debrief.log)"

# 4. The checks.
node "$web/test/debrief_test.mjs" --observer "$(sed -n 's/^observers: //p' "$out/bridge.out")" \
  --instructor "$(sed -n 's/^instructor: //p' "$out/bridge.out")" --commands "$out/commands" \
  --frame-log "$out/frames.log" --server-log "$out/debrief.log" --out "$out" 2>&1 | tee "$out/page_test.log"
rc=${PIPESTATUS[0]}

# 5. The debrief's own account.
exec 3>&-
kill -INT "$debrief"
wait "$debrief"
drc=$?
summary="$(tail -1 "$out/debrief.json")"
echo "debrief summary: $summary"
python3 - "$summary" <<'PY' || rc=1
import json, sys
s = json.loads(sys.argv[1])
assert s["hash_checks"] > 0, f"no frame was checked against the live session: {s}"
assert s["hash_mismatches"] == 0, f"frames differ from the live session: {s}"
assert s["refused"] >= 1, f"the bad command line was not refused: {s}"
print(f"ok replayed-hashes-equal-live: {s['hash_checks']} frames checked, seek max {s['seek_max_ms']} ms")
PY
[ "$drc" -eq 0 ] || { echo "debrief_test: the debrief exited $drc" >&2; rc=1; }
[ "$rc" -eq 0 ] || echo "debrief_test: checks failed; logs and screenshots in $out" >&2
exit "$rc"
