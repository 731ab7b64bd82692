#!/usr/bin/env bash
# The README's test command: installs what is missing, builds, runs every
# test with ctest, exits non-zero on any failure.
#
#   ./deploy/test.sh            # the `ci` preset: optimised, warnings are errors
#   PRESET=asan ./deploy/test.sh  # the same suite under AddressSanitizer + UBSan
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
