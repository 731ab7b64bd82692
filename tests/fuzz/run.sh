#!/usr/bin/env bash
# Builds the libFuzzer targets (preset `fuzz`: clang, ASan, UBSan) and runs
# each for a bounded time on a copy of its seed corpus (tests/fuzz/corpus/),
# then prints one JSON line per target: executions, coverage (libFuzzer's
# `cov` edges), corpus size and crashes. Exits 1 if any target crashed (the
# reproducer is kept under out/fuzz/), 77 (skip) if clang is not installed.
#
#   tests/fuzz/run.sh [SECONDS_PER_TARGET]     (default 12: ~1.5 min in all)
#
# CUTSIM_FUZZ_TARGETS="mesh wire" runs a subset. Leaks inside libgmsh are
# suppressed (tests/fuzz/lsan.supp); every other leak is a finding.
set -uo pipefail

seconds="${1:-12}"
src="$(cd "$(dirname "$0")/../.." && pwd)"
command -v clang++ >/dev/null || { echo "fuzz: SKIP: clang++ not installed (Debian package clang)" >&2; exit 77; }
targets=(${CUTSIM_FUZZ_TARGETS:-scene mesh surface tool_path checkpoint journal recording wire observer web_http trainee_message lab_list})
export LSAN_OPTIONS="suppressions=$src/tests/fuzz/lsan.supp:print_suppressions=0"

cd "$src"
cmake --preset fuzz >/dev/null || exit 1
cmake --build --preset fuzz -j"${CUTSIM_FUZZ_JOBS:-2}" --target "${targets[@]/#/fuzz_}" >/dev/null || exit 1

out="$src/out/fuzz"
mkdir -p "$out"
work="$(mktemp -d /tmp/cutsim-fuzz.XXXXXX)"
trap 'rm -rf "$work"' EXIT
failed=0
for t in "${targets[@]}"; do
  corpus="$work/$t"
  mkdir -p "$corpus"
  cp "$src/tests/fuzz/corpus/$t/"* "$corpus/" 2>/dev/null
  log="$out/$t.log"
  "$src/build/fuzz/bin/fuzz_$t" -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 \
      -artifact_prefix="$out/$t-" -print_final_stats=1 "$corpus" >"$log" 2>&1
  rc=$?
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | cut -d' ' -f2)
  crashes=0
  if [ "$rc" -ne 0 ]; then
    crashes=1
    failed=1
    echo "fuzz: $t FAILED (exit $rc), see $log and $out/$t-*" >&2
  fi
  printf '{"target":"%s","seconds":%s,"executions":%s,"coverage_edges":%s,"corpus":%s,"crashes":%s}\n' \
    "$t" "$seconds" "${execs:-0}" "${cov:-0}" "$(ls "$corpus" | wc -l)" "$crashes"
done
exit $failed
