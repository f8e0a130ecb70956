#!/usr/bin/env bash
# Large answers across the engine's transport: WebSocket frames (tools/ws_frames.py, 512³,
# 1280×720, an edit every frame) and whole-world field reads, from another checkout's server and
# this one's, alternating, with this checkout's clients.
# Usage on the GPU machine, from the project root:
#   source .whl/activate.sh; bash tools/transport_ab.sh OTHER_CHECKOUT [rounds]
# Results: $OUT/transport-ab/ (each run's JSON, text and server log) and a table on stdout.
set -uo pipefail
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
other=$1; rounds=${2:-2}; out=${OUT:-/tmp/sdfserver-out}/transport-ab; mkdir -p "$out"
device=${DEVICE-nvidia}; port=8771
for round in $(seq "$rounds"); do
  for tree in "$other" .; do
    name=$([ "$tree" = . ] && echo this || echo other)-$round
    rm -rf /tmp/sdfserver-transport-data
    (cd "$tree" && PYTHONPATH=$PWD:$PYTHONPATH exec python3 -m sdfserver serve ${device:+--device "$device"} \
      --port $port --data-dir /tmp/sdfserver-transport-data) > "$out/$name-server.log" 2>&1 &
    server=$!
    for _ in $(seq 480); do curl -sf http://127.0.0.1:$port/readyz >/dev/null && break; sleep 0.25; done
    timeout 40 python3 tools/ws_frames.py --url http://127.0.0.1:$port --size 512 --duration 10 \
      --json "$out/$name-ws.json" > "$out/$name-ws.txt" 2>&1
    timeout 40 python3 clients/loadtest --url http://127.0.0.1:$port --size 128 128 128 --clients 8 \
      --duration 6 --read-every 1 --read-size 0 --quiet --json "$out/$name-reads.json" > /dev/null 2>&1
    kill $server; wait $server 2>/dev/null
  done
done
python3 - "$out" "$rounds" <<'PY'
import json, sys
out, rounds = sys.argv[1], int(sys.argv[2])
print("| run | WebSocket FPS | whole 128³ field reads/s, p50, p99 |")
print("| --- | ---: | --- |")
for r in range(1, rounds + 1):
    for side in ("other", "this"):
        name = f"{side}-{r}"
        try:
            ws = json.load(open(f"{out}/{name}-ws.json"))
            fps = ws.get("fps", ws.get("frames_per_s"))
        except (OSError, ValueError):
            fps = "(none)"
        try:
            reads = json.load(open(f"{out}/{name}-reads.json"))["reads"]
            lat = reads["latency_ms"]
            text = f"{reads['throughput_per_s']:,.0f}, {lat['p50']:.1f} ms, {lat['p99']:.1f} ms"
        except (OSError, ValueError, KeyError):
            text = "(none)"
        print(f"| {name} | {fps} | {text} |")
PY
