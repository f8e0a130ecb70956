#!/usr/bin/env bash
# Scale-out over the GPUs of one host with engines as Ray actors, one per GPU, against one GPU in
# the same lease: a lone client's round trip, 64 and 256 clients over as many worlds as load
# generators, a killed engine under load (tools/cluster_kill.py), and the most worlds resident.
#
# On the multi-GPU machine, after `source .whl/activate.sh` (Ray among the wheels), from the root:
#   bash tools/multi_gpu_cluster.sh [GPUS...]        e.g.  bash tools/multi_gpu_cluster.sh 1 2
# SIZE, DUR, WORKERS and CAP_SIDE override 128^3 load worlds, 15 s a run, 8 API processes and the
# 1024^3 worlds counted for residency; a CPU smoke run:
#   GPU=0 GEN=8 SIZE=32 DUR=3 WORKERS=1 CAP_SIDE=128 KILL_SIDE=32 bash tools/multi_gpu_cluster.sh 1 2
# Results: $OUT/mgpu-*.json and a table on stdout.
set -uo pipefail
port=8768; SIZE=${SIZE:-128}; DUR=${DUR:-15}; WORKERS=${WORKERS:-8}; CAP_SIDE=${CAP_SIDE:-1024}
GPU=${GPU:-1}; GEN=${GEN:-1}; KILL_SIDE=${KILL_SIDE:-256}  # GPU=0: CPU devices (a smoke run); GEN divides the generators
FINAL=${OUT:-/tmp/sdfserver-out}; mkdir -p "$FINAL"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
source "$(dirname "$0")/serve_build.sh"
url=http://127.0.0.1:$port
load="python3 clients/loadtest --url $url --size $SIZE $SIZE $SIZE --quiet"

serve() {  # serve GPUS: engines as actors, one per GPU (each picks its own device), waited for until ready
  DEVICE= READY_S=240 serve_build . "$FINAL/mgpu-$1-server.log" $port /tmp/sdfserver-mgpu-data \
    --workers "$WORKERS" --no-warm-up --cluster local --engines "$1" --engine-gpus "$GPU"
}

load_runs() {  # load_runs TAG GENERATORS CLIENTS_EACH
  local pids=()
  for k in $(seq "$2"); do
    timeout $((DUR + 90)) $load --clients "$3" --duration "$DUR" --read-every 0 \
      --json "$FINAL/mgpu-$1-load$k.json" > /dev/null 2>&1 &
    pids+=($!)
    sleep 0.1
  done
  wait "${pids[@]}"
}

for gpus in "${@:-1 2}"; do
  serve "$gpus"
  timeout 60 $load --clients 1 --duration 8 --read-every 1 --read-size 16 --json "$FINAL/mgpu-$gpus-rtt.json" \
    > /dev/null 2>&1
  load_runs "$gpus-c64" $((16 / GEN)) 4
  load_runs "$gpus-c256" $((32 / GEN)) 8
  kill $server; wait $server 2>/dev/null
  if [ "$gpus" -gt 1 ]; then
    serve "$gpus"
    timeout 240 python3 tools/cluster_kill.py --url $url --worlds 10 --side "$KILL_SIDE" --json "$FINAL/mgpu-$gpus-kill.json"
    kill $server; wait $server 2>/dev/null
  fi
  serve "$gpus"
  timeout 240 python3 - "$url" "$CAP_SIDE" "$FINAL/mgpu-$gpus-capacity.json" <<'PY'
import json, sys, time
import httpx
url, side, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
http = httpx.Client(base_url=url, timeout=300)
made, started = [], time.monotonic()
while time.monotonic() - started < 180:
    r = http.post("/v1/worlds", json={"size": [side] * 3, "chunk_size": 32})
    if r.status_code != 201:
        refusal = f"{r.status_code} {r.json()['error']['code']}"
        break
    made.append(r.json()["id"])
else:
    refusal = "time"
engines = http.get("/v1/engines").json()
result = {"side": side, "worlds": len(made), "stopped_by": refusal,
          "device_bytes": sum(http.get(f"/v1/worlds/{w}").json()["device_bytes"] for w in made),
          "per_engine": [e["worlds"] for e in engines]}
json.dump(result, open(out, "w"))
print(result)
PY
  kill $server; wait $server 2>/dev/null
done

python3 - "$FINAL" "${@:-1 2}" <<'PY'
import glob, json, sys
out, runs = sys.argv[1], sys.argv[2:]
def j(path):
    try:
        return json.load(open(path))
    except (OSError, ValueError):
        return None
print("| GPUs | lone edit -> field p50 (ms) | 64 clients / 16 worlds: batches/s, worst p99 | 256 clients / 32 worlds: batches/s, worst p99 | resident worlds |")
print("| --- | --- | --- | --- | --- |")
for g in runs:
    rtt = j(f"{out}/mgpu-{g}-rtt.json")
    cells = []
    for tag in ("c64", "c256"):
        loads = [r for r in (j(p) for p in sorted(glob.glob(f"{out}/mgpu-{g}-{tag}-load*.json"))) if r]
        total = sum(r["throughput_rps"] for r in loads)
        p99 = max((r["edits"]["latency_ms"]["p99"] for r in loads), default=0)
        errors = sum(r["errors"]["count"] for r in loads)
        cells.append(f"{total:,.0f}, {p99:.1f} ms ({errors} errors)")
    cap = j(f"{out}/mgpu-{g}-capacity.json") or {}
    p50 = f"{rtt['round_trips']['latency_ms']['p50']:.2f}" if rtt else "-"
    print(f"| {g} | {p50} | {cells[0]} | {cells[1]} | {cap.get('worlds')} x {cap.get('side')}^3 ({cap.get('per_engine')}, {cap.get('stopped_by')}) |")
for g in runs:
    kill = j(f"{out}/mgpu-{g}-kill.json")
    if kill:
        print(f"kill, {g} GPUs: {json.dumps(kill)}")
PY
