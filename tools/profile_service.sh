#!/usr/bin/env bash
# Where the server's host time goes under load: py-spy samples the engine process and one API
# process while the load test runs, and tools/profile_summary.py prints the functions that take it.
# Usage (GPU machine, from the project root, with py-spy among the carried wheels):
#   source .whl/activate.sh; bash tools/profile_service.sh [CLIENTS] [SECONDS] [serve flags...]
# Results: $OUT/profile-{engine,api}-CLIENTS.txt (py-spy's raw stacks) and their summaries on stdout.
set -uo pipefail
clients=${1:-64}; seconds=${2:-10}; shift 2 || true
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
OUT=${OUT:-/tmp/sdfserver-out}; mkdir -p "$OUT"
port=8799; device=${DEVICE-nvidia}; size=${SIZE:-256}
spy=$(command -v py-spy || echo /tmp/site/bin/py-spy)
rm -rf /tmp/sdfserver-profile-data
python3 -m sdfserver serve --device "$device" --port $port --data-dir /tmp/sdfserver-profile-data "$@" \
  > "$OUT/profile-server-$clients.log" 2>&1 &
server=$!
for _ in $(seq 480); do curl -sf http://127.0.0.1:$port/readyz >/dev/null && break; sleep 0.25; done
children=($(pgrep -P $server))
engine=${children[0]}; api=${children[-1]}
processes=$(( clients >= 8 ? 8 : 1 ))
"$spy" record -p "$engine" -d "$seconds" -r 250 -f raw -o "$OUT/profile-engine-$clients.txt" > /dev/null 2>&1 &
"$spy" record -p "$api" -d "$seconds" -r 250 -f raw -o "$OUT/profile-api-$clients.txt" > /dev/null 2>&1 &
python3 clients/loadtest --url http://127.0.0.1:$port --size $size $size $size --clients "$clients" \
  --processes $processes --duration "$seconds" --read-every "${READ_EVERY:-0}" --quiet
wait %2 %3 2>/dev/null
kill $server; wait $server 2>/dev/null
for part in engine api; do
  echo "== $part process, $clients clients"
  python3 tools/profile_summary.py "$OUT/profile-$part-$clients.txt"
done
