# Sourced by the session benchmarks: wait_for_server LOG PID SECONDS waits
# until the server whose stderr goes to LOG has logged its session start
# ("session '…': physics"), or fails (exit 1, naming the log) when PID dies
# or SECONDS pass first.
wait_for_server() {
  local log="$1" pid="$2" limit="$3"
  local deadline=$((SECONDS + limit))
  until grep -q "session '.*': physics" "$log" 2>/dev/null; do
    if [ "$SECONDS" -ge "$deadline" ] || ! kill -0 "$pid" 2>/dev/null; then
      echo "$(basename "$0"): the server did not come up (see $log)" >&2
      kill "$pid" 2>/dev/null || true
      exit 1
    fi
    sleep 0.05
  done
}
