#!/usr/bin/env bash
# `sdfserver bench metrics` on the GPU machine in one lease (issue 30, item 6): every metric and
# sign at 64^3 .. 1024^3 (with scipy's accuracy up to 256^3 and the cupyx anchor), then the
# Manhattan-only before/after: tools/dense_ab.sh (`sdfserver bench --algorithms exact`, 512^3 full
# regeneration and the radius-8 brush in 1024^3, cap 255) of the build before metric and signed
# worlds (8963431, the parent of 5ffbd24) against this one, alternating.
#
# Here, from the checkout's root, once: fetch the wheels (../shared/gpu/README.md) and unpack the
# old build under the git-ignored ab/, so that both travel when `carry` names them:
#   ../shared/gpu/fetch-wheels.sh .whl
#   mkdir -p ab/before-metrics && git archive 8963431 sdfserver kernels pyproject.toml | tar -x -C ab/before-metrics
# On the GPU machine (run with carry [".whl", "ab"]), from the checkout's root:
#   bash tools/metrics_bench_gpu.sh [ACTIVATE] [BEFORE]
# ACTIVATE: the script that sets up pyopencl and NVIDIA's OpenCL driver (default: the first of
# .whl/activate.sh, shared/gpu/activate.sh, ../shared/gpu/activate.sh that exists; "none" when the
# environment is ready). BEFORE: the old build's tree (default ab/before-metrics; made with git
# archive if git can, else the before/after is skipped, saying so).
# DEVICE (nvidia), SIZES (64,128,256,512,1024), ROUNDS (2), METRICS_TIMEOUT (420 s, then SIGINT:
# the tables keep what was measured) and METRICS_ARGS (extra options) override; a CPU smoke run:
#   DEVICE= SIZES=32,64 ROUNDS=1 METRICS_ARGS=--quick WORLD=64 UPDATE_WORLD=128 REPS=3 \
#     bash tools/metrics_bench_gpu.sh none /tmp/before-metrics
# Results: $OUT/metrics/metrics.{json,md}, $OUT/metrics-progress.log, $OUT/dense-ab/*; tables on stdout.
set -uo pipefail
activate=${1:-}
if [ -z "$activate" ]; then
  for candidate in .whl/activate.sh shared/gpu/activate.sh ../shared/gpu/activate.sh; do
    [ -f "$candidate" ] && { activate=$candidate; break; }
  done
fi
if [ -n "$activate" ] && [ "$activate" != none ]; then
  # shellcheck disable=SC1090
  source "$activate" || { echo "could not source $activate" >&2; exit 1; }
elif [ -z "$activate" ]; then
  echo "no activate.sh found (.whl/, shared/gpu/, ../shared/gpu/): using the environment as it is" >&2
fi
before=${2:-ab/before-metrics}
final=${OUT:-/tmp/sdfserver-out}; mkdir -p "$final/metrics"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
export DEVICE=${DEVICE-nvidia}

echo "== sdfserver bench metrics (every metric and sign)"
# shellcheck disable=SC2086
timeout -s INT "${METRICS_TIMEOUT:-420}" python3 -m sdfserver bench metrics ${DEVICE:+--device "$DEVICE"} \
  --sizes "${SIZES:-64,128,256,512,1024}" --out "$final/metrics" ${METRICS_ARGS:-} \
  2> >(tee "$final/metrics-progress.log" >&2)
echo "metrics bench exit status: $?"

echo "== Manhattan only, before/after: $before against this build"
if [ ! -d "$before" ]; then
  mkdir -p "$before" && git archive 8963431 sdfserver kernels pyproject.toml 2>/dev/null | tar -x -C "$before" \
    || { rm -rf "$before"; echo "skipped: no $before and no git history here to make it (see this script's head)"; exit 0; }
fi
bash tools/dense_ab.sh "$before" "${ROUNDS:-2}"
