#!/usr/bin/env bash
# The engine process alone (tools/engine_drive.py: typed requests, no HTTP) at several client
# counts, then 64 clients again with py-spy sampling the engine process (--idle: waits included; --gil: holding the GIL),
# summarized thread by thread (tools/profile_threads.py).
# Usage on the GPU machine, from the project root:
#   source .whl/activate.sh; bash tools/engine_drive.sh ["1 16 64 128"] [serve flags...]
# DEVICE, SIZE, DUR override the device (nvidia), the world's side (256), each run's seconds (5);
# PROFILE="" skips the profiles.
# Results: $OUT/engine-drive/ (each run's JSON and log, the profile) and a table on stdout.
set -uo pipefail
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
out=${OUT:-/tmp/sdfserver-out}/engine-drive; mkdir -p "$out"
counts=${1:-1 16 64 128}; shift || true
device=${DEVICE-nvidia}; size=${SIZE:-256}; dur=${DUR:-5}
spy=$(command -v py-spy || echo /tmp/site/bin/py-spy)
drive() {  # name clients seconds [serve flags]
  local name=$1 clients=$2 seconds=$3; shift 3
  python3 tools/engine_drive.py --size "$size" --clients "$clients" --duration "$seconds" \
    --json "$out/$name.json" -- ${device:+--device "$device"} "$@" > "$out/$name.log" 2>&1
}
for c in $counts; do drive "clients-$c" "$c" "$dur" "$@"; done
for mode in ${PROFILE-idle gil}; do  # waits included; then only samples holding the GIL
  drive "profiled-$mode-64" 64 10 "$@" &
  driver=$!; pid=
  for _ in $(seq 240); do pid=$(grep -o 'engine process [0-9]*' "$out/profiled-$mode-64.log" 2>/dev/null | cut -d' ' -f3)
    [ -n "$pid" ] && break; sleep 0.5; done
  sleep 2
  [ -n "$pid" ] && "$spy" record "--$mode" --threads -p "$pid" -d 6 -r 200 -f raw -o "$out/profile-$mode-64.txt" > /dev/null 2>&1
  wait $driver
done
python3 - "$out" <<'PY'
import json, pathlib, sys
print("| run | batches/s | p50 ms | p99 ms | batches a step | engine CPU µs a batch | apply / recompute s |")
print("| --- | ---: | ---: | ---: | ---: | ---: | --- |")
for path in sorted(pathlib.Path(sys.argv[1]).glob("*.json"), key=lambda p: (len(p.stem), p.stem)):
    r = json.loads(path.read_text()); ph = r["phases_s"]
    print(f"| {path.stem} | {r['batches_per_s']:,.0f} | {r['p50_ms']:.2f} | {r['p99_ms']:.2f} | "
          f"{r['batches_per_step'] or 0:.1f} | {r['engine_cpu_us_per_batch']:.0f} | {ph.get('apply', 0):.2f} / {ph.get('recompute', 0):.2f} |")
PY
[ -n "${PROFILE-x}" ] && python3 tools/profile_threads.py "$out"/profile-idle-64.txt "$out"/profile-gil-64.txt --cpu "$out/clients-64.json"
