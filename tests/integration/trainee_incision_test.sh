#!/usr/bin/env bash
# A browser trainee incises the skin pad: cutsim-server on
# scenes/skin_pad.pbtxt (real time, with a session key, a session report
# and the final mesh), cutsim-haptic --device browser --serve, and Debian's
# chromium (headless, driven by playwright-core through
# web/trainee/test/incision_test.mjs) whose mouse and keyboard draw the
# blade 3 mm deep along the planned incision the page shows. Passes when
# the page showed the pad and the blade before and after the cut (and the
# wound after it), the session report's mean deviation from the plan is
# ≤ 1.5 mm, and the server's final mesh shows the incision open ≥ 2 mm at
# the middle of the line (tests/integration/incision_gap.py). Screenshots,
# the report and the mesh are kept in OUT_DIR. Runs in a private loopback
# namespace.
#
#   tests/integration/trainee_incision_test.sh BIN_DIR [OUT_DIR] [--bench N]
#
# With --bench N the page also times N mouse moves, input to force and
# input to picture, and the last line on stdout is that JSON
# (bench/trainee_latency.sh). Exits 77 (skip) without chromium, node,
# python3 or the observer page's npm packages (deploy/install-deps.sh).
set -uo pipefail

bin="$(cd "${1:?usage: $0 BIN_DIR [OUT_DIR] [--bench N]}" && pwd)"
src="$(cd "$(dirname "$0")/../.." && pwd)"
modules="$src/web/observer/node_modules"
skip() { echo "trainee_incision_test: SKIP: $*" >&2; exit 77; }
[ -x /usr/bin/chromium ] || skip "chromium is not installed"
command -v node >/dev/null || skip "node is not installed"
command -v python3 >/dev/null || skip "python3 is not installed"
[ -d "$modules/playwright-core" ] || skip "the observer page's npm packages are not installed (deploy/install-deps.sh)"

if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  exec "$src/deploy/netns-run.sh" "$0" "$@"
fi

out="${2:-$(mktemp -d /tmp/cutsim-incision.XXXXXX)}"
bench=()
[ "${3:-}" = "--bench" ] && bench=(--bench "${4:?--bench needs N}")
mkdir -p "$out"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  wait 2>/dev/null
}
trap cleanup EXIT
fail() { echo "trainee_incision_test: FAIL: $*; logs in $out" >&2; exit 1; }

cd "$src" || exit 1
umask 077
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$out/key"
rm -f "$out/url" "$out/server.json" "$out/report.json" "$out/final.vtu"
"$bin/cutsim-server" --scene scenes/skin_pad.pbtxt --duration 300 --no-rt --key-file "$out/key" \
  --stats-json "$out/server.json" --session-report "$out/report.json" --out "$out/final.vtu" \
  >"$out/server.out" 2>"$out/server.log" &
server=$!
pids+=("$server")
"$bin/cutsim-haptic" --device browser --serve 127.0.0.1:18096 --key-file "$out/key" --url-file "$out/url" \
  --scene scenes/skin_pad.pbtxt --no-rt --csv "$out/haptic.csv" >"$out/haptic.json" 2>"$out/haptic.log" &
haptic=$!
pids+=("$haptic")
for _ in $(seq 100); do [ -s "$out/url" ] && break; sleep 0.1; done
[ -s "$out/url" ] || fail "the trainee page did not start: $(tail -3 "$out/haptic.log")"

node "$src/web/trainee/test/incision_test.mjs" --url "$(cat "$out/url")" --out "$out" "${bench[@]}" \
  >"$out/page_test.log" 2>&1
rc=$?
cat "$out/page_test.log" >&2
[ "$rc" -eq 0 ] || fail "page checks failed"

kill -INT "$haptic"
wait "$haptic" || fail "cutsim-haptic exited $?"
kill -INT "$server"
wait "$server" || fail "cutsim-server exited $?"
pids=()
[ -s "$out/report.json" ] && [ -s "$out/final.vtu" ] || fail "the server wrote no report or no final mesh"

# The score: the cut followed the line (the report's mean deviation, m).
python3 - "$out/report.json" <<'PY' || fail "the session report's score misses its target"
import json, sys
report = json.load(open(sys.argv[1]))
score = report.get("score", {})
get = lambda snake, camel: score.get(snake, score.get(camel, 0.0))
points, mean = get("cut_points", "cutPoints"), get("mean_deviation", "meanDeviation")
coverage = get("coverage", "coverage")
print(f"score: {points:.0f} cut points, mean deviation {1e3 * mean:.2f} mm, coverage {100 * coverage:.1f} %",
      file=sys.stderr)
sys.exit(0 if points >= 1 and mean <= 0.0015 else 1)
PY
echo "ok score-follows-the-line" >&2
# The opening at the middle of the line, in the server's final mesh.
gap="$(python3 "$src/tests/integration/incision_gap.py" "$out/final.vtu" --at 0 0 0 --along 1 0 0)" ||
  fail "no wound at the middle of the line: $gap"
echo "incision gap at the middle: $gap" >&2
python3 -c 'import json, sys; sys.exit(0 if json.loads(sys.argv[1])["gap_m"] >= 0.002 else 1)' "$gap" ||
  fail "the incision opened less than 2 mm at the middle: $gap"
echo "ok incision-gapes" >&2
tail -1 "$out/page_test.log"
