#!/usr/bin/env bash
# How long a start takes, clean and after a crash under load: a server on an empty data directory
# (twice: the first on a fresh machine also fills pyopencl's caches), then 64 clients for 8 s on a
# kept 256^3 world, SIGKILL, and a start again on the same data directory; each timed from the start
# command to /readyz. Also pyopencl's import, platform and context times, and the servers' logs.
#
# On the GPU machine, from the checkout's root:  source .whl/activate.sh; bash tools/restart_timing.sh
# DEVICE overrides the device (nvidia). Results: $OUT/restart-timing.tgz and a summary on stdout.
set -uo pipefail
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
port=8765; data=$(mktemp -d); R=$(mktemp -d); FINAL=${OUT:-/tmp/sdfserver-out}; mkdir -p "$FINAL"
pid=
trap '[ -n "$pid" ] && kill $pid 2> /dev/null; tar czf "$FINAL/restart-timing.tgz" -C "$R" . ; rm -rf "$R" "$data"' EXIT
start() {  # start NAME: a server on $data, timed until /readyz answers; sets $pid
  local t0 t1
  t0=$(date +%s.%N)
  python3 -m sdfserver serve --device "${DEVICE:-nvidia}" --port $port --data-dir "$data" > "$R/$1.log" 2>&1 &
  pid=$!
  until curl -sf http://127.0.0.1:$port/readyz > /dev/null; do
    kill -0 $pid 2> /dev/null || { echo "$1: the server exited (log: $R/$1.log)"; return 1; }
    sleep 0.05
  done
  t1=$(date +%s.%N)
  echo "$1: ready $(python3 -c "print(round($t1 - $t0, 2))") s after the start command at $(date -d @"$t0" +%T.%N)" \
    | tee -a "$R/summary.txt"
}
rm -rf "$data"; start clean1 || exit 1; kill $pid; wait $pid
rm -rf "$data"; start clean2 || exit 1
timeout 60 python3 clients/loadtest --url http://127.0.0.1:$port --size 256 256 256 --quiet --keep-world \
  --clients 64 --processes 8 --duration 8 --read-every 0 > "$R/load.txt" 2>&1
head -1 "$R/load.txt" | tee -a "$R/summary.txt"
kill -9 $pid; wait $pid 2> /dev/null; sleep 1  # its engine and API processes die with it (PDEATHSIG)
start restart || exit 1; kill $pid; wait $pid; pid=
python3 -c "
import time; t = time.perf_counter(); import pyopencl as cl; t1 = time.perf_counter(); p = cl.get_platforms()
t2 = time.perf_counter(); c = cl.Context([x for pl in p for x in pl.get_devices()][:1]); t3 = time.perf_counter()
print(f'import pyopencl {t1 - t:.2f} s, platforms {t2 - t1:.2f} s, context {t3 - t2:.2f} s')" | tee -a "$R/summary.txt"
for name in clean2 restart; do echo "== $name"; head -8 "$R/$name.log" | cut -c1-220; done | tee -a "$R/summary.txt"
