#!/usr/bin/env bash
# One GPU against two on the same machine (issue 22, item 3), real episodes through `pipeline run`
# (scripts/bench/gpu_end_to_end.sh: OpenVLA-7B random weights, libero_spatial, MAX_STEPS, default 60):
#   one: a replica on cuda:0 with the renders on that GPU too (MUJOCO_EGL_DEVICE_ID: what a machine
#        with one GPU does), JOBS workers, TRIALS trials per task;
#   two: a replica on each of cuda:0 and cuda:1 with the default GL thread, twice the workers and
#        the episodes (the same per GPU);
# then the ratio of their policy steps/s. Machines of one kind differ by up to ~15% from lease to
# lease (data/benchmarks/gpu-two-h100-one-gl-thread-2026-11-27): the ratio means something only
# within one call. ORDER=two-first runs them the other way round.
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_two_gpus.sh CARRY OUT [JOBS:TRIALS]
#   CARRY: scripts/bench/gpu_carry.sh's folder; OUT: each run's `bench run` figures, logs and
#   nvidia-smi samples (the runs themselves stay in $TMPDIR: the device tool returns small files).
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); IFS=: read -r jobs trials <<< "${3:-32:12}"
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-two; mkdir -p "$work"
. scripts/bench/gpu_setup.sh

# the EGL device of CUDA device 0, from the device `bench render` reports for each
egl0=""
for id in 0 1 2 3; do
  line=$(MUJOCO_EGL_DEVICE_ID=$id "$P" --bundles "$work/bundles" bench render --suites libero_spatial --python none \
    --frames 2 --threads 2 2>/dev/null | grep 'threads per' || true)
  if [[ $line == *"(($id, Some(0)))"* ]]; then egl0=$id; break; fi
done
[ -n "$egl0" ] || { echo "no EGL device reports CUDA device 0" >&2; exit 1; }

one() { MUJOCO_EGL_DEVICE_ID=$egl0 run_e2e one "$jobs:64:$trials:devices=cuda:0"; }
two() { run_e2e two "$((2 * jobs)):64:$((2 * trials)):devices=cuda:0,cuda:1"; }
run_e2e() {
  local name=$1 run=$2
  MAX_STEPS=${MAX_STEPS:-60} bash scripts/bench/gpu_end_to_end.sh "$carry" "$work/runs/$name" "$run" > "$out/$name.log" 2>&1
  find "$work/runs/$name" -maxdepth 1 -type f \( -name '*.txt' -o -name '*.csv' -o -name '*.log' \) \
    -exec sh -c 'cp "$1" "$2/'"$name"'-$(basename "$1")"' _ {} "$out" \;
  grep -A6 'where the time goes' "$out/$name.log" | sed "s/^/$name: /" | tee -a "$out/figures.txt"
}
if [ "${ORDER:-one-first}" = two-first ]; then two; one; else one; two; fi
rate() { grep -o '[0-9.]* policy steps/s' "$out/$1.log" | head -1 | cut -d' ' -f1; }
echo "two GPUs / one GPU: $(rate two) / $(rate one) = $(python3 -c "print(round($(rate two) / $(rate one), 3))") (JOBS=$jobs TRIALS=$trials per GPU, EGL device $egl0 for one)" | tee -a "$out/figures.txt"
