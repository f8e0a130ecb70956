#!/usr/bin/env bash
# A lone client's edit -> field-ready round trip from several builds, in many short runs that
# alternate between them, so that a host that drifts over minutes drifts under every build alike.
# One 4 s run's p50 moves by a few hundred microseconds on the lent machines; the median of
# the runs is what tells builds apart.
#
# Usage on the GPU machine, from the project root:
#   source .whl/activate.sh; bash tools/lone_round_trips.sh "this=." "old=ab/old"
# Each argument is a build: its name, '=', its checkout, then `sdfserver serve` flags. ROUNDS
# (3) servers a build, RUNS (3) runs of DUR (4) seconds each server, SIZE (256) the world's
# side. Results: $OUT/lone/ (each run's JSON and server log) and a table of each build's runs
# and their median.
set -uo pipefail
export PYTHONUNBUFFERED=1
source "$(dirname "$0")/serve_build.sh"
out=${OUT:-/tmp/sdfserver-out}/lone; mkdir -p "$out"; port=8766
for round in $(seq "${ROUNDS:-3}"); do
  for build in "$@"; do
    name=${build%%=*}; read -r tree flags <<< "${build#*=}"
    # shellcheck disable=SC2086  # the flags are words
    serve_build "$tree" "$out/$name-$round-server.log" $port /tmp/sdfserver-lone-data $flags || continue
    for run in $(seq "${RUNS:-3}"); do
      timeout 60 python3 clients/loadtest --url http://127.0.0.1:$port --size ${SIZE:-256} ${SIZE:-256} ${SIZE:-256} --quiet --clients 1 \
        --duration "${DUR:-4}" --read-every 1 --read-size 16 --json "$out/$name-$round-$run.json" > /dev/null 2>&1
    done
    kill $server; wait $server 2>/dev/null
  done
done
python3 - "$out" "$@" <<'PY'
import glob, json, statistics, sys
out, builds = sys.argv[1], [b.split("=", 1)[0] for b in sys.argv[2:]]
print("| build | runs | round trip p50 of each run, ms | median | edit, read (medians) |")
print("| --- | ---: | --- | ---: | --- |")
for name in builds:
    runs = []
    for path in sorted(glob.glob(f"{out}/{name}-*-*.json")):
        try:
            report = json.load(open(path))
            runs.append([report[k]["latency_ms"]["p50"] for k in ("round_trips", "edits", "reads")])
        except (OSError, ValueError, KeyError):
            continue
    if not runs:
        print(f"| {name} | 0 | failed | | |")
        continue
    trips, edits, reads = zip(*runs)
    print(f"| {name} | {len(runs)} | {', '.join(f'{t:.2f}' for t in trips)} | **{statistics.median(trips):.2f}** | "
          f"{statistics.median(edits):.2f}, {statistics.median(reads):.2f} |")
PY
