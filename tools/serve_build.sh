# Sourced by the A/B scripts (tools/service_ab.sh, tools/many_worlds.sh): start one build's server
# and wait until it answers /readyz.
#   serve_build ROOT LOG PORT DATA_DIR [serve flags...]   sets $server to the server's PID
# DEVICE (default nvidia; empty: the first usable device) picks the device.
serve_build() {
  local root=$1 log=$2 port=$3 data=$4; shift 4
  rm -rf "$data"
  local device=${DEVICE-nvidia}
  (cd "$root" && PYTHONPATH=$root:${PYTHONPATH:-} exec python3 -m sdfserver serve ${device:+--device "$device"} \
    --port "$port" --data-dir "$data" "$@") > "$log" 2>&1 &
  server=$!
  for _ in $(seq 480); do curl -sf "http://127.0.0.1:$port/readyz" >/dev/null && return 0; sleep 0.25; done
  echo "the server of $root did not answer /readyz in 120 s (log: $log)" >&2
  return 1
}
