#!/usr/bin/env bash
# Outputs that cannot be written fail loudly: `--record /dev/full` (a device
# that refuses every write), a `--checkpoint` or `--stats-json` in a
# missing directory and an event journal (beside the checkpoint) that is a
# directory exit non-zero at start, naming the file, instead of
# running a session whose recording is then lost. Run inside a private
# network namespace (deploy/netns-run.sh): the real-time server opens LCM and
# DDS on loopback only.
#
#   tests/integration/outputs_test.sh BIN_DIR
set -uo pipefail

bin="${1:?usage: $0 BIN_DIR}"
src="$(cd "$(dirname "$0")/../.." && pwd)"
work="$(mktemp -d /tmp/cutsim-outputs.XXXXXX)"
trap 'rm -rf "$work"' EXIT
fail=0

# expect NAME CODE_PATTERN TEXT CMD...: CMD exits with a code matching
# CODE_PATTERN within 60 s and its stderr contains TEXT.
expect() {
  local name="$1" codes="$2" text="$3"
  shift 3
  timeout 60 "$@" >"$work/out" 2>"$work/err"
  local rc=$?
  if [[ ! "$rc" =~ ^($codes)$ ]] || { [ -n "$text" ] && ! grep -qF -- "$text" "$work/err"; }; then
    echo "outputs_test: FAIL: $name: exit $rc (want $codes), stderr:" >&2
    cat "$work/err" >&2
    fail=1
  else
    echo "outputs_test: ok: $name (exit $rc)"
  fi
}

server=("$bin/cutsim-server" --scene "$src/scenes/ligament.pbtxt" --no-rt --lcm-url "udpm://239.255.76.67:7911?ttl=0"
        --session outputs-$$ --duration 0.5 --log-level warn)
expect "record to a full device" "2|5" "/dev/full" "${server[@]}" --record /dev/full
expect "checkpoint in a missing directory" "2" "does not exist" "${server[@]}" --checkpoint "$work/no/such/x.ckpt"
mkdir -p "$work/j.ckpt.journal"
expect "event journal path is a directory" "2" "event journal" "${server[@]}" --checkpoint "$work/j.ckpt"
expect "stats in a missing directory" "2" "does not exist" "${server[@]}" --stats-json "$work/no/such/s.json"
expect "headless output is a directory" "2" "directory" \
  "$bin/cutsim-server" --headless --scene "$src/scenes/block.pbtxt" --duration 0.01 --out "$work" --log-level warn
# The control: the same session with a writable recording exits 0 and the
# recording replays.
expect "control: writable recording" "0" "" "${server[@]}" --record "$work/ok.lcm"
expect "control: the recording replays" "0" "" "$bin/cutsim-server" --headless --replay "$work/ok.lcm" --log-level warn
exit $fail
