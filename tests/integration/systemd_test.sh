#!/usr/bin/env bash
# The shipped systemd units, as configured for the install (UNIT_DIR: the
# build tree's deploy/systemd), exercised:
#  1. `systemd-analyze verify` on an instance of each template
#     (cutsim-{server,haptic,bridge}@NAME, binaries pointed at BIN_DIR); a
#     warning fails it as an error does;
#  2. their ExecStart lines, expanded the way systemd does: %i, the units'
#     Environment= defaults, then each EnvironmentFile= in order (the
#     configured cutsim.env, then NAME.env holding the test's overrides: a
#     scene, a 2 s tool path, DDS on lo), ${VAR} one word, $VAR split on
#     whitespace, a credentials directory holding a fresh key and observer
#     token, a state directory; run for real in a private network namespace:
#     the haptic station gets models from the server, its signed poses are
#     accepted, the bridge serves the observer page and opens its stream
#     only with the token, and SIGTERM leaves a checkpoint in the session's
#     state directory and the session's score in the lab's history
#     (--history in NAME.env).
#
#   tests/integration/systemd_test.sh BIN_DIR UNIT_DIR
set -uo pipefail

src="$(cd "$(dirname "$0")/../.." && pwd)"

if [ "${1:-}" = "--inside" ]; then
  # Second stage, inside deploy/netns-run.sh: $2 = work dir with
  # {server,haptic,bridge}.cmd (NUL-separated argv) and env.
  work="$2"
  mapfile -d '' server < "$work/server.cmd"
  mapfile -d '' haptic < "$work/haptic.cmd"
  mapfile -d '' bridge < "$work/bridge.cmd"
  # What EnvironmentFile= does: every KEY=value line exported as is.
  while IFS='=' read -r key value; do export "$key=$value"; done < "$work/env"
  "${server[@]}" > "$work/server.out" 2> "$work/server.log" &
  spid=$!
  "${bridge[@]}" > "$work/bridge.out" 2> "$work/bridge.log" &
  bpid=$!
  # Each waits for its start-up line, polling with a deadline rather than
  # sleeping a fixed time.
  wait_for() {  # file pattern pid what
    local deadline=$((SECONDS + 60))
    until grep -q "$2" "$1" 2>/dev/null; do
      if [ "$SECONDS" -ge "$deadline" ] || ! kill -0 "$3" 2>/dev/null; then
        echo "systemd_test: the $4 did not come up" >&2
        kill -TERM "$spid" "$bpid" 2>/dev/null
        exit 1
      fi
      sleep 0.05
    done
  }
  wait_for "$work/server.log" "session '.*': physics" "$spid" server
  wait_for "$work/bridge.out" "^observers: http" "$bpid" bridge
  url="$(sed -n 's/^observers: //p' "$work/bridge.out" | head -n 1)"
  base="${url%%\?*}"
  {
    "$src/tests/integration/http_get.py" --websocket "${base}ws"
    "$src/tests/integration/http_get.py" --websocket "${base}ws?${url#*\?}"
    "$src/tests/integration/http_get.py" "$url" "$work/page.html"
    "$src/tests/integration/http_get.py" "${base}vendor/three.module.js"
  } > "$work/http.codes"
  timeout 60 "${haptic[@]}" > "$work/haptic.out" 2> "$work/haptic.log"
  hrc=$?
  kill -TERM "$spid" "$bpid"
  wait "$spid"
  src_rc=$?
  wait "$bpid"
  brc=$?
  echo "haptic exit $hrc, server exit $src_rc, bridge exit $brc" >&2
  [ "$hrc" -eq 0 ] && [ "$src_rc" -eq 0 ] && [ "$brc" -eq 0 ]
  exit $?
fi

bin="${1:?usage: $0 BIN_DIR UNIT_DIR}"
units="${2:?usage: $0 BIN_DIR UNIT_DIR}"
session="sd$$"
work="$(mktemp -d /tmp/cutsim-systemd.XXXXXX)"
trap 'rc=$?; if [ $rc -ne 0 ] && [ $rc -ne 77 ]; then for f in "$work"/*.log; do echo "---- $f"; tail -n 20 "$f"; done >&2; fi; rm -rf "$work"; exit $rc' EXIT

# The configured units name the install's binaries (ExecStart) and its
# configuration folder (EnvironmentFile=, LoadCredential=): here BIN_DIR and
# the test's own folder.
bindir="$(sed -n 's#^ExecStart=\(/.*\)/cutsim-server .*#\1#p' "$units/cutsim-server@.service")"
confdir="$(sed -n 's#^EnvironmentFile=\(/.*\)/cutsim.env$#\1#p' "$units/cutsim-server@.service")"
[ -n "$bindir" ] && [ -n "$confdir" ] || { echo "systemd_test: cannot read ExecStart/EnvironmentFile of $units/cutsim-server@.service" >&2; exit 1; }
mkdir -p "$work/units" "$work/conf"
for u in server haptic bridge; do
  [ -f "$units/cutsim-$u@.service" ] || { echo "systemd_test: $units/cutsim-$u@.service missing" >&2; exit 1; }
  sed -e "s#$bindir/#$bin/#g" -e "s#$confdir/#$work/conf/#g" -e "s#/var/lib/cutsim/#$work/state/#g" \
    "$units/cutsim-$u@.service" > "$work/units/cutsim-$u@$session.service"
done

# The lab view's unit (no template): checked with the others.
[ -f "$units/cutsim-lab.service" ] || { echo "systemd_test: $units/cutsim-lab.service missing" >&2; exit 1; }
sed -e "s#$bindir/#$bin/#g" -e "s#$confdir/#$work/conf/#g" -e "s#/var/lib/cutsim/#$work/state/#g" \
  "$units/cutsim-lab.service" > "$work/units/cutsim-lab.service"

# 1. systemd's own check of the unit files, one instance of each template.
if command -v systemd-analyze >/dev/null; then
  if ! systemd-analyze verify --man=no "$work"/units/*.service > "$work/verify.log" 2>&1 || [ -s "$work/verify.log" ]; then
    cat "$work/verify.log" >&2
    echo "systemd_test: systemd-analyze verify failed or warned" >&2
    exit 1
  fi
  echo "systemd_test: systemd-analyze verify: ok"
else
  echo "systemd_test: systemd-analyze not installed; only running the command lines" >&2
fi

# 2. The configuration a unit would see: the configured cutsim.env, and this
# session's NAME.env with the test's overrides; the session's credentials.
cp "$units/cutsim.env" "$work/conf/cutsim.env"
mkdir -p "$work/credentials" "$work/state/$session"
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$work/credentials/session.key"
head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$work/credentials/observer.token"
chmod 600 "$work/credentials/session.key" "$work/credentials/observer.token"
cat > "$work/cut.path" <<'PATH'
0.00    0.0151 -0.0080 0.0100       0 0 1
0.40    0.0151 -0.0080 -0.0060      0 0 1
1.60    0.0151 0.0080 -0.0060       0 0 1
2.00    0.0151 0.0080 0.0100        0 0 1
PATH
cat > "$work/conf/$session.env" <<EOF
CUTSIM_SCENE=$src/scenes/ligament.pbtxt
CUTSIM_CHECKPOINT_EVERY=1
CUTSIM_SERVER_ARGS=--no-rt --history $work/state/history.sqlite --trainee alice
CUTSIM_HAPTIC_ARGS=--device scripted --path $work/cut.path --csv $work/haptic.csv --no-rt
CUTSIM_BRIDGE_LISTEN=127.0.0.1:0
CYCLONEDDS_URI=file://$src/deploy/cyclonedds-unicast.xml
CUTSIM_DDS_INTERFACE=lo
CUTSIM_DDS_PEER1=127.0.0.1
EOF

# ExecStart= → argv, with systemd's expansion rules.
python3 - "$work" "$session" <<'PY' || exit 1
import re, sys
work, session = sys.argv[1], sys.argv[2]
runtime = {"CREDENTIALS_DIRECTORY": f"{work}/credentials", "STATE_DIRECTORY": f"{work}/state:{work}/state/{session}",
           "LOGS_DIRECTORY": f"{work}/state/{session}"}
def read_env(path, env):
    for line in open(path):
        line = line.rstrip("\n")
        if re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", line):
            k, _, v = line.partition("=")
            env[k] = v
exported = {}
for unit in ("server", "haptic", "bridge"):
    name = f"cutsim-{unit}@{session}.service"
    text = open(f"{work}/units/{name}").read().replace("%i", session)
    lines = text.splitlines()
    for needed in ("Restart=on-failure", f"EnvironmentFile={work}/conf/cutsim.env",
                   f"EnvironmentFile=-{work}/conf/{session}.env", f"LoadCredential=session.key:{work}/conf/{session}.key"):
        if needed not in lines:
            sys.exit(f"{name}: missing {needed}")
    env = dict(runtime)
    for l in lines:  # defaults first, then the files in their order
        if l.startswith("Environment="):
            k, _, v = l[len("Environment="):].partition("=")
            env[k] = v
    for l in lines:
        if l.startswith("EnvironmentFile="):
            read_env(l[len("EnvironmentFile="):].lstrip("-"), env)
    exported.update(env)
    line = next(l for l in lines if l.startswith("ExecStart="))[len("ExecStart="):]
    argv = []
    for word in line.split():
        m = re.fullmatch(r"\$([A-Za-z_][A-Za-z0-9_]*)", word)
        if m:  # $VAR: split into words
            argv += env.get(m.group(1), "").split()
            continue
        def sub(m):
            if m.group(1) not in env:
                sys.exit(f"{name}: ${{{m.group(1)}}} is set by neither the unit nor its environment files")
            return env[m.group(1)]
        argv.append(re.sub(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}", sub, word))
    open(f"{work}/{unit}.cmd", "wb").write(b"\0".join(a.encode() for a in argv) + b"\0")
    print(f"systemd_test: {unit}: {' '.join(argv)}")
with open(f"{work}/env", "w") as f:
    for k, v in exported.items():
        f.write(f"{k}={v}\n")
PY

"$src/deploy/netns-run.sh" "$0" --inside "$work"
rc=$?
[ "$rc" -eq 77 ] && exit 77
[ "$rc" -eq 0 ] || { echo "systemd_test: the units' command lines failed" >&2; exit 1; }

python3 - "$work" "$session" <<'PY'
import json, re, sys, os, sqlite3
work, session = sys.argv[1], sys.argv[2]
server = json.loads(open(f"{work}/server.out").read().strip().splitlines()[-1])
haptic = None
for line in open(f"{work}/haptic.out").read().splitlines() + open(f"{work}/haptic.log").read().splitlines():
    m = re.search(r'(\{"kind":"haptic_stats".*\})', line)
    if m: haptic = json.loads(m.group(1))
codes = open(f"{work}/http.codes").read().split()
history = sqlite3.connect(f"{work}/state/history.sqlite").execute(
    "SELECT session, cuts FROM sessions WHERE trainee = 'alice'").fetchall() if os.path.exists(f"{work}/state/history.sqlite") else []
fail = []
if haptic is None or haptic["models_accepted"] <= 10: fail.append(f"haptic models: {haptic and haptic['models_accepted']}")
if server["tool_messages"] <= 5: fail.append(f"server tool messages: {server['tool_messages']}")
if server["tool_rejected"] != 0: fail.append(f"signed poses rejected: {server['tool_rejected']}")
if not os.path.exists(f"{work}/state/{session}/checkpoint.pb"): fail.append("no checkpoint in the session's state directory after SIGTERM")
if codes != ["403", "101", "200", "200"]:
    fail.append(f"bridge HTTP codes (stream without token, with it, page, three.js): {codes}, want 403 101 200 200")
elif "cutsim observer" not in open(f"{work}/page.html").read(): fail.append("the bridge's page is not the observer page")
if len(history) != 1 or history[0][0] != session: fail.append(f"the score history holds {history}, want one session {session} of alice")
print(json.dumps({"systemd_test": "fail" if fail else "pass", "models_accepted": haptic and haptic["models_accepted"],
                  "tool_messages": server["tool_messages"], "tool_rejected": server["tool_rejected"],
                  "bridge_http": codes, "history": history}))
for f in fail: print("systemd_test: FAILED:", f, file=sys.stderr)
sys.exit(1 if fail else 0)
PY
