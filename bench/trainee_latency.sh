#!/usr/bin/env bash
# Trainee latency of the browser device on the skin pad: the incision
# test's session (tests/integration/trainee_incision_test.sh: cutsim-server
# on scenes/skin_pad.pbtxt, cutsim-haptic --device browser, headless
# chromium) with N extra mouse moves after the cut, each timed from its
# input event's timestamp to
# - input to force: the page's receipt of the first force frame computed
#   from a pose that includes it (the frame carries the page time of the
#   newest sample in that pose);
# - input to picture: the animation frame after the one that drew that
#   pose (by then the drawn frame has gone to the compositor).
# Prints one JSON line: both sets of quantiles (ms), the targets (p99 ≤ 50
# ms to force, ≤ 100 ms to picture) and whether they were met.
#
#   bench/trainee_latency.sh BIN_DIR [OUT_DIR] [N]
#
# Exits 77 (skip) without chromium, node, python3, the npm packages or a
# network namespace; 1 if the session or its checks fail or a target is
# missed.
set -uo pipefail
bin="$(cd "${1:?usage: $0 BIN_DIR [OUT_DIR] [N]}" && pwd)"
src="$(cd "$(dirname "$0")/.." && pwd)"
out="${2:-$(mktemp -d /tmp/cutsim-trainee-bench.XXXXXX)}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
"$src/tests/integration/trainee_incision_test.sh" "$bin" "$out" --bench "${3:-600}" > "$out/bench.out"
rc=$?
[ "$rc" -eq 0 ] || exit "$rc"
tail -1 "$out/bench.out" | python3 -c '
import json, sys
r = json.loads(sys.stdin.read())
r["targets"] = {"input_to_force_p99_ms": 50, "input_to_picture_p99_ms": 100}
force, picture = r["input_to_force"]["p99_ms"], r["input_to_picture"]["p99_ms"]
r["met"] = force is not None and force <= 50 and picture is not None and picture <= 100
print(json.dumps(r))
sys.exit(0 if r["met"] else 1)
'
