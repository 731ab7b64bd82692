#!/usr/bin/env bash
# The link fidelity benchmark across "hosts": the server and the haptic
# station as real processes in two network namespaces joined by a veth pair
# (nothing touches the host's interfaces), the station running the block's
# fast press with the scripted device. The link is delayed one-way by
# DELAY ms ±20 % and loses LOSS % of the datagrams in each direction:
# by the kernel (tc netem on both ends of the veth) where it has netem,
# else by the station's fault injector (--fault-*, both directions). Each
# run's force is compared with the in-process reference at the positions the
# station logged (link_fidelity_bench --compare-csv). One JSON line per run;
# "link" says which did the delaying.
#
#   bench/link_netns.sh BIN_DIR OUT_DIR ["DELAY_MS:LOSS_PERCENT ..."]
#
# Needs root and iproute2; otherwise exits 77 (skip) with the reason.
set -uo pipefail

bin="${1:?usage: $0 BIN_DIR OUT_DIR [DELAY:LOSS ...]}"
out="${2:?usage: $0 BIN_DIR OUT_DIR [DELAY:LOSS ...]}"
runs="${3:-0:0 25:0 100:0 25:5 100:5}"
src="$(cd "$(dirname "$0")/.." && pwd)"
# shellcheck source=bench/wait_for_server.sh
source "$src/bench/wait_for_server.sh"

skip() { echo "link_netns: SKIP: $*" >&2; exit 77; }
[ "$(id -u)" -eq 0 ] || skip "needs root to create network namespaces and a veth pair"
command -v ip >/dev/null || skip "iproute2 (ip) is not installed"
for b in cutsim-server cutsim-haptic link_fidelity_bench; do
  [ -x "$bin/$b" ] || { echo "link_netns: $bin/$b missing" >&2; exit 1; }
done

id="$$"
srv="cs-lsrv-$id"
hap="cs-lhap-$id"
mkdir -p "$out"
pids=()
cleanup() {
  local rc=$?
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  sleep 0.3
  for p in "${pids[@]}"; do kill -KILL "$p" 2>/dev/null; done
  wait 2>/dev/null
  ip netns del "$srv" 2>/dev/null
  ip netns del "$hap" 2>/dev/null
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

ip netns add "$srv" 2>/dev/null || skip "ip netns add is not permitted here"
ip netns add "$hap" || exit 1
# The pair is created in the server's namespace with its peer in the
# station's: no interface ever appears on the host.
ip -n "$srv" link add eth0 type veth peer name eth0 netns "$hap" || skip "no veth support in this kernel"
for pair in "$srv 10.78.0.1" "$hap 10.78.0.2"; do
  read -r ns addr <<<"$pair"
  ip -n "$ns" link set lo up
  ip -n "$ns" addr add "$addr/24" dev eth0
  ip -n "$ns" link set eth0 multicast on up
  ip -n "$ns" route add 224.0.0.0/4 dev eth0  # LCM's group over the veth
done
netem=0
if ip netns exec "$srv" tc qdisc add dev eth0 root netem delay 1ms 2>/dev/null; then
  ip netns exec "$srv" tc qdisc del dev eth0 root
  netem=1
else
  echo "link_netns: no netem in this kernel: the station's fault injector delays and drops" >&2
fi

# The block with cutting off and the tool waiting above the press point.
"$bin/link_fidelity_bench" --scene-dir "$src/scenes" --compare-scene block --path-out "$out/stroke.path" || exit 1
read -r _ x y z _ < <(grep -v '^#' "$out/stroke.path" | head -1)
sed -e 's/enabled: true/enabled: false/' \
    -e "s#path_file: .*#keyframes { t: 0 tip { x: $x y: $y z: $z } blade_dir { z: 1 } }#" \
    "$src/scenes/block.pbtxt" > "$out/block_nocut.pbtxt"
lcm="udpm://239.255.76.67:7667?ttl=1"

for run in $runs; do
  delay="${run%%:*}"
  loss="${run##*:}"
  name="d${delay}_l${loss}"
  jitter_lo=$(/usr/bin/python3 -c "print(0.8 * $delay)")
  jitter_span=$(/usr/bin/python3 -c "print(0.4 * $delay)")
  faults=()
  if [ "$netem" -eq 1 ]; then
    link="netem"
    for ns in "$srv" "$hap"; do
      ip netns exec "$ns" tc qdisc replace dev eth0 root netem delay "${delay}ms" \
        "$(/usr/bin/python3 -c "print(0.2 * $delay)")ms" distribution uniform loss "${loss}%" || exit 1
    done
  else
    link="fault_injector"
    faults=(--fault-delay-ms "$jitter_lo" --fault-jitter-ms "$jitter_span"
            --fault-drop "$(/usr/bin/python3 -c "print($loss / 100)")" --fault-direction both)
  fi
  session="lf$id$delay$loss"
  ip netns exec "$srv" "$bin/cutsim-server" --scene "$out/block_nocut.pbtxt" --duration 86400 --session "$session" \
    --lcm-url "$lcm" --no-rt --threads 1 >/dev/null 2>"$out/$name.server.log" &
  server=$!
  pids=("$server")
  wait_for_server "$out/$name.server.log" "$server" 60
  ip netns exec "$hap" "$bin/cutsim-haptic" --device scripted --path "$out/stroke.path" --session "$session" \
    --lcm-url "$lcm" --csv "$out/$name.csv" --no-rt "${faults[@]}" \
    >"$out/$name.station.json" 2>"$out/$name.station.log" || { echo "link_netns: station failed ($name)" >&2; exit 1; }
  kill -TERM "$server"; wait "$server" 2>/dev/null
  pids=()
  line=$("$bin/link_fidelity_bench" --scene-dir "$src/scenes" --compare-scene block --compare-csv "$out/$name.csv" \
    --label "$name") || exit 1
  /usr/bin/python3 - "$line" "$link" "$delay" "$loss" "$out/$name.station.json" <<'PY'
import json, sys
row = json.loads(sys.argv[1])
station = json.load(open(sys.argv[5]))
row.update(link=sys.argv[2], one_way_ms=float(sys.argv[3]), loss=float(sys.argv[4]) / 100,
           watchdog_trips=station.get("watchdog_trips"), models_accepted=station.get("models_accepted"),
           loadavg_1min=float(open("/proc/loadavg").read().split()[0]))
print(json.dumps(row))
PY
done
