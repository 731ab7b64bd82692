#!/usr/bin/env bash
# Re-records scenes/ligament-cut.lcm, the session that tests/integration/
# replay_test.cc replays: a keyed real-time cutsim-server on the ligament and
# the scripted haptic client cutting it (scenes/ligament-cut.path) over LCM,
# inside a private network namespace (deploy/netns-run.sh). Then replays the
# new recording twice to check it.
#
#   scenes/record-ligament-cut.sh [BUILD_DIR]     (default build/ci)
#
# Re-record whenever the physics or the cutting changes on purpose: the
# recording pins their results (replay then reports the first frame whose cut
# decision differs). Use a portable build (presets ci, dev or asan — not
# release, whose -march=native rounds differently); the header records which.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build="$(cd "${1:-$root/build/ci}" && pwd)"
out="$root/scenes/ligament-cut.lcm"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
for exe in cutsim-server cutsim-haptic; do
  [ -x "$build/bin/$exe" ] || { echo "no $build/bin/$exe: build it first" >&2; exit 2; }
done

cat > "$work/session.sh" <<EOF
#!/usr/bin/env bash
set -euo pipefail
cd "$root"
url="udpm://239.255.76.67:7913?ttl=0"
openssl rand -hex 32 > "$work/session.key"
chmod 600 "$work/session.key"
"$build/bin/cutsim-server" --scene scenes/ligament.pbtxt --duration 3.2 --session ligament \
  --lcm-url "\$url" --key-file "$work/session.key" --record "$work/rec.lcm" \
  > "$work/server.out" 2> "$work/server.err" &
server=\$!
sleep 1
"$build/bin/cutsim-haptic" --device scripted --path scenes/ligament-cut.path --session ligament \
  --lcm-url "\$url" --key-file "$work/session.key" --csv - --no-rt > "$work/haptic.out" 2> "$work/haptic.err"
wait \$server
EOF
chmod +x "$work/session.sh"
"$root/deploy/netns-run.sh" "$work/session.sh" || { cat "$work/server.err" "$work/haptic.err" >&2; exit 1; }
cat "$work/server.out"
for run in 1 2; do
  (cd "$root" && "$build/bin/cutsim-server" --headless --replay "$work/rec.lcm" --log-level warn)
done
cp "$work/rec.lcm" "$out"
echo "wrote $out ($(stat -c %s "$out") bytes)"
