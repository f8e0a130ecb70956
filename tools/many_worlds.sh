#!/usr/bin/env bash
# 64 clients on one world against 64 clients spread over 16 and over 64 worlds, one engine, for
# two builds in one lease, alternating (issue 31, "many worlds cost what one does"): K load
# generators at once, each with its own 128^3 world and C clients, edits only; batches/s summed.
#
# On the GPU machine, from this checkout's root, the old build unpacked inside the tree:
#   mkdir -p ab/old && git archive OLD_COMMIT sdfserver kernels pyproject.toml | tar -x -C ab/old
#   source .whl/activate.sh; bash tools/many_worlds.sh ab/old [rounds]
# DEVICE, SIZE, DUR override the device (nvidia), the worlds' side (128) and each run's seconds (12);
# SERVE_FLAGS adds `sdfserver serve` flags to both builds' servers (for example --no-sync); OLD
# given as - measures this checkout alone. Each run's server CPU (tools/cpu_use.py) is kept beside
# its load generators' JSON. A CPU smoke run: DEVICE= SIZE=32 DUR=3 bash tools/many_worlds.sh - 1
# Results: $OUT/many-worlds.tgz and a table on stdout.
set -uo pipefail
old=${1:?old checkout, or -}; [ "$old" = - ] || old=$(cd "$old" && pwd); rounds=${2:-1}
new=$PWD
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD:${PYTHONPATH:-}
FINAL=${OUT:-/tmp/sdfserver-out}; OUT=$(mktemp -d); mkdir -p "$FINAL"
trap 'tar czf "$FINAL/many-worlds.tgz" -C "$OUT" . ; rm -rf "$OUT"' EXIT
port=8767
size=${SIZE:-128}; dur=${DUR:-12}
source "$new/tools/serve_build.sh"
load="python3 $new/clients/loadtest --url http://127.0.0.1:$port --size $size $size $size --quiet --read-every 0"

spread() {  # spread NAME K C [PROCESSES]: K generators of C clients at once
  local name=$1 k=$2 c=$3 procs=${4:-1} pids=()
  python3 "$new/tools/cpu_use.py" snap $server > "$OUT/$name-cpu-before.json"
  for i in $(seq "$k"); do
    timeout $((dur + 60)) $load --clients "$c" --processes "$procs" --duration "$dur" \
      --json "$OUT/$name-load$i.json" > /dev/null 2>&1 &
    pids+=($!)
  done
  wait "${pids[@]}"
  python3 "$new/tools/cpu_use.py" snap $server > "$OUT/$name-cpu-after.json"
}

measure() {  # measure NAME ROOT
  local name=$1 root=$2
  # shellcheck disable=SC2086  # the flags are words
  serve_build "$root" "$OUT/$name-server.log" $port /tmp/sdfserver-many-data ${SERVE_FLAGS:-} || return
  spread "$name-w1" 1 64 8
  spread "$name-w16" 16 4
  spread "$name-w64" 64 1
  kill $server; wait $server 2>/dev/null
}

for round in $(seq "$rounds"); do
  [ "$old" = - ] || measure "r$round-old" "$old"
  measure "r$round-new" "$new"
done

NEW_TREE=$new python3 - "$OUT" <<'PY'
import glob, json, os, sys
out = sys.argv[1]
runs = sorted({os.path.basename(p).rsplit("-load", 1)[0] for p in glob.glob(f"{out}/*-load*.json")})
sys.path.insert(0, os.path.join(os.environ["NEW_TREE"], "tools"))
from cpu_use import thread_split
print("| run | worlds | batches/s (sum) | worst p99 (ms) | errors | against 1 world | engine CPU a batch | by thread |")
print("| --- | --- | --- | --- | --- | --- | --- | --- |")
one = {}
for run in runs:
    loads = []
    for p in sorted(glob.glob(f"{out}/{run}-load*.json")):
        try:
            loads.append(json.load(open(p)))
        except ValueError:
            pass
    if not loads:
        continue
    total = sum(r["throughput_rps"] for r in loads)
    p99 = max(r["edits"]["latency_ms"]["p99"] for r in loads)
    errors = sum(r["errors"]["count"] for r in loads)
    build, worlds = run.rsplit("-w", 1)
    if worlds == "1":
        one[build] = total
    ratio = f"{total / one[build]:.2f}x" if build in one and worlds != "1" else ""
    engine = threads = ""
    try:
        before, after = (json.load(open(f"{out}/{run}-cpu-{when}.json")) for when in ("before", "after"))
        batches = sum(r["requests"] for r in loads)
        engine = f"{(after['engine_s'] - before['engine_s']) / batches * 1e6:.0f} us"
        threads = ", ".join(f"{n} {u:.0f}" for n, u in thread_split(before, after, batches).items())
    except (OSError, ValueError, KeyError, ZeroDivisionError):
        pass
    print(f"| {build} | {worlds} | {total:,.0f} | {p99:.1f} | {errors} | {ratio} | {engine} | {threads} |")
PY
