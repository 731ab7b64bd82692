#!/usr/bin/env bash
# The one bench command: installs what is missing, builds the `release`
# preset, runs every benchmark in bench/ with JSON output into out/bench/,
# and plots them (PNG) with matplotlib. About 25 minutes on a 2-core box with
# a cold build (~11 min of it), ~14 min with the build cached.
#
#   ./deploy/bench.sh                 # everything
#   BENCH_MIN_TIME=0.1 ./deploy/bench.sh   # quicker, noisier
set -euo pipefail
cd "$(dirname "$0")/.."

jobs="${JOBS:-$(nproc)}"
min_time="${BENCH_MIN_TIME:-0.2}"
reps="${BENCH_REPETITIONS:-3}"
out=out/bench
start=$(date +%s)

./deploy/install-deps.sh

echo "== configure (release)"
cmake --preset release >/dev/null
echo "== build (release)"
cmake --build --preset release -j "$jobs"
bin=build/release/bin
mkdir -p "$out"

echo "== machine"
{
  echo "{"
  echo "  \"cpu\": \"$(lscpu | sed -n 's/^Model name: *//p' | head -1)\","
  echo "  \"cores\": $(nproc),"
  echo "  \"load_average_1min\": $(cut -d' ' -f1 /proc/loadavg),"
  echo "  \"date\": \"$(date -u +%Y-%m-%dT%H:%M:%SZ)\","
  echo "  \"commit\": \"$(git rev-parse --short HEAD 2>/dev/null || echo unknown)\""
  echo "}"
} > "$out/machine.json"
cat "$out/machine.json"

echo "== fem_bench (force kernel, full step, skip table, STREAM triad)"
# Medians of $reps repetitions; the triad runs in the same binary so the
# kernel numbers can be read as a fraction of the memory roofline.
"$bin/fem_bench" --benchmark_min_time="$min_time" --benchmark_repetitions="$reps" \
  --benchmark_report_aggregates_only=true \
  --benchmark_out="$out/fem_bench.json" --benchmark_out_format=json >/dev/null

echo "== skip_bench (session-level skips: no tool, cutting off, no haptic client, no viewer)"
"$bin/skip_bench" --scene-dir scenes --json "$out/skip.json" > /dev/null 2>"$out/skip.log" \
  || echo "skip_bench failed (see $out/skip.log)"
cat "$out/skip.log"

echo "== organ_mesh (sliver cleanup and stable step of the organ)"
"$bin/organ_mesh" > "$out/organ_mesh.json"
cat "$out/organ_mesh.json"

echo "== organ scene run (real-time factor)"
if [[ -f scenes/organ.pbtxt ]]; then
  "$bin/cutsim-server" --headless --scene scenes/organ.pbtxt --duration 0.5 --no-progress \
    > "$out/organ_run.json" 2>"$out/organ_run.log" || echo "organ run failed (see $out/organ_run.log)"
else
  echo "scenes/organ.pbtxt not present yet: skipped"
fi

echo "== haptic loop under load (real server physics on the other core) vs bare loop"
bench/haptic_session.sh "$PWD/$bin" "$PWD/$out" "${HAPTIC_SECONDS:-20}" || echo "haptic bench skipped (see $out/haptic_loop.log)"

echo "== buffer-model accuracy against a 1 kHz FEM reference"
"$bin/buffer_model_bench" --scene scenes/ligament.pbtxt > "$out/buffer_model.jsonl"
cat "$out/buffer_model.jsonl"

echo "== observers: delta vs snapshot bytes, late join, encode cost (mesh_stream_test [bench] lines)"
"$bin/mesh_stream_test" 2>/dev/null | grep '^\[bench\]' > "$out/mesh_stream.txt" || true
cat "$out/mesh_stream.txt"

echo "== headless cut of scenes/block.pbtxt (time per cut step, components)"
"$bin/cutsim-server" --headless --scene scenes/block.pbtxt --no-progress > "$out/block_cut.json" 2>"$out/block_cut.log" \
  || echo "block run failed (see $out/block_cut.log)"

echo "== cut_bench (cut step by phase at 1k/10k/100k tets; block after 100 cuts: stable step, quality, throughput)"
"$bin/cut_bench" --scene-dir scenes --json "$out/cut_bench.json" > /dev/null 2>"$out/cut_bench.log" \
  || echo "cut_bench failed (see $out/cut_bench.log)"
cat "$out/cut_bench.json" 2>/dev/null || true

echo "== accuracy_bench (run time against error: cantilever statics/dynamics, scripted cut; ~8 min)"
# The beam part is written to accuracy.json before the cutting part starts;
# the timeout guards against a hang in the cutting path.
timeout "${ACCURACY_TIMEOUT:-1800}" "$bin/accuracy_bench" --repeats "${ACCURACY_REPETITIONS:-1}" \
  --out "$out/accuracy.json" 2>"$out/accuracy.log" || echo "accuracy_bench failed or timed out (see $out/accuracy.log)"

echo "== stability_bench (stress suite: Markdown table in stability.md; ~3-4 min)"
# Rows are written as cases finish; the timeout guards the random-cuts case
# (last) against a hang in the cutting path.
timeout "${STABILITY_TIMEOUT:-900}" "$bin/stability_bench" --out "$out/stability.json" > "$out/stability.md" \
  2>"$out/stability.log" || echo "stability_bench failed or timed out (see $out/stability.log)"
cat "$out/stability.md" 2>/dev/null || true

echo "== plots"
/usr/bin/python3 bench/plot.py "$out"

echo "== done in $(( $(date +%s) - start )) s; results in $out/"
