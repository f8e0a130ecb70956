# The one way the measurement scripts start a server and wait for it (tools/serve_build.py is the
# same for the Python tools). Sourced, then:
#   serve_build ROOT LOG PORT DATA_DIR [serve flags...]
# starts checkout ROOT's `sdfserver serve` with ROOT's own code first on PYTHONPATH (so an older
# build runs with this checkout's clients: only the server differs), its output in LOG, and sets
# $server to its PID. It returns 0 once /readyz answers, and 1, saying why, when the server exits
# first or is not ready within READY_S seconds (then it is killed: nothing is left to clean up).
# DATA_DIR is emptied first, unless KEEP_DATA=1 (a restart that replays what a killed server
# logged). DEVICE (default nvidia; empty: no --device, the server's own choice) picks the device;
# READY_S (120) is longer for a Ray cluster's start; the array SERVE_ENTRY (default:
# -m sdfserver serve) is what python3 runs, for a server started with something installed first.
serve_build() {
  local root log=$2 port=$3 data=$4
  root=$(cd "$1" && pwd) || return 1
  shift 4
  [ "${KEEP_DATA:-0}" = 1 ] || rm -rf "$data"
  local device=${DEVICE-nvidia} entry=(-m sdfserver serve)
  [ -n "${SERVE_ENTRY+set}" ] && entry=("${SERVE_ENTRY[@]}")
  (cd "$root" && PYTHONPATH=$root:${PYTHONPATH:-} exec python3 "${entry[@]}" ${device:+--device "$device"} \
    --port "$port" --data-dir "$data" "$@") > "$log" 2>&1 &
  server=$!
  local waited=0 limit=$(( ${READY_S:-120} * 4 ))
  while [ $waited -lt $limit ]; do
    curl -sf "http://127.0.0.1:$port/readyz" > /dev/null && return 0
    if ! kill -0 $server 2> /dev/null; then
      echo "the server of $root exited before it was ready (log: $log)" >&2
      wait $server 2> /dev/null
      return 1
    fi
    sleep 0.25
    waited=$((waited + 1))
  done
  echo "the server of $root did not answer /readyz in ${READY_S:-120} s (log: $log)" >&2
  kill $server 2> /dev/null; wait $server 2> /dev/null
  return 1
}
