#!/usr/bin/env bash
# A lone client's edit-and-read round trip on a 128^3 world, with the engine idle and while
# another world on the same engine regenerates again and again (PATCH algorithm fim, then jfa,
# each a full recompute of a BIG^3 world): how much one tenant's heavy recompute costs another.
#
# Usage on the GPU machine, from the project root:
#   source .whl/activate.sh; bash tools/neighbour_stall.sh "this=. --step-budget-ms 20" "old=ab/old"
# Each argument is a build: its name, '=', its checkout, then `sdfserver serve` flags (the
# recompute cost limit is lifted, since fim at 1024^3 is past the default). BIG (1024) the heavy
# world's side, DUR (8) seconds a run. Results: $OUT/stall/ and a table.
set -uo pipefail
export PYTHONUNBUFFERED=1
here=$(cd "$(dirname "$0")" && pwd)
source "$here/serve_build.sh"
out=${OUT:-/tmp/sdfserver-out}/stall; mkdir -p "$out"; port=8767
big=${BIG:-1024}; dur=${DUR:-8}
for build in "$@"; do
  name=${build%%=*}; read -r tree flags <<< "${build#*=}"
  # shellcheck disable=SC2086  # the flags are words
  serve_build "$tree" "$out/$name-server.log" $port /tmp/sdfserver-stall-data --max-recompute-voxel-visits 0 $flags \
    || continue
  url=http://127.0.0.1:$port
  heavy=$(python3 - "$url" "$big" <<'PY'
import sys, httpx
url, side = sys.argv[1], int(sys.argv[2])
world = httpx.post(f"{url}/v1/worlds", json={"size": [side] * 3, "chunk_size": 32, "algorithm": "fim"},
                   timeout=600).json()
httpx.post(f"{url}/v1/worlds/{world['id']}/edits", json={"edits": [
    {"op": "sphere", "center": [side / 3] * 3, "radius": side / 8, "colour": 1},
    {"op": "box", "min": [side // 2] * 3, "max": [side // 2 + 40] * 3, "colour": 2}]}, timeout=600)
print(world["id"])
PY
)
  python3 clients/loadtest --url $url --size 128 128 128 --quiet --clients 1 --duration "$dur" --read-every 1 \
    --json "$out/$name-idle.json" > /dev/null 2>&1
  # the neighbour: regenerations back to back for the whole run, each PATCH timed
  python3 - "$url" "$heavy" "$((dur + 2))" > "$out/$name-switches.txt" <<'PY' &
import sys, time, httpx
url, world, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
end, algorithms, times = time.monotonic() + seconds, ["jfa", "fim"], []
with httpx.Client(timeout=600) as client:
    while time.monotonic() < end:
        started = time.perf_counter()
        client.patch(f"{url}/v1/worlds/{world}", json={"algorithm": algorithms[len(times) % 2]}).raise_for_status()
        times.append(time.perf_counter() - started)
print(f"{len(times)} regenerations; PATCH answered in {min(times) * 1e3:.0f}..{max(times) * 1e3:.0f} ms")
PY
  switcher=$!
  sleep 1
  python3 clients/loadtest --url $url --size 128 128 128 --quiet --clients 1 --duration "$dur" --read-every 1 \
    --json "$out/$name-busy.json" > /dev/null 2>&1
  wait $switcher
  curl -s $url/metrics | grep -E '^sdfserver_recompute_seconds_(sum|count)' > "$out/$name-recomputes.txt"
  kill $server; wait $server 2>/dev/null
done
python3 - "$out" "$@" <<'PY'
import json, sys
out, builds = sys.argv[1], [b.split("=", 1)[0] for b in sys.argv[2:]]
print("| build | idle p50 / p99, ms | round trips/s | busy p50 / p99 / max, ms | round trips/s | p99 busy/idle | neighbour |")
print("| --- | ---: | ---: | ---: | ---: | ---: | --- |")
for name in builds:
    try:
        idle, busy = (json.load(open(f"{out}/{name}-{k}.json"))["round_trips"] for k in ("idle", "busy"))
        switches = open(f"{out}/{name}-switches.txt").read().strip()
    except (OSError, ValueError, KeyError) as exc:
        print(f"| {name} | failed: {exc!r} | | | | | |")
        continue
    i, b = idle["latency_ms"], busy["latency_ms"]
    print(f"| {name} | {i['p50']:.2f} / {i['p99']:.2f} | {idle['throughput_per_s']:.0f} | {b['p50']:.2f} / {b['p99']:.2f} / "
          f"{b['max']:.1f} | {busy['throughput_per_s']:.0f} | {b['p99'] / i['p99']:.1f}× | {switches} |")
PY
