#!/usr/bin/env bash
# A disk that fills during a session fails the event journal loudly: a
# headless run cuts the block with its checkpoint (and so its journal) on a
# 512 KiB tmpfs, mounted in a private mount namespace, that a filler file
# leaves one page of. The journal's writes fail with ENOSPC once its records
# pass that page: the error names the journal, the summary counts the
# failures, and, with the filler removed as soon as the error is logged (so
# the final checkpoint is written), the exit status is 5 because of the
# journal alone. The control: the same run with room exits 0 with no
# failure.
#
#   tests/integration/journal_full_test.sh BIN_DIR
set -uo pipefail

bin="${1:?usage: $0 BIN_DIR}"
if [ "${CUTSIM_IN_MOUNTNS:-}" != "1" ]; then
  self="$(readlink -f "$0")"
  export CUTSIM_IN_MOUNTNS=1
  if [ "$(id -u)" -eq 0 ] && unshare --mount true 2>/dev/null; then
    exec unshare --mount "$self" "$@"
  elif unshare --user --map-root-user --mount true 2>/dev/null; then
    exec unshare --user --map-root-user --mount "$self" "$@"
  fi
  echo "journal_full_test: cannot create a mount namespace here (needs root or user namespaces); skipping" >&2
  exit 77
fi

src="$(cd "$(dirname "$0")/../.." && pwd)"
work="$(mktemp -d /tmp/cutsim-journal-full.XXXXXX)"
trap 'umount "$work/full" "$work/roomy" 2>/dev/null; rm -rf "$work"' EXIT
mkdir -p "$work/full" "$work/roomy"
if ! mount -t tmpfs -o size=512k cutsim-full "$work/full" || ! mount -t tmpfs -o size=4m cutsim-roomy "$work/roomy"; then
  echo "journal_full_test: cannot mount a tmpfs here; skipping" >&2
  exit 77
fi
fail=0

server=("$bin/cutsim-server" --headless --scene "$src/scenes/block.pbtxt" --checkpoint-every 0 --no-progress)

# The control: room for everything.
"${server[@]}" --checkpoint "$work/roomy/block.ckpt" >"$work/roomy.json" 2>"$work/roomy.err"
rc=$?
if [ "$rc" -ne 0 ] || ! grep -q '"journal":{[^}]*"failures":0' "$work/roomy.json" \
   || ! grep -qE '"journal":\{[^}]*"records":[1-9]' "$work/roomy.json"; then
  echo "journal_full_test: FAIL: control run: exit $rc" >&2
  cat "$work/roomy.json" "$work/roomy.err" >&2
  fail=1
else
  echo "journal_full_test: ok: control run journals its cuts and exits 0"
fi

# One free page left.
dd if=/dev/zero of="$work/full/filler" bs=4k count=127 status=none 2>/dev/null
"${server[@]}" --checkpoint "$work/full/block.ckpt" >"$work/full.json" 2>"$work/full.err" &
pid=$!
# Room again once the journal has failed: the final checkpoint is written,
# so the exit status reports the journal's loss alone.
for _ in $(seq 1 600); do
  if grep -q "event journal $work/full/block.ckpt.journal" "$work/full.err" 2>/dev/null \
     && grep -q "No space left on device" "$work/full.err"; then
    rm -f "$work/full/filler"
    break
  fi
  kill -0 "$pid" 2>/dev/null || break
  sleep 0.05
done
wait "$pid"
rc=$?
rm -f "$work/full/filler"
if [ "$rc" -ne 5 ]; then
  echo "journal_full_test: FAIL: full disk: exit $rc (want 5)" >&2
  fail=1
fi
if ! grep -q "event journal $work/full/block.ckpt.journal: write of the record at byte" "$work/full.err" \
   || ! grep -q "No space left on device" "$work/full.err"; then
  echo "journal_full_test: FAIL: full disk: no error naming the journal and ENOSPC" >&2
  fail=1
fi
if ! grep -qE '"journal":\{[^}]*"failures":[1-9]' "$work/full.json"; then
  echo "journal_full_test: FAIL: full disk: the summary counts no journal failure" >&2
  fail=1
fi
if ! grep -q "lost .* writes" "$work/full.err"; then
  echo "journal_full_test: FAIL: full disk: no error at exit" >&2
  fail=1
fi
if [ ! -s "$work/full/block.ckpt" ]; then
  echo "journal_full_test: FAIL: the final checkpoint was not written once there was room" >&2
  fail=1
fi
if [ "$fail" -ne 0 ]; then
  cat "$work/full.json" "$work/full.err" >&2
else
  grep -E "event journal|checkpoint" "$work/full.err" | head -5
  echo "journal_full_test: ok: a full disk fails the journal loudly (exit 5)"
fi
exit $fail
