#!/usr/bin/env bash
# Where the 64-client limit is: fresh servers with different flags, each taking a lone client and
# then 64 clients, the engine's own counters (/metrics: steps, batches, step phases) read after.
#
# Usage on the GPU machine, from the project root:
#   source .whl/activate.sh; bash tools/engine_limit.sh "default" "nosync --no-sync" "nopersist --no-persist"
# Each argument is a row: its name, then `sdfserver serve` flags. DEVICE, SIZE, DUR override the
# device (nvidia), the world's side (256) and the 64-client run's seconds (12), PROCS the load
# generator's processes for the 64 clients (8), RATE adds a run at that many batches a second
# (its p99 timed from each request's slot and from its send: tools/set_rate_cell.py),
# SERVER_TREE runs another checkout's server (an A/B: same load generator), LOAD_FLAGS adds load
# generator flags (--http httptools); a CPU smoke run:
#   DEVICE= SIZE=32 DUR=3 bash tools/engine_limit.sh default
# Results: $OUT/engine-limit/ (each run's JSON, metrics and server log), a table on stdout and, for
# each row, where the 64 clients' CPU went (tools/cpu_use.py); TRACE=1 adds where their batches'
# time went inside the engine process (tools/engine_trace.py).
set -uo pipefail
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
here=$(cd "$(dirname "$0")" && pwd)
source "$here/serve_build.sh"
out=${OUT:-/tmp/sdfserver-out}/engine-limit; mkdir -p "$out"; out=$(cd "$out" && pwd)
size=${SIZE:-256}; dur=${DUR:-12}; port=8765
load="python3 clients/loadtest --url http://127.0.0.1:$port --size $size $size $size --quiet ${LOAD_FLAGS:-}"

for row in "$@"; do
  read -r name flags <<< "$row"
  SERVE_ENTRY=(-m sdfserver serve)  # TRACE=1: the engine process traced, its record written as it stops
  [ -n "${TRACE:-}" ] && SERVE_ENTRY=(-c "import sys; sys.path.insert(0, '$here'); import engine_trace; \
engine_trace.install('$out/$name-trace.json'); from sdfserver.api.server import main; raise SystemExit(main())")
  # SERVER_TREE: another checkout's server (an A/B), driven by this checkout's load generator
  # shellcheck disable=SC2086  # the flags are words
  serve_build "${SERVER_TREE:-.}" "$out/$name-server.log" $port /tmp/sdfserver-limit-data $flags || continue
  timeout 30 $load --clients 1 --duration 6 --read-every 1 --read-size 16 --json "$out/$name-rtt.json" > /dev/null 2>&1
  python3 tools/cpu_use.py snap $server > "$out/$name-cpu-before.json"
  loaded_at=$(python3 -c "import time; print(time.perf_counter())")
  timeout $((dur + 30)) $load --clients 64 --processes "${PROCS:-8}" --duration "$dur" --read-every 0 \
    --json "$out/$name-64.json" > /dev/null 2>&1
  python3 tools/cpu_use.py snap $server > "$out/$name-cpu-after.json"
  curl -s http://127.0.0.1:$port/metrics > "$out/$name-metrics.txt"
  [ -n "${RATE:-}" ] && timeout $((dur + 30)) $load --clients 64 --processes "${PROCS:-8}" --duration "$dur" \
    --rate "$RATE" --read-every 0 --json "$out/$name-rate.json" > /dev/null 2>&1
  kill $server; wait $server 2>/dev/null
  [ -n "${TRACE:-}" ] && python3 tools/engine_trace.py "$out/$name-trace.json" "$loaded_at" \
    > "$out/$name-in-engine.json"  # written by the engine process as it stopped
done

python3 - "$out" "$@" <<'PY'
import json, os, re, sys
sys.path.insert(0, "tools")
from set_rate_cell import HEADER, cell_from
out, rows = sys.argv[1], [r.split()[0] for r in sys.argv[2:]]
rate = os.environ.get("RATE")
print("| row | lone round trip p50 | 64 clients: batches/s, p99 |" + (f" a set {rate}/s: {HEADER} |" if rate else "")
      + " steps | batches a step | in steps (s): apply / recompute / serve |")
print("| --- | --- | --- |" + (" --- |" if rate else "") + " ---: | ---: | --- |")
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
    at_rate = f" {cell_from(f'{out}/{name}-rate.json')} |" if rate else ""
    print(f"| {name} | {rtt['round_trips']['latency_ms']['p50']:.2f} ms | {full['throughput_rps']:,.0f}, "
          f"{full['edits']['latency_ms']['p99']:.1f} ms |{at_rate} {steps:,.0f} | {batches / max(steps, 1):.1f} | {phases} |")
PY
for row in "$@"; do  # where the 64 clients' CPU went (the load generator's own: client_cpu_us_per_request)
  read -r name _ <<< "$row"
  requests=$(python3 -c "import json; print(json.load(open('$out/$name-64.json'))['requests'])" 2>/dev/null || echo 0)
  echo "$name, 64 clients:"
  [ -f "$out/$name-in-engine.json" ] && python3 -c "import json; [print(f'  {k}: p50 {v[\"p50_ms\"]} ms, p90 \
{v[\"p90_ms\"]} ms') for k, v in json.load(open('$out/$name-in-engine.json')).items()]"
  python3 tools/cpu_use.py diff "$out/$name-cpu-before.json" "$out/$name-cpu-after.json" \
    --requests "$requests" 2>/dev/null | sed 's/^/  /'
done
