#!/usr/bin/env bash
# 64 game clients against two builds of the server in one lease, alternating (issue 30: "nothing
# about Manhattan worlds gets slower"): each build serves with its default flags, then a lone
# client's round trip, 64 clients as fast as they go, and 64 clients at a set 5,000 batches/s
# (each request timed from its slot and from its send: tools/set_rate_cell.py), every run with THIS
# checkout's load generator.
#
# On the GPU machine, from this checkout's root, the old build unpacked inside the tree:
#   mkdir -p ab/old && git archive OLD_COMMIT sdfserver kernels pyproject.toml | tar -x -C ab/old
#   source .whl/activate.sh; bash tools/service_ab.sh ab/old [rounds]
# DEVICE, SIZE, LOAD_S override the device (nvidia), the world's side (256) and each 64-client
# run's seconds (15); a CPU smoke run: DEVICE= SIZE=64 LOAD_S=3 bash tools/service_ab.sh OLD 1
# Results: $OUT/service-ab.tgz (each run's JSON and text, the servers' logs), a table on stdout.
set -uo pipefail
old=$(cd "${1:?old checkout}" && pwd); rounds=${2:-2}
new=$PWD
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
FINAL=${OUT:-/tmp/sdfserver-out}; OUT=$(mktemp -d); mkdir -p "$FINAL"
trap 'tar czf "$FINAL/service-ab.tgz" -C "$OUT" . ; rm -rf "$OUT"' EXIT
port=8765
size=${SIZE:-256}; load_s=${LOAD_S:-15}
source "$new/tools/serve_build.sh"
load="python3 $new/clients/loadtest --url http://127.0.0.1:$port --size $size $size $size --quiet"

measure() {  # measure NAME ROOT: serve checkout ROOT, run the loads, stop it
  local name=$1 root=$2
  serve_build "$root" "$OUT/$name-server.log" $port /tmp/sdfserver-ab-data
  timeout 60 $load --clients 1 --duration 6 --read-every 1 --read-size 16 --json "$OUT/$name-rtt.json" \
    > "$OUT/$name-rtt.txt" 2>&1
  timeout 90 $load --clients 64 --processes 8 --duration "$load_s" --read-every 0 --json "$OUT/$name-64.json" \
    > "$OUT/$name-64.txt" 2>&1
  timeout 90 $load --clients 64 --processes 8 --duration "$load_s" --read-every 0 --rate 5000 \
    --json "$OUT/$name-64-rate5000.json" > "$OUT/$name-64-rate5000.txt" 2>&1
  kill $server; wait $server 2>/dev/null
}

for round in $(seq "$rounds"); do
  measure "r$round-old" "$old"
  measure "r$round-new" "$new"
done

python3 - "$OUT" "$new/tools" <<'PY'
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
print(f"| run | lone round trip p50 (ms) | 64 clients: batches/s, p99 (ms) | a set 5,000/s: {HEADER} |")
print("| --- | --- | --- | --- |")
for n in names:
    rtt, full = j(f"{out}/{n}-rtt.json"), j(f"{out}/{n}-64.json")
    cells = [f"{rtt['round_trips']['latency_ms']['p50']:.2f}" if rtt else "",
             f"{full['throughput_rps']:,.0f}, {full['edits']['latency_ms']['p99']:.1f}" if full else "",
             cell_from(f"{out}/{n}-64-rate5000.json")]
    print(f"| {n} | " + " | ".join(cells) + " |")
PY
