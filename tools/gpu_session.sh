#!/usr/bin/env bash
# One packed measurement session on the lent GPU machine (see docs/benchmarks.md).
# Usage there: source .whl/activate.sh; [SERVE_FLAGS="--workers 4"] bash tools/gpu_session.sh [sections]
# Sections: host tests bench render service restart (default: all). Results: $OUT/results.tgz.
set -uo pipefail
export PYTHONPATH=$PWD:${PYTHONPATH:-} PYTHONUNBUFFERED=1
FINAL=${OUT:-/tmp/sdfserver-out}; OUT=$(mktemp -d); mkdir -p "$FINAL"
trap 'tar czf "$FINAL/results.tgz" -C "$OUT" . ; rm -rf "$OUT"' EXIT
sections=${1:-host,tests,bench,render,service,restart}
has() { [[ ",$sections," == *",$1,"* ]]; }
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$OUT/gpu.txt"

port=8765
source tools/serve_build.sh
serve() {  # serve LOG: this checkout's server on the data directory in /tmp, waited for until ready
  serve_build . "$OUT/$1" $port /tmp/sdfserver-data ${SERVE_FLAGS:-}
}

if has host; then
  # Is this host quiet? Stalls of every CPU at once with nothing else running come from below the
  # guest, and they set the service's tail latency (docs/benchmarks.md, "How we measure").
  grep -m1 "model name" /proc/cpuinfo > "$OUT/host.txt"
  python3 tools/stall_probe.py --per-cpu --seconds 8 --threshold-ms 1 >> "$OUT/host.txt" 2>&1
fi
if has tests; then
  timeout 200 python3 -m pytest tests/core tests/durability/test_engine_journal.py -q -p no:cacheprovider > "$OUT/core-tests.txt" 2>&1
  tail -1 "$OUT/core-tests.txt"
fi
if has bench; then
  timeout 300 python3 -m sdfserver bench --device nvidia --json "$OUT/bench.json" 2>/dev/null > "$OUT/bench.txt"
  python3 tools/tune_exact.py --device nvidia --size 512 --reps 20 > "$OUT/tune-512.txt" 2>&1
fi
if has render; then
  timeout 120 python3 -m sdfserver bench render --device nvidia --sizes 256,512 --algorithms exact \
    --duration 4 --width 1280 --height 720 --json "$OUT/render.json" > "$OUT/render.txt" 2>&1
fi
if has service; then
  serve server.log
  # The one-client round trip four times: one run's p50 moves by a few hundred microseconds on
  # the lent hosts (docs/benchmarks.md, "How we measure"), so one run says little about the next.
  rtt="--clients 1 --duration 8 --read-every 1 --read-size 16"
  for run in "load-rtt-1:$rtt" "load-rtt-2:$rtt" "load-rtt-3:$rtt" "load-rtt-4:$rtt" \
             "load-64:--clients 64 --processes 8 --duration 15 --read-every 0" \
             "load-64-rate5000:--clients 64 --processes 8 --duration 15 --read-every 0 --rate 5000" \
             "load-64-again:--clients 64 --processes 8 --duration 15 --read-every 0"; do
    name=${run%%:*}
    timeout 60 python3 tools/service_overhead.py --pid $server --url http://127.0.0.1:$port -- \
      python3 clients/loadtest --url http://127.0.0.1:$port --size 256 256 256 --quiet \
      --json "$OUT/$name.json" ${run#*:} > "$OUT/$name.txt" 2>&1
  done
  timeout 40 python3 tools/ws_frames.py --url http://127.0.0.1:$port --size 512 --duration 10 \
    --json "$OUT/ws-frames.json" > "$OUT/ws-frames.txt" 2>&1
  curl -s http://127.0.0.1:$port/metrics > "$OUT/metrics.txt"
  kill $server; wait $server 2>/dev/null
fi
if has restart; then
  # Recovery after a crash under load: 64 clients for 8 s on a kept world, SIGKILL, start again;
  # the restart replays the batches logged since the world's last snapshot.
  serve server-crash.log
  timeout 60 python3 clients/loadtest --url http://127.0.0.1:$port --size 256 256 256 --quiet --keep-world \
    --clients 64 --processes 8 --duration 8 --read-every 0 > "$OUT/load-before-crash.txt" 2>&1
  kill -9 $server; wait $server 2>/dev/null; sleep 1  # its engine and API processes die with it (PDEATHSIG)
  started=$(date +%s.%N)
  KEEP_DATA=1 serve server-restart.log
  echo "ready $(python3 -c 'import sys, time; print(round(time.time() - float(sys.argv[1]), 1))' $started) s" \
    "after the start command" > "$OUT/restart.txt"
  grep -h "restored" "$OUT/server-restart.log" >> "$OUT/restart.txt"
  kill $server; wait $server 2>/dev/null
fi
for f in host.txt bench.txt render.txt load-rtt-1.txt load-rtt-2.txt load-rtt-3.txt load-rtt-4.txt load-64.txt \
         load-64-rate5000.txt load-64-again.txt ws-frames.txt load-before-crash.txt restart.txt; do [ -f "$OUT/$f" ] && { echo "== $f"; cat "$OUT/$f"; }; done
