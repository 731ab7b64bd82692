#!/usr/bin/env bash
# Browser observers end to end: cutsim-server on the ligament, cutsim-viewer
# --serve relaying it, and Debian's chromium (driven by playwright-core,
# web/observer/test/observer_test.mjs) watching it while a scripted scalpel
# cuts: the page loads, shows tissue and scalpel, follows the tool and the
# cut, a late browser catches up, 20 WebSocket clients are served and
# hostile ones are refused without harm. Runs in a private loopback
# namespace (deploy/netns-run.sh).
#
#   tests/integration/browser_test.sh BIN_DIR [OUT_DIR]
#
# Exits 77 (skip) when chromium, node or the page's npm packages are absent
# (deploy/install-deps.sh installs them).
set -uo pipefail

bin="$(cd "${1:?usage: $0 BIN_DIR [OUT_DIR]}" && pwd)"
src="$(cd "$(dirname "$0")/../.." && pwd)"
web="$src/web/observer"
skip() { echo "browser_test: SKIP: $*" >&2; exit 77; }
[ -x /usr/bin/chromium ] || skip "chromium is not installed"
command -v node >/dev/null || skip "node is not installed"
[ -f "$web/node_modules/three/build/three.module.js" ] && [ -d "$web/node_modules/playwright-core" ] ||
  skip "the page's npm packages are not installed (deploy/install-deps.sh)"

if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$src/deploy/netns-run.sh" "$0" "$@"
fi

out="${2:-$(mktemp -d /tmp/cutsim-browser.XXXXXX)}"
mkdir -p "$out"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  wait 2>/dev/null
}
trap cleanup EXIT

cd "$src"
port=18089
token="$(head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n')"
printf '%s\n' "$token" > "$out/token"
# Off loopback a token is required; on loopback it is optional: this run
# uses one, so the stream's token check is exercised.
"$bin/cutsim-server" --scene scenes/ligament.pbtxt --duration 30 --no-rt >"$out/server.log" 2>&1 &
pids+=($!)
"$bin/cutsim-viewer" --serve "127.0.0.1:$port" --token-file "$out/token" --duration 32 \
  --summary "$out/viewer.json" >"$out/viewer.out" 2>"$out/viewer.log" &
pids+=($!)
for _ in $(seq 100); do grep -q '^observers:' "$out/viewer.out" 2>/dev/null && break; sleep 0.1; done
grep -q '^observers:' "$out/viewer.out" || { echo "browser_test: the bridge did not start" >&2; cat "$out/viewer.log" >&2; exit 1; }

# The scalpel starts once the first page shows the session (the page test
# creates the ready file), so the page sees the tool move and the cut.
ready="$out/page-ready"
(
  for _ in $(seq 300); do [ -f "$ready" ] && break; sleep 0.1; done
  exec "$bin/cutsim-haptic" --device scripted --path scenes/ligament-cut.path --no-rt \
    >"$out/haptic.json" 2>"$out/haptic.log"
) &
pids+=($!)

node "$web/test/observer_test.mjs" --url "http://127.0.0.1:$port/" --token "$token" --out "$out" \
  --ready-file "$ready" 2>&1 | tee "$out/page_test.log"
rc=${PIPESTATUS[0]}
[ "$rc" -eq 0 ] || echo "browser_test: page checks failed; logs and screenshots in $out" >&2
exit "$rc"
