#!/usr/bin/env bash
# Where the 64-client limit is: fresh servers with different flags, each taking a lone client and
# then 64 clients, the engine's own counters (/metrics: steps, batches, step phases) read after.
#
# Usage on the GPU machine, from the project root:
#   source .whl/activate.sh; bash tools/engine_limit.sh "default" "nosync --no-sync" "nopersist --no-persist"
# Each argument is a row: its name, then `sdfserver serve` flags. DEVICE, SIZE, DUR override the
# device (nvidia), the world's side (256) and the 64-client run's seconds (12), PROCS the load
# generator's processes for the 64 clients (8); a CPU smoke run:
#   DEVICE= SIZE=32 DUR=3 bash tools/engine_limit.sh default
# Results: $OUT/engine-limit/ (each run's JSON, metrics and server log) and a table on stdout.
set -uo pipefail
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
out=${OUT:-/tmp/sdfserver-out}/engine-limit; mkdir -p "$out"
device=${DEVICE-nvidia}; size=${SIZE:-256}; dur=${DUR:-12}; port=8765
load="python3 clients/loadtest --url http://127.0.0.1:$port --size $size $size $size --quiet"

for row in "$@"; do
  read -r name flags <<< "$row"
  rm -rf /tmp/sdfserver-limit-data
  # shellcheck disable=SC2086  # the flags are words
  python3 -m sdfserver serve ${device:+--device "$device"} --port $port --data-dir /tmp/sdfserver-limit-data \
    $flags > "$out/$name-server.log" 2>&1 &
  server=$!
  for _ in $(seq 480); do curl -sf http://127.0.0.1:$port/readyz >/dev/null && break; sleep 0.25; done
  timeout 30 $load --clients 1 --duration 6 --read-every 1 --read-size 16 --json "$out/$name-rtt.json" > /dev/null 2>&1
  timeout $((dur + 30)) $load --clients 64 --processes "${PROCS:-8}" --duration "$dur" --read-every 0 \
    --json "$out/$name-64.json" > /dev/null 2>&1
  curl -s http://127.0.0.1:$port/metrics > "$out/$name-metrics.txt"
  kill $server; wait $server 2>/dev/null
done

python3 - "$out" "$@" <<'PY'
import json, re, sys
out, rows = sys.argv[1], [r.split()[0] for r in sys.argv[2:]]
print("| row | lone round trip p50 | 64 clients: batches/s, p99 | steps | batches a step | in steps (s): apply / recompute / serve |")
print("| --- | --- | --- | ---: | ---: | --- |")
for name in rows:
    try:
        full, rtt = (json.load(open(f"{out}/{name}-{k}.json")) for k in ("64", "rtt"))
        metrics = open(f"{out}/{name}-metrics.txt").read()
    except (OSError, ValueError) as exc:
        print(f"| {name} | failed: {exc} | | | | |")
        continue
    def total(pattern: str) -> float:
        return sum(float(v) for v in re.findall(pattern + r"\s+([0-9.e+-]+)", metrics))
    steps, batches = total(r"\nsdfserver_engine_steps_total"), total(r"\nsdfserver_edit_batches_total")
    phase = dict(re.findall(r'sdfserver_engine_phase_seconds_total\{phase="([a-z_]+)"\}\s+([0-9.e+-]+)', metrics))
    phases = " / ".join(f"{float(phase.get(p, 0)):.2f}" for p in ("apply", "recompute", "serve"))
    print(f"| {name} | {rtt['round_trips']['latency_ms']['p50']:.2f} ms | {full['throughput_rps']:,.0f}, "
          f"{full['edits']['latency_ms']['p99']:.1f} ms | {steps:,.0f} | {batches / max(steps, 1):.1f} | {phases} |")
PY
