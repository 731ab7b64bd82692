#!/usr/bin/env bash
# The one bench command: installs what is missing, builds the `release`
# preset, runs every benchmark in bench/ with JSON output into out/bench/,
# and plots them (PNG) with matplotlib. Every benchmark runs even when an
# earlier one fails; the script then exits 1 and names the failed ones. A
# benchmark fails when it crashes, times out, or misses a target it states
# (its binary exits non-zero; the reason is in its log).
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
failed=()

# run NAME LOG CMD...: runs CMD with stderr to LOG; a non-zero exit is
# recorded as a failure of NAME and the script carries on.
run() {
  local name="$1" log="$2"
  shift 2
  local rc=0
  "$@" 2>"$log" || rc=$?
  if [[ $rc -ne 0 ]]; then
    echo "!! $name failed (exit $rc, see $log)" >&2
    failed+=("$name")
  fi
  return 0
}

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
run fem_bench "$out/fem_bench.log" "$bin/fem_bench" --benchmark_min_time="$min_time" \
  --benchmark_repetitions="$reps" --benchmark_report_aggregates_only=true \
  --benchmark_out="$out/fem_bench.json" --benchmark_out_format=json >/dev/null

echo "== tool_auth_bench (HMAC sign/verify of a tool message beside its decode)"
run tool_auth_bench "$out/tool_auth.log" "$bin/tool_auth_bench" --benchmark_min_time="$min_time" \
  --benchmark_out="$out/tool_auth.json" --benchmark_out_format=json >/dev/null

echo "== journal_bench (a cut's journal record: hand-off to fdatasync'd, on this machine's disk)"
run journal_bench "$out/journal.log" "$bin/journal_bench" --dir "$out" > "$out/journal.json"
cat "$out/journal.json"

echo "== skip_bench (session-level skips: no tool, cutting off, no haptic client, no viewer)"
run skip_bench "$out/skip.log" "$bin/skip_bench" --scene-dir scenes --json "$out/skip.json" >/dev/null
cat "$out/skip.log"

echo "== organ_mesh (sliver cleanup and stable step of the organ)"
run organ_mesh "$out/organ_mesh.log" "$bin/organ_mesh" > "$out/organ_mesh.json"
cat "$out/organ_mesh.json"

echo "== shipped scenes headless (real-time factor, integrator each scene's time_step picks)"
# Each scene for SCENE_SECONDS simulated seconds on its default threads, the
# organ for its whole stroke (organ-cut.path, ORGAN_SECONDS);
# bench/scene_targets.py then checks the real-time targets on the JSON.
for scene in ligament beam block organ; do
  seconds="${SCENE_SECONDS:-2}"
  [[ $scene == organ ]] && seconds="${ORGAN_SECONDS:-8.4}"
  run "scene_$scene" "$out/scene_$scene.log" "$bin/cutsim-server" --headless --scene "scenes/$scene.pbtxt" \
    --duration "$seconds" --no-progress > "$out/scene_$scene.json"
done
# The organ at ~109k tets (bench/scenes/organ_large.pbtxt), its whole stroke.
run scene_organ_large "$out/scene_organ_large.log" "$bin/cutsim-server" --headless \
  --scene bench/scenes/organ_large.pbtxt --duration "${ORGAN_SECONDS:-8.4}" --no-progress \
  > "$out/scene_organ_large.json"
run scene_targets "$out/scene_targets.log" /usr/bin/python3 bench/scene_targets.py "$out" \
  > "$out/scene_targets.json"
cat "$out/scene_targets.json" 2>/dev/null || true

echo "== real-time sessions on the block and the organ (scripted haptic client cutting each)"
# Exit 77: no network namespace here (deploy/netns-run.sh), a skip.
for session in "block.pbtxt block-cut.path 6" "organ.pbtxt organ-cut.path 10" \
               "../bench/scenes/organ_large.pbtxt organ-cut.path 10"; do
  read -r scene path seconds <<<"$session"
  name="$(basename "$scene" .pbtxt)"
  rc=0
  bench/scene_session.sh "$PWD/$bin" "$PWD/$out" "$scene" "$path" "$seconds" \
    >"$out/session_$name.json" 2>"$out/session_$name.log" || rc=$?
  if [[ $rc -eq 77 ]]; then
    echo "session $name skipped (see $out/session_$name.log)"
  elif [[ $rc -ne 0 ]]; then
    echo "!! session_$name failed (exit $rc, see $out/session_$name.log)"
    failed+=("session_$name")
  fi
  cat "$out/session_$name.json" 2>/dev/null || true
done

echo "== browser observers (glass-to-glass latency, bytes/s per observer, server CPU with 0 and 20 clients)"
# Exit 77: no chromium, node packages or namespace, a skip.
for run in "ligament.pbtxt ligament-cut.path 6 0" "ligament.pbtxt ligament-cut.path 6 20" \
           "block.pbtxt block-cut.path 6 0" "organ.pbtxt organ-cut.path 9 0"; do
  read -r scene path seconds clients <<<"$run"
  name="observers_${scene%.pbtxt}_${clients}"
  rc=0
  bench/observer_session.sh "$PWD/$bin" "$PWD/$out/$name" "$scene" "$path" "$seconds" "$clients" \
    >"$out/$name.json" 2>"$out/$name.log" || rc=$?
  if [[ $rc -eq 77 ]]; then
    echo "$name skipped (see $out/$name.log)"
  elif [[ $rc -ne 0 ]]; then
    echo "!! $name failed (exit $rc, see $out/$name.log)"
    failed+=("$name")
  fi
  cat "$out/$name.json" 2>/dev/null || true
done

echo "== browser trainee on the skin pad (input-to-force and input-to-picture latency, p99 targets 50 and 100 ms)"
rc=0
bench/trainee_latency.sh "$PWD/$bin" "$PWD/$out/trainee" "${TRAINEE_MOVES:-600}" >"$out/trainee_latency.json" \
  2>"$out/trainee_latency.log" || rc=$?
if [[ $rc -eq 77 ]]; then
  echo "trainee latency skipped (see $out/trainee_latency.log)"
elif [[ $rc -ne 0 ]]; then
  echo "!! trainee_latency failed (exit $rc, see $out/trainee_latency.log)"
  failed+=(trainee_latency)
fi
cat "$out/trainee_latency.json" 2>/dev/null || true

echo "== debrief of a 61 s recording (first picture within 2 s of the launch, every seek within 1 s)"
# Its output ends with the JSON line; the per-seek lines stay in the .out.
rc=0
bench/debrief_seek.sh "$PWD/$bin" "$PWD/$out/debrief" >"$out/debrief_seek.out" 2>"$out/debrief_seek.log" || rc=$?
tail -n 1 "$out/debrief_seek.out" >"$out/debrief_seek.json" 2>/dev/null || true
if [[ $rc -ne 0 ]]; then
  echo "!! debrief_seek failed (exit $rc, see $out/debrief_seek.out and .log)"
  failed+=(debrief_seek)
fi
cat "$out/debrief_seek.json" 2>/dev/null || true

echo "== the package in a fresh Debian 12 root (deploy/verify-package.sh; root only, else skipped)"
if [[ "$(id -u)" -eq 0 ]] && command -v debootstrap >/dev/null; then
  run package "$out/package.log" ./deploy/package.sh >"$out/package.out"
  run verify_package "$out/verify_package.log" ./deploy/verify-package.sh >"$out/verify_package.out"
  tail -n 1 "$out/verify_package.out" 2>/dev/null || true
else
  echo "verify-package skipped: needs root and debootstrap"
fi

echo "== observer bridge under 1100 idle connections from one peer (page time for another peer, server CPU)"
run bridge_flood "$out/bridge_flood.log" "$bin/bridge_flood_bench" --idle 1100 --seconds 5 >"$out/bridge_flood.json"
cat "$out/bridge_flood.json" 2>/dev/null || true

echo "== lab view (8 and 32 sessions: bytes/s and frames/s per watched session, the lab bridge's CPU)"
run lab_bench "$out/lab_bench.log" "$bin/lab_bench" --bin "$bin" --seconds "${LAB_SECONDS:-5}" >"$out/lab_bench.json"
cat "$out/lab_bench.json" 2>/dev/null || true

echo "== implicit_bench (backward Euler at organ scale: step time, Newton/PCG iterations, a cut)"
run implicit_bench "$out/implicit.log" "$bin/implicit_bench" --cases organ,organ_soft,large --steps 10 \
  > "$out/implicit.json"
cat "$out/implicit.json" 2>/dev/null || true

echo "== budget_accuracy (the organ's stroke with the real-time frame budget against converged steps)"
run budget_accuracy "$out/budget_accuracy.log" /usr/bin/python3 bench/budget_accuracy.py "$PWD/$bin" \
  "$PWD/$out/budget" scenes/organ.pbtxt 0.6 > "$out/budget_accuracy.json"
cat "$out/budget_accuracy.json" 2>/dev/null || true

echo "== haptic loop under load (real server physics on the other core) vs bare loop"
# Exit 77: no network namespace here (deploy/netns-run.sh), a skip, not a failure.
rc=0
bench/haptic_session.sh "$PWD/$bin" "$PWD/$out" "${HAPTIC_SECONDS:-20}" >"$out/haptic_session.json" \
  2>"$out/haptic_session.log" || rc=$?
if [[ $rc -eq 77 ]]; then
  echo "haptic bench skipped (see $out/haptic_session.log)"
elif [[ $rc -ne 0 ]]; then
  echo "!! haptic_session failed (exit $rc, see $out/haptic_session.log)"
  failed+=(haptic_session)
fi
cat "$out/haptic_session.json" 2>/dev/null || true

echo "== flood resistance of the haptic link (hostile packets on the tool and model channels)"
# Exit 77: no network namespace here, a skip; exit 1: a target missed.
rc=0
bench/flood_session.sh "$PWD/$bin" "$PWD/$out" "${FLOOD_SECONDS:-10}" "${FLOOD_RATE:-50000}" \
  >"$out/flood_session.jsonl" 2>"$out/flood_session.log" || rc=$?
if [[ $rc -eq 77 ]]; then
  echo "flood bench skipped (see $out/flood_session.log)"
elif [[ $rc -ne 0 ]]; then
  echo "!! flood_session failed (exit $rc, see $out/flood_session.log)"
  failed+=(flood_session)
fi
cat "$out/flood_session.jsonl" 2>/dev/null || true

echo "== haptic loop per device (jitter; the cost of a plugin call against a built-in one)"
run device_loop "$out/device_loop.log" "$bin/cutsim-haptic-loop-bench" --devices \
  --seconds "${DEVICE_SECONDS:-10}" > "$out/device_loop.json"
cat "$out/device_loop.json" 2>/dev/null || true

echo "== buffer-model accuracy against a 1 kHz FEM reference"
run buffer_model_bench "$out/buffer_model.log" "$bin/buffer_model_bench" --scene scenes/ligament.pbtxt \
  > "$out/buffer_model.jsonl"
cat "$out/buffer_model.jsonl"

echo "== link_fidelity_bench (force error, energy into the hand and stability against one-way delay and loss)"
# A simulated link (fault injector on a simulated clock): deterministic.
run link_fidelity "$out/link_fidelity.log" "$bin/link_fidelity_bench" --scene-dir scenes \
  --trace "$out/link_fidelity_trace.json" > "$out/link_fidelity.json"
/usr/bin/python3 -c 'import json,sys; print("missed:", json.load(open(sys.argv[1]))["missed"])' \
  "$out/link_fidelity.json" 2>/dev/null || true

echo "== link across namespaces (real server and station over a veth pair, the block's fast press)"
# Exit 77: no namespaces or veth here, a skip.
rc=0
bench/link_netns.sh "$PWD/$bin" "$PWD/$out/link_netns" >"$out/link_netns.jsonl" 2>"$out/link_netns.log" || rc=$?
if [[ $rc -eq 77 ]]; then
  echo "link across namespaces skipped (see $out/link_netns.log)"
elif [[ $rc -ne 0 ]]; then
  echo "!! link_netns failed (exit $rc, see $out/link_netns.log)"
  failed+=(link_netns)
fi
cat "$out/link_netns.jsonl" 2>/dev/null || true

echo "== mesh_stream_bench (observers: delta vs snapshot bytes, late join, encode cost)"
run mesh_stream_bench "$out/mesh_stream.log" "$bin/mesh_stream_bench" --json "$out/mesh_stream.json" >/dev/null
cat "$out/mesh_stream.json" 2>/dev/null || true

echo "== headless cut of scenes/block.pbtxt (time per cut step, components)"
run block_cut "$out/block_cut.log" "$bin/cutsim-server" --headless --scene scenes/block.pbtxt --no-progress \
  > "$out/block_cut.json"

echo "== cut_bench (cut step by phase at 1k/10k/100k tets; block after 100 cuts: stable step, quality, throughput)"
run cut_bench "$out/cut_bench.log" "$bin/cut_bench" --scene-dir scenes --json "$out/cut_bench.json" >/dev/null
cat "$out/cut_bench.json" 2>/dev/null || true

echo "== accuracy_bench (run time against error: cantilever statics/dynamics, scripted cut)"
# The beam part is written to accuracy.json before the cutting part starts;
# the timeout guards against a hang in the cutting path.
run accuracy_bench "$out/accuracy.log" timeout "${ACCURACY_TIMEOUT:-1800}" "$bin/accuracy_bench" \
  --repeats "${ACCURACY_REPETITIONS:-1}" --out "$out/accuracy.json"

echo "== stability_bench (stress suite: Markdown table in stability.md)"
# Rows are written as cases finish; the timeout guards the random-cuts case
# (last) against a hang in the cutting path.
run stability_bench "$out/stability.log" timeout "${STABILITY_TIMEOUT:-900}" "$bin/stability_bench" \
  --out "$out/stability.json" > "$out/stability.md"
cat "$out/stability.md" 2>/dev/null || true

echo "== plots"
run plots "$out/plot.log" /usr/bin/python3 bench/plot.py "$out"

echo "== done in $(( $(date +%s) - start )) s; results in $out/"
if [[ ${#failed[@]} -gt 0 ]]; then
  echo "!! failed: ${failed[*]}" >&2
  exit 1
fi
