#!/usr/bin/env bash
# Large answers from two builds of the server in one lease, alternating: WebSocket frames
# (tools/ws_frames.py: 512^3, 1280x720 JPEG, an edit every frame) and whole 128^3 field reads
# (8 clients), every run with this checkout's clients, so only the server differs. Frames at 60
# edits a second are capped at 60 FPS (a frame is drawn only when the field changed), so the
# figure to compare is how near each build gets to it.
#
# Usage on the GPU machine, from the project root, the other build unpacked inside the tree:
#   mkdir -p ab/old && git archive OLD_COMMIT sdfserver kernels pyproject.toml | tar -x -C ab/old
#   source .whl/activate.sh; bash tools/frames_ab.sh ab/old [rounds]
# DEVICE (nvidia) picks the device. Results: $OUT/frames-ab/ (each run's JSON, text and server
# log) and a table on stdout.
set -uo pipefail
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
source "$(dirname "$0")/serve_build.sh"
other=${1:?other checkout}; rounds=${2:-2}; out=${OUT:-/tmp/sdfserver-out}/frames-ab; mkdir -p "$out"
port=8771
for round in $(seq "$rounds"); do
  for tree in "$other" .; do
    name=$([ "$tree" = . ] && echo this || echo other)-$round
    serve_build "$tree" "$out/$name-server.log" $port /tmp/sdfserver-frames-data || continue
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
            ws = json.load(open(f"{out}/{name}-ws.json"))  # tools/ws_frames.py --json: one result a format
            fps = f"{ws['results'][0]['fps_min']:.1f}"
        except (OSError, ValueError, KeyError, IndexError):
            fps = "(none)"
        try:
            reads = json.load(open(f"{out}/{name}-reads.json"))["reads"]
            lat = reads["latency_ms"]
            text = f"{reads['throughput_per_s']:,.0f}, {lat['p50']:.1f} ms, {lat['p99']:.1f} ms"
        except (OSError, ValueError, KeyError):
            text = "(none)"
        print(f"| {name} | {fps} | {text} |")
PY
