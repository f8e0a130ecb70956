#!/usr/bin/env bash
# The service A/B of issue 17 in one lease: today's topology (a checkout of main before the
# engine process: one server process and --fronts) against this checkout's (one engine process
# per device, --workers API processes), alternating, every run with THIS checkout's load
# generator and ws_frames, so only the server differs.
#
# Usage on the GPU machine, from this checkout's root (its wheels: ../shared/gpu/fetch-wheels.sh .whl
# aiohttp aiohappyeyeballs aiosignal attrs frozenlist multidict propcache yarl; msgspec and pyzmq
# are in its list already), the old topology unpacked inside the tree so that it travels:
#   mkdir -p ab-old && git archive a946656 sdfserver kernels | tar -x -C ab-old
#   source .whl/activate.sh; bash tools/topology_ab.sh ab-old [rounds] [worker counts]
#   e.g. bash tools/topology_ab.sh ab-old 1 "2 4 6"   (about 6 minutes a round)
# DEVICE, SIZE, WS_SIZE, LOAD_S override the device (nvidia), the load test's world side (256), the
# frames' world side (512) and each 64-client run's seconds (15): a CPU smoke run uses
#   DEVICE= SIZE=64 WS_SIZE=64 LOAD_S=4 bash tools/topology_ab.sh ../old 1 2
# Results: $OUT/topology-ab.tgz (each run's JSON and text, the servers' logs) and a summary on stdout.
set -uo pipefail
old=$(cd "${1:?old checkout}" && pwd); rounds=${2:-2}; workers=${3:-"2 4 6"}
new=$PWD
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
FINAL=${OUT:-/tmp/sdfserver-out}; OUT=$(mktemp -d); mkdir -p "$FINAL"
trap 'tar czf "$FINAL/topology-ab.tgz" -C "$OUT" . ; rm -rf "$OUT"' EXIT
port=8765
device=${DEVICE-nvidia}; size=${SIZE:-256}; ws_size=${WS_SIZE:-512}; load_s=${LOAD_S:-15}  # smaller for a CPU smoke run
load="python3 $new/clients/loadtest --url http://127.0.0.1:$port --size $size $size $size --quiet"

serve() {  # serve ROOT LOG FLAGS...: the server of checkout ROOT, waited for until ready
  local root=$1 log=$2; shift 2
  (cd "$root" && PYTHONPATH=$root:${PYTHONPATH:-} exec python3 -m sdfserver serve --device "$device" --port $port \
    --data-dir /tmp/sdfserver-ab-data "$@") > "$OUT/$log" 2>&1 &
  server=$!
  for _ in $(seq 480); do curl -sf http://127.0.0.1:$port/readyz >/dev/null && return; sleep 0.25; done
}

measure() {  # measure NAME ROOT FLAGS...
  local name=$1 root=$2; shift 2
  rm -rf /tmp/sdfserver-ab-data
  serve "$root" "$name-server.log" "$@"
  for i in 1 2; do
    timeout 60 $load --clients 1 --duration 8 --read-every 1 --read-size 16 --json "$OUT/$name-rtt$i.json" \
      > "$OUT/$name-rtt$i.txt" 2>&1
  done
  timeout 60 $load --clients 64 --processes 8 --duration $load_s --read-every 0 --json "$OUT/$name-64.json" \
    > "$OUT/$name-64.txt" 2>&1
  timeout 60 $load --clients 64 --processes 8 --duration $load_s --read-every 0 --rate 5000 \
    --json "$OUT/$name-64-rate5000.json" > "$OUT/$name-64-rate5000.txt" 2>&1
  timeout 40 python3 "$new/tools/ws_frames.py" --url http://127.0.0.1:$port --size $ws_size --duration 10 \
    --json "$OUT/$name-ws.json" > "$OUT/$name-ws.txt" 2>&1
  # restart replay: a kept world under load, SIGKILL, start again (the batches since its snapshot replay)
  timeout 60 $load --clients 64 --processes 8 --duration 8 --read-every 0 --keep-world > /dev/null 2>&1
  kill -9 $server; wait $server 2>/dev/null; sleep 1
  local started; started=$(date +%s.%N)
  serve "$root" "$name-restart.log" "$@"
  echo "$(python3 -c 'import sys, time; print(round(time.time() - float(sys.argv[1]), 2))' $started)" \
    > "$OUT/$name-restart.txt"
  kill $server; wait $server 2>/dev/null
}

for round in $(seq "$rounds"); do
  measure "r$round-old-fronts2" "$old" --fronts 2
  for n in $workers; do measure "r$round-new-workers$n" "$new" --workers "$n"; done
done

python3 - "$OUT" "$new/tools" <<'EOF'
import glob, json, os, sys
out = sys.argv[1]
sys.path.insert(0, sys.argv[2])
from set_rate_cell import HEADER, cell_from
def j(path):
    try:
        return json.load(open(path))
    except (OSError, ValueError):
        return None
names = sorted({os.path.basename(p).rsplit("-server.log", 1)[0] for p in glob.glob(f"{out}/*-server.log")})
print(f"| run | rtt p50 (ms) | 64 clients: batches/s, p99 (ms) | at a set 5,000/s: {HEADER} | WS FPS 512³ | restart (s) |")
print("| --- | --- | --- | --- | --- | --- |")
for n in names:
    rtt = [j(f"{out}/{n}-rtt{i}.json") for i in (1, 2)]
    rtt = ", ".join(f"{r['round_trips']['latency_ms']['p50']:.2f}" for r in rtt if r)
    full, ws = j(f"{out}/{n}-64.json"), j(f"{out}/{n}-ws.json")
    restart = open(f"{out}/{n}-restart.txt").read().strip() if os.path.exists(f"{out}/{n}-restart.txt") else ""
    cells = [rtt,
             f"{full['throughput_rps']:,.0f}, {full['edits']['latency_ms']['p99']:.1f}" if full else "",
             cell_from(f"{out}/{n}-64-rate5000.json"),
             f"{ws.get('fps', 0):.1f}" if ws else "", restart]
    print(f"| {n} | " + " | ".join(cells) + " |")
EOF
