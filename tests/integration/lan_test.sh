#!/usr/bin/env bash
# A session across "machines" on one host: the server, the haptic
# station and a viewer each in their own network namespace, joined by veth
# pairs to a bridge that lives in a fourth namespace (nothing touches the
# host's interfaces). LCM uses multicast with ttl=1 routed over the veths,
# Cyclone DDS unicast discovery to the peers' addresses
# (deploy/cyclonedds-unicast.xml), and nftables drops N % of the UDP packets
# arriving in each namespace. Checks: the haptic client gets models, the
# tissue gets cut, the viewer renders hash-verified frames, and packets were
# really dropped.
#
#   tests/integration/lan_test.sh BIN_DIR [LOSS_PERCENT]
#
# Needs root (CI runs as root), iproute2 and nftables; otherwise exits 77
# (skip) with the reason. Every namespace is deleted on every exit path.
set -uo pipefail

bin="${1:?usage: $0 BIN_DIR [LOSS_PERCENT]}"
loss="${2:-5}"
src="$(cd "$(dirname "$0")/../.." && pwd)"

skip() { echo "lan_test: SKIP: $*" >&2; exit 77; }
[ "$(id -u)" -eq 0 ] || skip "needs root to create network namespaces and veth pairs"
command -v ip >/dev/null || skip "iproute2 (ip) is not installed"
command -v nft >/dev/null || skip "nftables (nft) is not installed"
for b in cutsim-server cutsim-haptic cutsim-viewer; do
  [ -x "$bin/$b" ] || { echo "lan_test: $bin/$b missing" >&2; exit 1; }
done

id="$$"
br="cs-br-$id"
declare -A addr=([srv]=10.77.0.1 [hap]=10.77.0.2 [view]=10.77.0.3)
work="$(mktemp -d /tmp/cutsim-lan.XXXXXX)"
pids=()

cleanup() {
  local rc=$?
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  sleep 0.3
  for p in "${pids[@]}"; do kill -KILL "$p" 2>/dev/null; done
  wait 2>/dev/null
  for n in srv hap view; do ip netns del "cs-$n-$id" 2>/dev/null; done
  ip netns del "$br" 2>/dev/null
  if [ "$rc" -ne 0 ] && [ "$rc" -ne 77 ]; then
    for f in "$work"/*.log; do echo "---- $f"; tail -n 30 "$f"; done >&2
  fi
  rm -rf "$work"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

ip netns add "$br" 2>/dev/null || skip "ip netns add is not permitted here"
ip -n "$br" link set lo up
ip -n "$br" link add br0 type bridge mcast_snooping 0 || skip "no bridge support in this kernel"
ip -n "$br" link set br0 up
for n in srv hap view; do
  ns="cs-$n-$id"
  ip netns add "$ns" || exit 1
  # The pair is created inside the bridge namespace, then one end moves to
  # the node's namespace: no interface ever appears on the host.
  ip -n "$br" link add "p-$n" type veth peer name eth0 netns "$ns" || exit 1
  ip -n "$br" link set "p-$n" master br0 up
  ip -n "$ns" link set lo up
  ip -n "$ns" addr add "${addr[$n]}/24" dev eth0
  ip -n "$ns" link set eth0 multicast on up
  ip -n "$ns" route add 224.0.0.0/4 dev eth0  # LCM's group over the veth
  # Packet loss: drop LOSS % of the UDP datagrams arriving here (LCM and DDS).
  ip netns exec "$ns" nft -f - <<NFT || skip "nftables rules cannot be loaded (numgen/kernel support)"
table inet cutsim_loss {
  chain input {
    type filter hook input priority 0; policy accept;
    meta l4proto udp numgen random mod 100 < $loss counter drop
  }
}
NFT
done
session="lan$id"
lcm="udpm://239.255.76.67:7667?ttl=1"
dds_env=(CYCLONEDDS_URI="file://$src/deploy/cyclonedds-unicast.xml" CUTSIM_DDS_INTERFACE=eth0
         CUTSIM_DDS_PEER1="${addr[srv]}" CUTSIM_DDS_PEER2="${addr[hap]}" CUTSIM_DDS_PEER3="${addr[view]}")
run() {  # run NS LOG CMD...: in the background inside namespace NS
  local ns="$1" log="$2"
  shift 2
  ip netns exec "cs-$ns-$id" env "${dds_env[@]}" "$@" >"$work/$log.log" 2>&1 &
  pids+=("$!")
}

run srv server "$bin/cutsim-server" --scene "$src/scenes/ligament.pbtxt" --duration 5 --session "$session" \
    --lcm-url "$lcm" --stats-json "$work/server.json" --log-level info --no-rt
srv_pid="${pids[-1]}"
run view viewer "$bin/cutsim-viewer" --session "$session" --frames "$work/frames" --fps 5 \
    --exit-when-idle 4 --summary "$work/viewer.json" --log-level warn
view_pid="${pids[-1]}"
# The haptic station starts once the server's session is up (its start-up
# log line), polling with a deadline rather than sleeping a fixed time.
deadline=$((SECONDS + 60))
until grep -q "session '$session': physics" "$work/server.log" 2>/dev/null; do
  if [ "$SECONDS" -ge "$deadline" ] || ! kill -0 "$srv_pid" 2>/dev/null; then
    echo "lan_test: the server did not come up" >&2
    exit 1
  fi
  sleep 0.05
done
run hap haptic "$bin/cutsim-haptic" --device scripted --path "$src/scenes/ligament-cut.path" --session "$session" \
    --lcm-url "$lcm" --csv "$work/haptic.csv" --no-rt --fault-delay-ms 2 --fault-jitter-ms 1
hap_pid="${pids[-1]}"

status=0
wait "$hap_pid" || { echo "lan_test: haptic client failed" >&2; status=1; }
wait "$srv_pid" || { echo "lan_test: server failed" >&2; status=1; }
wait "$view_pid" || { echo "lan_test: viewer failed" >&2; status=1; }
pids=()
[ "$status" -eq 0 ] || exit 1

drops=0
for n in srv hap view; do
  c="$(ip netns exec "cs-$n-$id" nft list chain inet cutsim_loss input | sed -n 's/.*counter packets \([0-9]*\).*/\1/p')"
  drops=$((drops + ${c:-0}))
done

python3 - "$work" "$drops" "$loss" <<'PY'
import json, sys, re
work, drops, loss = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
server = json.load(open(f"{work}/server.json"))
viewer = json.load(open(f"{work}/viewer.json"))
haptic = None
for line in open(f"{work}/haptic.log"):
    m = re.search(r'(\{"kind":"haptic_stats".*\})', line)
    if m: haptic = json.loads(m.group(1))
failures = []
def check(ok, what):
    if not ok: failures.append(what)
check(haptic is not None, "haptic client printed its statistics")
if haptic:
    check(haptic["models_accepted"] > 10, f"haptic client got models ({haptic['models_accepted']})")
check(server["tool_messages"] > 5, f"server got tool poses ({server['tool_messages']})")
check(server["cuts"] >= 1 and server["topology_version"] >= 1,
      f"tissue cut (cuts {server['cuts']}, topology {server['topology_version']})")
check(viewer["verified_frames"] > 5, f"viewer verified frames ({viewer['verified_frames']})")
check(viewer["hash_mismatches"] == 0, f"no hash mismatch ({viewer['hash_mismatches']})")
check(drops > 0, f"nftables dropped packets ({drops})")
print(json.dumps({"lan_test": "pass" if not failures else "fail", "loss_percent": loss, "packets_dropped": drops,
                  "models_accepted": haptic and haptic["models_accepted"], "tool_messages": server["tool_messages"],
                  "cuts": server["cuts"], "topology_version": server["topology_version"],
                  "viewer_verified_frames": viewer["verified_frames"], "viewer_resyncs": viewer["resyncs"],
                  "viewer_hash_mismatches": viewer["hash_mismatches"]}))
for f in failures: print("lan_test: FAILED:", f, file=sys.stderr)
sys.exit(1 if failures else 0)
PY
