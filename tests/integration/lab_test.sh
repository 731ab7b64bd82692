#!/usr/bin/env bash
# The lab view end to end: three real-time servers on the ligament (sessions
# bay-1, bay-2, bay-3, each naming its trainee), a scripted station cutting
# bay-1, and the lab bridge (`cutsim-viewer --lab`) that knows none of them
# by name. Debian's chromium (web/observer/test/lab_test.mjs) checks that the
# page lists the three live, shows each in the grid with frames arriving,
# shows bay-1's station connected, shows bay-3 stopped once its server is
# stopped and then its trainee's trend from the lab's history (the stopped
# server appended the session), and opens a session's observer page from the grid. Runs in a
# private loopback namespace (deploy/netns-run.sh).
#
#   tests/integration/lab_test.sh BIN_DIR [OUT_DIR]
#
# Exits 77 (skip) when chromium, node or the page's npm packages are absent.
set -uo pipefail

bin="$(cd "${1:?usage: $0 BIN_DIR [OUT_DIR]}" && pwd)"
src="$(cd "$(dirname "$0")/../.." && pwd)"
web="$src/web/observer"
skip() { echo "lab_test: SKIP: $*" >&2; exit 77; }
[ -x /usr/bin/chromium ] || skip "chromium is not installed"
command -v node >/dev/null || skip "node is not installed"
[ -f "$web/node_modules/three/build/three.module.js" ] && [ -d "$web/node_modules/playwright-core" ] ||
  skip "the page's npm packages are not installed (deploy/install-deps.sh)"

if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$src/deploy/netns-run.sh" "$0" "$@"
fi

out="${2:-$(mktemp -d /tmp/cutsim-lab.XXXXXX)}"
mkdir -p "$out"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  wait 2>/dev/null
}
trap cleanup EXIT

cd "$src"
port=18090
"$bin/cutsim-viewer" --lab "127.0.0.1:$port" --history "$out/history.sqlite" --duration 170 \
  >"$out/lab.out" 2>"$out/lab.log" &
pids+=($!)
declare -A server_pid
trainees=(ada grace linus)
for i in 1 2 3; do
  "$bin/cutsim-server" --scene scenes/ligament.pbtxt --session "bay-$i" --duration 160 --no-rt \
    --history "$out/history.sqlite" --trainee "${trainees[$((i - 1))]}" >"$out/server-$i.log" 2>&1 &
  server_pid[$i]=$!
  pids+=($!)
done
for _ in $(seq 100); do grep -q '^lab:' "$out/lab.out" 2>/dev/null && break; sleep 0.1; done
grep -q '^lab:' "$out/lab.out" || { echo "lab_test: the lab bridge did not start" >&2; cat "$out/lab.log" >&2; exit 1; }

# A station cuts bay-1 once the page shows the list (it creates the ready
# file), so the page sees the station connect.
ready="$out/page-ready"
(
  for _ in $(seq 1500); do [ -f "$ready" ] && break; sleep 0.1; done
  exec "$bin/cutsim-haptic" --session bay-1 --device scripted --path scenes/ligament-cut.path --no-rt \
    >"$out/haptic.json" 2>"$out/haptic.log"
) &
pids+=($!)

# The page asks for bay-3's server to stop by creating the stop file.
stop_file="$out/stop-bay-3"
(
  for _ in $(seq 1500); do [ -f "$stop_file" ] && break; sleep 0.1; done
  kill -INT "${server_pid[3]}" 2>/dev/null
) &
pids+=($!)

node "$web/test/lab_test.mjs" --url "http://127.0.0.1:$port/" --sessions bay-1,bay-2,bay-3 --stopped bay-3 \
  --stop-file "$stop_file" --station bay-1 --ready-file "$ready" --out "$out" 2>&1 | tee "$out/page_test.log"
rc=${PIPESTATUS[0]}
[ "$rc" -eq 0 ] || echo "lab_test: page checks failed; logs and screenshots in $out" >&2
exit "$rc"
