#!/usr/bin/env bash
# Runs a command inside a fresh, private network namespace whose only
# interface is loopback, with multicast routed over it. LCM (UDP multicast)
# and Cyclone DDS then work between the processes of the command and nothing
# at all — not even an IGMP report — reaches the machine's real interfaces.
#
#   deploy/netns-run.sh CMD [ARGS...]
#
# As root this uses `unshare --net`; otherwise an unprivileged user namespace
# (`unshare --user --map-root-user --net`). If neither is permitted it exits
# 77 (the conventional "skip" code) with the reason on stderr.
set -euo pipefail

if [ "${CUTSIM_IN_NETNS:-}" = "1" ]; then
  # Second stage, inside the namespace: bring loopback up for multicast.
  ip link set lo up
  ip link set lo multicast on
  ip route add 224.0.0.0/4 dev lo 2>/dev/null || true
  exec "$@"
fi

if [ $# -eq 0 ]; then
  echo "usage: $0 CMD [ARGS...]" >&2
  exit 2
fi

self="$(readlink -f "$0")"
export CUTSIM_IN_NETNS=1
if [ "$(id -u)" -eq 0 ] && unshare --net true 2>/dev/null; then
  exec unshare --net "$self" "$@"
elif unshare --user --map-root-user --net true 2>/dev/null; then
  exec unshare --user --map-root-user --net "$self" "$@"
fi
echo "netns-run: cannot create a network namespace here (needs root or unprivileged user namespaces); skipping" >&2
exit 77
