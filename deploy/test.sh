#!/usr/bin/env bash
# The README's test command: installs what is missing, builds, runs every
# test with ctest, exits non-zero on any failure. Arguments go to ctest.
#
#   ./deploy/test.sh              # the `ci` preset: optimised, warnings are errors
#   ./deploy/test.sh -LE slow     # the quick run: every test but those labelled slow
#   ./deploy/test.sh -L unit      # unit tests only (labels: unit, integration, slow)
#   PRESET=asan ./deploy/test.sh  # the same suite under AddressSanitizer + UBSan
#
# Every test has its own TIMEOUT (tests/CMakeLists.txt); --timeout is the
# limit of a test that has none.
set -euo pipefail
cd "$(dirname "$0")/.."

preset="${PRESET:-ci}"
jobs="${JOBS:-$(nproc)}"

./deploy/install-deps.sh

echo "== configure ($preset)"
cmake --preset "$preset" >/dev/null
echo "== build ($preset)"
cmake --build --preset "$preset" -j "$jobs"
echo "== test ($preset)"
ctest --preset "$preset" -j "$jobs" --timeout 600 "$@"
