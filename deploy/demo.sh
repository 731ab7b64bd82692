#!/usr/bin/env bash
# The README's demo command: installs what is missing, builds the release
# preset, then runs a whole session on this machine and leaves in ./out/:
#
#   out/frames/        PNG frames of a viewer that watched from the start
#   out/frames-late/   PNG frames of a viewer that joined 2 s late
#   out/session.mp4    the first viewer's video (when ffmpeg is installed)
#   out/haptic.csv     the haptic client's 1 kHz log (force, model age, timing)
#   out/haptic-force.png  force over time, with the cut marked
#   out/summary.json   cuts, frames, loop statistics, resyncs of every process
#   out/block.vtu      a headless cut of scenes/block.pbtxt (open in ParaView)
#
# The session: cutsim-server on scenes/ligament.pbtxt (the seed paper's
# ligament), cutsim-haptic with the scripted device cutting it along
# scenes/ligament-cut.path, and two cutsim-viewer processes. Everything runs
# inside a private network namespace with only loopback (deploy/netns-run.sh),
# so no LCM or DDS packet leaves this machine.
set -euo pipefail
cd "$(dirname "$0")/.."
root="$PWD"

if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  ./deploy/install-deps.sh
  echo "== build (release)"
  cmake --preset release >/dev/null
  cmake --build --preset release -j "$(nproc)" --target cutsim-server cutsim-haptic cutsim-viewer
fi
bin="$root/build/release/bin"

out="$root/out"
rm -rf "$out/frames" "$out/frames-late"
mkdir -p "$out"

if [ "${CUTSIM_IN_NETNS:-}" != "1" ]; then
  # Re-enter this script inside a private loopback-only network namespace.
  exec ./deploy/netns-run.sh "$0" "$@"
fi

pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
}
trap cleanup EXIT INT TERM

echo "== session: server + scripted haptic client + two viewers (ligament, seed parameters)"
"$bin/cutsim-server" --scene scenes/ligament.pbtxt --duration 6 --stats-json "$out/server.json" \
  >"$out/server.log" 2>&1 &
pids+=($!)
sleep 0.5
video=()
if command -v ffmpeg >/dev/null; then video=(--video "$out/session.mp4"); fi
"$bin/cutsim-viewer" --frames "$out/frames" "${video[@]}" --exit-when-idle 2 \
  --summary "$out/viewer.json" >"$out/viewer.log" 2>&1 &
pids+=($!)
sleep 0.5
"$bin/cutsim-haptic" --device scripted --path scenes/ligament-cut.path --csv "$out/haptic.csv" \
  >"$out/haptic.json" 2>"$out/haptic.log" &
haptic=$!
pids+=($haptic)
sleep 2
"$bin/cutsim-viewer" --frames "$out/frames-late" --exit-when-idle 2 \
  --summary "$out/viewer-late.json" >"$out/viewer-late.log" 2>&1 &
pids+=($!)
status=0
for p in "${pids[@]}"; do wait "$p" || status=$?; done
pids=()
if [ "$status" -ne 0 ]; then
  echo "demo: a process failed (exit $status); logs are in $out/*.log" >&2
  exit "$status"
fi

echo "== headless: cutting scenes/block.pbtxt along its tool path"
"$bin/cutsim-server" --headless --scene scenes/block.pbtxt --out "$out/block.vtu" --no-progress \
  >"$out/block.json" 2>"$out/block.log"

/usr/bin/python3 deploy/demo_report.py "$out"
