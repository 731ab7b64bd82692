#!/usr/bin/env bash
# The shipped systemd units and example environment file, exercised:
#  1. `systemd-analyze verify` on both units (binaries pointed at BIN_DIR);
#  2. their ExecStart lines, expanded the way systemd does (${VAR} one word,
#     $VAR split on whitespace) from deploy/systemd/cutsim.env.example plus a
#     few test overrides (scene, checkpoint, a 2 s tool path, DDS on lo) and
#     a credentials directory holding a fresh session key, run for real in a
#     private network namespace: the haptic client gets models from the
#     server, its signed poses are accepted, and SIGTERM leaves a checkpoint.
#
#   tests/integration/systemd_test.sh BIN_DIR
set -uo pipefail

src="$(cd "$(dirname "$0")/../.." && pwd)"
units="$src/deploy/systemd"

if [ "${1:-}" = "--inside" ]; then
  # Second stage, inside deploy/netns-run.sh: $2 = work dir with server.cmd, haptic.cmd (NUL-separated argv).
  work="$2"
  mapfile -d '' server < "$work/server.cmd"
  mapfile -d '' haptic < "$work/haptic.cmd"
  # What EnvironmentFile= does: every KEY=value line exported as is.
  while IFS='=' read -r key value; do export "$key=$value"; done < "$work/env"
  "${server[@]}" > "$work/server.out" 2> "$work/server.log" &
  spid=$!
  # The client starts once the server's session is up (its start-up log
  # line), polling with a deadline rather than sleeping a fixed time.
  deadline=$((SECONDS + 60))
  until grep -q "session '.*': physics" "$work/server.log" 2>/dev/null; do
    if [ "$SECONDS" -ge "$deadline" ] || ! kill -0 "$spid" 2>/dev/null; then
      echo "systemd_test: the server did not come up" >&2
      exit 1
    fi
    sleep 0.05
  done
  timeout 60 "${haptic[@]}" > "$work/haptic.out" 2> "$work/haptic.log"
  hrc=$?
  kill -TERM "$spid"
  wait "$spid"
  src_rc=$?
  echo "haptic exit $hrc, server exit $src_rc" >&2
  [ "$hrc" -eq 0 ] && [ "$src_rc" -eq 0 ]
  exit $?
fi

bin="${1:?usage: $0 BIN_DIR}"
work="$(mktemp -d /tmp/cutsim-systemd.XXXXXX)"
trap 'rc=$?; if [ $rc -ne 0 ] && [ $rc -ne 77 ]; then for f in "$work"/*.log; do echo "---- $f"; tail -n 20 "$f"; done >&2; fi; rm -rf "$work"; exit $rc' EXIT

# 1. systemd's own check of the unit files.
mkdir -p "$work/units"
for u in server haptic; do
  sed "s#/usr/local/bin#$bin#g" "$units/cutsim-$u.service" > "$work/units/cutsim-$u.service"
done
if command -v systemd-analyze >/dev/null; then
  systemd-analyze verify --man=no "$work/units/cutsim-server.service" "$work/units/cutsim-haptic.service" \
    || { echo "systemd_test: systemd-analyze verify failed" >&2; exit 1; }
  echo "systemd_test: systemd-analyze verify: ok"
else
  echo "systemd_test: systemd-analyze not installed; only running the command lines" >&2
fi

# 2. The environment a unit would see: the example file, then test overrides.
mkdir -p "$work/credentials"
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$work/credentials/session.key"
chmod 600 "$work/credentials/session.key"
cat > "$work/cut.path" <<'PATH'
0.00    0.0151 -0.0080 0.0100       0 0 1
0.40    0.0151 -0.0080 -0.0060      0 0 1
1.60    0.0151 0.0080 -0.0060       0 0 1
2.00    0.0151 0.0080 0.0100        0 0 1
PATH
{
  grep -E '^[A-Z_][A-Z0-9_]*=' "$units/cutsim.env.example"
  echo "CUTSIM_SESSION=sd$$"
  echo "CUTSIM_SCENE=$src/scenes/ligament.pbtxt"
  echo "CUTSIM_CHECKPOINT=$work/checkpoint.pb"
  echo "CUTSIM_CHECKPOINT_EVERY=1"
  echo "CUTSIM_HAPTIC_ARGS=--device scripted --path $work/cut.path --csv $work/haptic.csv --no-rt"
  echo "CYCLONEDDS_URI=file://$src/deploy/cyclonedds-unicast.xml"
  echo "CUTSIM_DDS_INTERFACE=lo"
  echo "CUTSIM_DDS_PEER1=127.0.0.1"
  echo "CREDENTIALS_DIRECTORY=$work/credentials"
} > "$work/env"

# ExecStart= → argv, with systemd's expansion rules.
python3 - "$work" <<'PY' || exit 1
import re, sys
work = sys.argv[1]
env = {}
for line in open(f"{work}/env"):
    k, _, v = line.rstrip("\n").partition("=")
    env[k] = v
for unit in ("server", "haptic"):
    text = open(f"{work}/units/cutsim-{unit}.service").read()
    for needed in ("Restart=on-failure", "EnvironmentFile=/etc/cutsim/cutsim.env"):
        if needed not in text:
            sys.exit(f"cutsim-{unit}.service: missing {needed}")
    line = next(l for l in text.splitlines() if l.startswith("ExecStart="))[len("ExecStart="):]
    argv = []
    for word in line.split():
        m = re.fullmatch(r"\$([A-Za-z_][A-Za-z0-9_]*)", word)
        if m:  # $VAR: split into words
            argv += env.get(m.group(1), "").split()
            continue
        def sub(m):
            if m.group(1) not in env:
                sys.exit(f"cutsim-{unit}.service: ${{{m.group(1)}}} is not set by the environment file")
            return env[m.group(1)]
        argv.append(re.sub(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}", sub, word))
    open(f"{work}/{unit}.cmd", "wb").write(b"\0".join(a.encode() for a in argv) + b"\0")
    print(f"systemd_test: {unit}: {' '.join(argv)}")
PY

"$src/deploy/netns-run.sh" "$0" --inside "$work"
rc=$?
[ "$rc" -eq 77 ] && exit 77
[ "$rc" -eq 0 ] || { echo "systemd_test: the units' command lines failed" >&2; exit 1; }

python3 - "$work" <<'PY'
import json, re, sys, os
work = sys.argv[1]
server = json.loads(open(f"{work}/server.out").read().strip().splitlines()[-1])
haptic = None
for line in open(f"{work}/haptic.out").read().splitlines() + open(f"{work}/haptic.log").read().splitlines():
    m = re.search(r'(\{"kind":"haptic_stats".*\})', line)
    if m: haptic = json.loads(m.group(1))
fail = []
if haptic is None or haptic["models_accepted"] <= 10: fail.append(f"haptic models: {haptic and haptic['models_accepted']}")
if server["tool_messages"] <= 5: fail.append(f"server tool messages: {server['tool_messages']}")
if server["tool_rejected"] != 0: fail.append(f"signed poses rejected: {server['tool_rejected']}")
if not os.path.exists(f"{work}/checkpoint.pb"): fail.append("no checkpoint after SIGTERM")
print(json.dumps({"systemd_test": "fail" if fail else "pass", "models_accepted": haptic and haptic["models_accepted"],
                  "tool_messages": server["tool_messages"], "tool_rejected": server["tool_rejected"]}))
for f in fail: print("systemd_test: FAILED:", f, file=sys.stderr)
sys.exit(1 if fail else 0)
PY
