#!/usr/bin/env bash
# Input-to-force latency of the browser device: the trainee test's session
# (cutsim-server on the ligament, cutsim-haptic --device browser, headless
# chromium) with N extra mouse moves, each timed from its input event's
# timestamp to the page's receipt of the first force frame computed from a
# pose that includes it. Prints one JSON line (p50/p99/max, ms).
#
#   bench/trainee_latency.sh BIN_DIR [OUT_DIR] [N]
#
# Exits 77 (skip) without chromium, node or the npm packages, or a network
# namespace; 1 if the session or its checks fail.
set -uo pipefail
bin="$(cd "${1:?usage: $0 BIN_DIR [OUT_DIR] [N]}" && pwd)"
src="$(cd "$(dirname "$0")/.." && pwd)"
out="${2:-$(mktemp -d /tmp/cutsim-trainee-bench.XXXXXX)}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
"$src/tests/integration/trainee_test.sh" "$bin" "$out" --bench "${3:-600}" > "$out/bench.out"
rc=$?
[ "$rc" -eq 0 ] || exit "$rc"
tail -1 "$out/bench.out"
