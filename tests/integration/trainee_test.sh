#!/usr/bin/env bash
# A browser trainee cuts the ligament: cutsim-server on scenes/ligament.pbtxt
# (real time, with a session key), cutsim-haptic --device browser --serve,
# and Debian's chromium (headless, driven by playwright-core through
# web/trainee/test/trainee_test.mjs) whose mouse and keyboard bring the
# scalpel down beside the ligament and across it. Passes when the server
# reports a cut, the page showed the tissue in 3-D with the scalpel, a force
# and the cut, and a wrong key, a foreign Origin, a rebound Host, a second
# trainee, oversized and malformed messages were refused without harm.
# Screenshots of the page before and after the cut are kept in OUT_DIR.
# Runs in a private loopback namespace.
#
#   tests/integration/trainee_test.sh BIN_DIR [OUT_DIR]
#
# Exits 77 (skip) without chromium, node or the observer page's npm
# packages (deploy/install-deps.sh installs them).
set -uo pipefail

bin="$(cd "${1:?usage: $0 BIN_DIR [OUT_DIR]}" && pwd)"
src="$(cd "$(dirname "$0")/../.." && pwd)"
modules="$src/web/observer/node_modules"
skip() { echo "trainee_test: SKIP: $*" >&2; exit 77; }
[ -x /usr/bin/chromium ] || skip "chromium is not installed"
command -v node >/dev/null || skip "node is not installed"
[ -d "$modules/playwright-core" ] && [ -d "$modules/ws" ] ||
  skip "the observer page's npm packages are not installed (deploy/install-deps.sh)"

if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$src/deploy/netns-run.sh" "$0" "$@"
fi

out="${2:-$(mktemp -d /tmp/cutsim-trainee.XXXXXX)}"
mkdir -p "$out"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  wait 2>/dev/null
}
trap cleanup EXIT
fail() { echo "trainee_test: FAIL: $*; logs in $out" >&2; exit 1; }

cd "$src"
umask 077
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$out/key"
rm -f "$out/url" "$out/server.json"
"$bin/cutsim-server" --scene scenes/ligament.pbtxt --duration 120 --no-rt --key-file "$out/key" \
  --stats-json "$out/server.json" >"$out/server.out" 2>"$out/server.log" &
server=$!
pids+=("$server")
"$bin/cutsim-haptic" --device browser --serve 127.0.0.1:18095 --key-file "$out/key" --url-file "$out/url" \
  --scene scenes/ligament.pbtxt --no-rt --csv "$out/haptic.csv" >"$out/haptic.json" 2>"$out/haptic.log" &
haptic=$!
pids+=("$haptic")
for _ in $(seq 100); do [ -s "$out/url" ] && break; sleep 0.1; done
[ -s "$out/url" ] || fail "the trainee page did not start: $(tail -3 "$out/haptic.log")"
grep -qf "$out/key" "$out/haptic.log" "$out/server.log" "$out/haptic.json" && fail "the session key was logged"

node "$src/web/trainee/test/trainee_test.mjs" --url "$(cat "$out/url")" --out "$out" \
  >"$out/page_test.log" 2>&1
rc=$?
cat "$out/page_test.log" >&2
[ "$rc" -eq 0 ] || fail "page checks failed"

kill -INT "$haptic"
wait "$haptic" || fail "cutsim-haptic exited $?"
kill -INT "$server"
wait "$server" || fail "cutsim-server exited $?"
pids=()
cuts="$(grep -o '"cuts": *[0-9]*' "$out/server.json" | head -1 | grep -o '[0-9]*$')"
[ "${cuts:-0}" -ge 1 ] || fail "the server reports ${cuts:-no} cuts"
echo "ok server-reports-cut ($cuts cut steps)" >&2
grep -Eq 'browser device: 2 pages connected' "$out/haptic.log" || fail "the haptic log does not show the trainee and the one after the oversized message"
grep -Eq 'refused: [1-9][0-9]* malformed, [1-9][0-9]* not finite, [1-9][0-9]* out of range, [1-9][0-9]* bad direction, [1-9][0-9]* bad buttons' \
  "$out/haptic.log" || fail "the refused messages were not counted: $(grep 'browser device:' "$out/haptic.log")"
grep -Eq '[1-9][0-9]* oversized' "$out/haptic.log" || fail "the oversized message was not counted"
grep -Eq 'upgrades refused: [1-9][0-9]* token, [1-9][0-9]* origin, [1-9][0-9]* host, [0-9]+ key, [1-9][0-9]* busy' \
  "$out/haptic.log" ||
  fail "the refused upgrades were not counted"
echo "ok refusals-counted" >&2
tail -1 "$out/page_test.log"
