#!/usr/bin/env bash
# Engines as Ray actors sharing one GPU against the embedded server, in one lease: for each
# configuration a lone client's edit -> field round trip, then K load generators at once (each on
# its own world, C clients each), batches/s summed; then, with two actors, the time until a killed
# engine's worlds serve again.
#
# On the GPU machine, after `source .whl/activate.sh` (with ray-site.tar.xz among the wheels,
# ../shared/gpu/fetch-ray.sh), from the checkout's root:
#   bash tools/cluster_bench.sh
# K, C, DUR, SIZE, KILL_WORLDS, KILL_SIZE, WORKERS and STAGGER override 16 generators x 4 clients,
# 15 s, 128^3 worlds, 10 worlds of 256^3 for the kill, 4 API processes, 0.2 s between generators'
# starts (64 clients over 64 worlds: K=64 C=1 STAGGER=0.02); a CPU smoke run:
#   DEVICE= GPU=0 K=2 C=2 DUR=3 SIZE=32 KILL_WORLDS=2 KILL_SIZE=32 WORKERS=1 bash tools/cluster_bench.sh
# Results: $OUT/cluster-*.json and a table on stdout.
set -uo pipefail
port=8767; K=${K:-16}; C=${C:-4}; DUR=${DUR:-15}; SIZE=${SIZE:-128}; WORKERS=${WORKERS:-4}
KILL_WORLDS=${KILL_WORLDS:-10}; KILL_SIZE=${KILL_SIZE:-256}; DEVICE=${DEVICE-nvidia}; GPU=${GPU:-1}
STAGGER=${STAGGER:-0.2}
FINAL=${OUT:-/tmp/sdfserver-out}; mkdir -p "$FINAL"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
source "$(dirname "$0")/serve_build.sh"
url=http://127.0.0.1:$port
load="python3 clients/loadtest --url $url --size $SIZE $SIZE $SIZE --quiet"

serve() {  # serve TAG FLAGS...: a server, waited for until ready (or 240 s), its start time kept
  local tag=$1; shift
  local started; started=$(date +%s.%N)
  READY_S=240 serve_build . "$FINAL/cluster-$tag-server.log" $port /tmp/sdfserver-cluster-data \
    --workers "$WORKERS" --no-warm-up "$@" || return 1
  python3 -c 'import sys, time; print(round(time.time() - float(sys.argv[1]), 1))' "$started" \
    > "$FINAL/cluster-$tag-start.txt"
}

measure() {  # measure TAG FLAGS...
  local tag=$1; shift
  serve "$tag" "$@" || return
  timeout 60 $load --clients 1 --duration 8 --read-every 1 --read-size 16 --json "$FINAL/cluster-$tag-rtt.json" \
    > /dev/null 2>&1
  pids=()
  for k in $(seq "$K"); do
    timeout $((DUR + 60)) $load --clients "$C" --duration "$DUR" --read-every 0 \
      --json "$FINAL/cluster-$tag-load$k.json" > /dev/null 2>&1 &
    pids+=($!)
    sleep "$STAGGER"
  done
  wait "${pids[@]}"
  kill $server; wait $server 2>/dev/null
}

measure embedded
gpus() { python3 -c "print($GPU / $1)"; }  # each of N actors' share of the GPU (GPU=0: CPU devices)
measure ray1 --cluster local --engines 1 --engine-gpus "$(gpus 1)"
measure ray2 --cluster local --engines 2 --engine-gpus "$(gpus 2)"
measure ray4 --cluster local --engines 4 --engine-gpus "$(gpus 4)"

# the kill: two actors, KILL_WORLDS worlds written to, SIGKILL of the engine holding the first
serve kill --cluster local --engines 2 --engine-gpus "$(gpus 2)" || exit 1
python3 - "$url" "$KILL_WORLDS" "$KILL_SIZE" "$FINAL/cluster-kill.json" <<'PY'
import json, os, signal, sys, time
import httpx
url, n, side, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
http = httpx.Client(base_url=url, timeout=120)
worlds = [http.post("/v1/worlds", json={"size": [side] * 3, "chunk_size": 32}).json()["id"] for _ in range(2 * n)]
for w in worlds:
    for i in range(20):
        http.post(f"/v1/worlds/{w}/edits", json={"edits": [{"op": "sphere", "center": [i * 7 % side, 40, 60],
                                                            "radius": 6, "colour": 1 + i}]})
engines = http.get("/v1/engines").json()
victim = max(engines, key=lambda e: e["worlds"])
mine = victim["world_ids"][:n]
killed = time.monotonic()
os.kill(victim["pid"], signal.SIGKILL)
waiting = set(mine)
while waiting and time.monotonic() - killed < 120:
    for w in list(waiting):
        try:
            if http.get(f"/v1/worlds/{w}/field", params={"min": "0,0,0", "max": "1,1,1", "min_version": 20},
                        timeout=2).status_code == 200:
                waiting.discard(w)
        except httpx.TransportError:
            pass
    time.sleep(0.02)
back = time.monotonic() - killed
after = next(e for e in http.get("/v1/engines").json() if e["engine"] == victim["engine"])
result = {"worlds_on_killed_engine": len(victim["world_ids"]), "watched": len(mine), "side": side,
          "serving_again_s": round(back, 2), "not_back": sorted(waiting), "pid_before": victim["pid"],
          "pid_after": after["pid"]}
json.dump(result, open(out, "w"))
print(result)
PY
kill $server; wait $server 2>/dev/null

python3 - "$FINAL" "$K" "$C" <<'PY'
import glob, json, sys
out, k, c = sys.argv[1], sys.argv[2], sys.argv[3]
print(f"| server | start (s) | lone client edit -> field p50 (ms) | {k} x {c} clients: batches/s (sum) | worst p99 (ms) | errors |")
print("| --- | --- | --- | --- | --- | --- |")
for tag in ("embedded", "ray1", "ray2", "ray4"):
    try:
        rtt = json.load(open(f"{out}/cluster-{tag}-rtt.json"))["round_trips"]["latency_ms"]["p50"]
        loads = [json.load(open(p)) for p in sorted(glob.glob(f"{out}/cluster-{tag}-load*.json"))]
        start = open(f"{out}/cluster-{tag}-start.txt").read().strip()
    except (OSError, ValueError, KeyError) as exc:
        print(f"| {tag} | (no result: {exc}) |")
        continue
    total = sum(r["throughput_rps"] for r in loads)
    p99 = max(r["edits"]["latency_ms"]["p99"] for r in loads)
    errors = sum(r["errors"]["count"] for r in loads)
    print(f"| {tag} | {start} | {rtt:.2f} | {total:,.0f} | {p99:.1f} | {errors} |")
PY
