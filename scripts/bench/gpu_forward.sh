#!/usr/bin/env bash
# One model's batched forward on the GPU machine, alone (no simulator): policies/benches/openvla.rs
# at each batch size, SDPA attention (what `pipeline run` uses on a GPU), bf16, random weights. The
# rate a run's forwards allow, to set beside `pipeline run`'s own in the same call (issue 46, item 3).
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_forward.sh CARRY OUT MODEL BATCHES
#   CARRY: made by scripts/bench/gpu_carry.sh with the bench binary; OUT: the JSON and log;
#   MODEL: openvla or oft (OFT's heads drawn by scripts/reference/oft_from_openvla.py);
#   BATCHES: e.g. 32,64.
# ITERS (default 10) timed calls after WARMUP (default 3) at each batch size; the median is printed.
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); model=$3; batches=$4
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"
MODEL=$model . scripts/bench/gpu_setup.sh
flag=(); [ "$model" = oft ] && flag=(--oft)
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/forward-$model.log"
"$BENCH" --checkpoint "$ckpt" "${flag[@]}" --attention sdpa --device cuda --batch "$batches" \
  --warmup "${WARMUP:-3}" --iters "${ITERS:-10}" --json "$out/forward-$model.json" 2>&1 | tee -a "$out/forward-$model.log"
