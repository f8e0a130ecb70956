#!/usr/bin/env bash
# One engine process per GPU (`--devices 0,1`) against one: K load generators run at once, each
# with its own world (placed on the engine with the most free device memory, so the worlds spread
# over the engines) and C clients; their batches/s are summed. Also a lone client's round trip.
#
# On the GPU machine, after `source .whl/activate.sh`, from the checkout's root:
#   bash tools/multi_engine_scale.sh 0 0,1
# K, C, DUR, SIZE and WORKERS override 8 generators, 8 clients each, 20 s, 256^3 worlds, 4 API
# processes; SERVE_FLAGS adds `sdfserver serve` flags (for example --no-sync). The generators
# start 0.3 s apart (so each world's placement sees the ones before it): their runs overlap by all
# but (K - 1) x 0.3 s. Results: $OUT/scale-*.json, a table on stdout and, for each `--devices`,
# where the server's CPU went while the generators ran (tools/cpu_use.py: the engine processes by
# thread, the API processes) beside the generators' own CPU a request.
set -uo pipefail
port=8766; K=${K:-8}; C=${C:-8}; DUR=${DUR:-20}; SIZE=${SIZE:-256}; WORKERS=${WORKERS:-4}
FINAL=${OUT:-/tmp/sdfserver-out}; mkdir -p "$FINAL"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
source "$(dirname "$0")/serve_build.sh"
load="python3 clients/loadtest --url http://127.0.0.1:$port --size $SIZE $SIZE $SIZE --quiet"
for devices in "$@"; do
  tag=${devices//,/_}
  # shellcheck disable=SC2086  # the flags are words
  DEVICE= serve_build . "$FINAL/scale-$tag-server.log" $port /tmp/sdfserver-scale-data \
    --devices "$devices" --workers "$WORKERS" ${SERVE_FLAGS:-} || continue
  timeout 60 $load --clients 1 --duration 8 --read-every 1 --read-size 16 --json "$FINAL/scale-$tag-rtt.json" \
    > /dev/null 2>&1
  python3 tools/cpu_use.py snap $server > "$FINAL/scale-$tag-cpu-before.json"
  pids=()
  for k in $(seq "$K"); do
    timeout $((DUR + 40)) $load --clients "$C" --duration "$DUR" --read-every 0 \
      --json "$FINAL/scale-$tag-load$k.json" > /dev/null 2>&1 &
    pids+=($!)
    sleep 0.3
  done
  wait "${pids[@]}"
  python3 tools/cpu_use.py snap $server > "$FINAL/scale-$tag-cpu-after.json"
  kill $server; wait $server 2>/dev/null
done
python3 - "$FINAL" "$C" "$@" <<'PY'
import glob, json, subprocess, sys
out, clients, runs = sys.argv[1], sys.argv[2], sys.argv[3:]
print("| devices | lone client edit -> field p50 (ms) | generators x clients | batches/s (sum) | worst p99 (ms) | errors |")
print("| --- | --- | --- | --- | --- | --- |")
for devices in runs:
    tag = devices.replace(",", "_")
    rtt = json.load(open(f"{out}/scale-{tag}-rtt.json"))["round_trips"]["latency_ms"]["p50"]
    loads = [json.load(open(p)) for p in sorted(glob.glob(f"{out}/scale-{tag}-load*.json"))]
    total = sum(r["throughput_rps"] for r in loads)
    p99 = max(r["edits"]["latency_ms"]["p99"] for r in loads)
    errors = sum(r["errors"]["count"] for r in loads)
    print(f"| {devices} | {rtt:.2f} | {len(loads)} x {clients} | {total:,.0f} | {p99:.1f} | {errors} |")
for devices in runs:
    tag = devices.replace(",", "_")
    loads = [json.load(open(p)) for p in sorted(glob.glob(f"{out}/scale-{tag}-load*.json"))]
    requests = sum(r["edits"]["count"] for r in loads)
    client_cpu = sum(r["client_cpu_us_per_request"] * r["edits"]["count"] for r in loads)
    client_cpu /= max(requests, 1)
    print(f"\n--devices {devices}: {requests} batches; the load generators {client_cpu:.0f} us of CPU a request")
    sys.stdout.flush()
    subprocess.run([sys.executable, "tools/cpu_use.py", "diff", f"{out}/scale-{tag}-cpu-before.json",
                    f"{out}/scale-{tag}-cpu-after.json", "--requests", str(requests)])
PY
