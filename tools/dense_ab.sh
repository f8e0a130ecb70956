#!/usr/bin/env bash
# Dense worlds against an older build in one lease (the targets' "nothing gets slower"): exact
# 512^3 full regeneration and a radius-8 brush in a 1024^3 world (cap 255), `sdfserver bench` of
# each checkout in turn, alternating, so both see the same device state.
#
# Usage on the GPU machine, from this checkout's root, the old build unpacked inside the tree so
# that it travels:
#   mkdir -p ab/old && git archive OLD_COMMIT sdfserver kernels pyproject.toml | tar -x -C ab/old
#   source .whl/activate.sh; bash tools/dense_ab.sh ab/old [rounds]
# DEVICE, WORLD, UPDATE_WORLD, REPS override the device (nvidia), the regenerated world's side
# (512), the brush's world side (1024) and the repetitions (20); a CPU smoke run uses
#   DEVICE= WORLD=64 UPDATE_WORLD=128 REPS=3 bash tools/dense_ab.sh ab/old 1
# Results: $OUT/dense-ab/*.json (each run's `bench --json`) and a table on stdout.
set -uo pipefail
old=$(cd "${1:?old checkout}" && pwd); rounds=${2:-2}
new=$PWD
out=${OUT:-/tmp/sdfserver-out}/dense-ab; mkdir -p "$out"
device=${DEVICE-nvidia}; world=${WORLD:-512}; update_world=${UPDATE_WORLD:-1024}; reps=${REPS:-20}

run() {  # run NAME ROOT: one bench of checkout ROOT into $out/NAME.json
  (cd "$2" && PYTHONPATH=$2:${PYTHONPATH:-} timeout 240 python3 -m sdfserver bench ${device:+--device "$device"} \
    --sections worlds,update --algorithms exact --padded "" --world-sizes "$world" \
    --update-world "$update_world" --update-caps 255 --reps "$reps" --accuracy-max-world 0 \
    --json "$out/$1.json" > "$out/$1.txt" 2> "$out/$1.log")
}

for round in $(seq "$rounds"); do
  run "old-$round" "$old"
  run "new-$round" "$new"
done

python3 - "$out" <<'EOF'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
print("| build, round | exact full regeneration, median ms | radius-8 brush, incremental, median / mean ms |")
print("| --- | --- | --- |")
for path in sorted(out.glob("*.json")):
    data = json.loads(path.read_text())
    worlds = [r for r in data.get("worlds", []) if r.get("algorithm") == "exact"]
    updates = data.get("update", [])
    regen = f"{worlds[0]['median_ms']:.3f}" if worlds else "?"
    brush = f"{updates[0]['median_ms']:.3f} / {updates[0]['mean_ms']:.3f}" if updates else "?"
    print(f"| {path.stem} | {regen} | {brush} |")
EOF
