#!/usr/bin/env bash
# Item 3 of issue 46 within one call on a machine of two GPUs: OpenVLA-7B's B = 64 forward alone on
# cuda:0 (policies/benches/openvla.rs), then the same `pipeline run` with the model on cuda:0 twice,
# its cameras first on the other GPU, then on the model's own GPU (as on a one-GPU machine). Each
# run's rate against the forward's is then a ratio of one call; `bench run` splits each run's step.
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_renders_elsewhere.sh CARRY OUT
#   CARRY: made by scripts/bench/gpu_carry.sh with the bench binary; OUT: logs, `bench run` figures,
#   nvidia-smi's per-GPU samples, vmstat and the runs' start and end times (times.txt).
# JOBS (128), BATCH (64), TRIALS per task (13), MAX_STEPS (120), WARMUP (3), ITERS (10): the runs
# and the forward. The runs are kept in the work folder ($TMPDIR/libero-gpu-e2e/runs).
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2")
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"
unset BENCH  # set by gpu_setup.sh where the carry has the bench binary, not by the caller
. scripts/bench/gpu_setup.sh
: "${BENCH:?the carry has no bench binary: build it (cargo bench -p libero-policies --bench openvla --no-run) and rerun gpu_carry.sh}"
jobs=${JOBS:-128}; batch=${BATCH:-64}; trials=${TRIALS:-13}; steps=${MAX_STEPS:-120}

# EGL's index of each CUDA device, from `pipeline doctor`'s list ("0: hardware, CUDA device 0")
devices=$("$P" --bundles "$work/bundles" doctor 2>&1 | tee "$out/doctor.txt" | grep -o '[0-9][0-9]*: hardware, CUDA device [0-9][0-9]*' || true)
egl_of() { echo "$devices" | sed -n "s/^\([0-9][0-9]*\): hardware, CUDA device $1\$/\1/p" | head -1; }
model_egl=$(egl_of 0); other_egl=$(egl_of 1)
[ -n "$model_egl" ] && [ -n "$other_egl" ] || { echo "EGL lists no device for CUDA 0 and 1: $devices" >&2; exit 1; }
echo "EGL device $model_egl is cuda:0 (the model's), $other_egl is cuda:1" | tee "$out/times.txt"

nvidia-smi --query-gpu=timestamp,index,utilization.gpu,memory.used --format=csv,noheader -lms 500 > "$out/nvidia-smi.csv" &
smi=$!
vmstat -t 5 > "$out/vmstat.txt" &
vm=$!
trap 'kill $smi $vm 2>/dev/null || true' EXIT

echo "forward start $(date -u +%T.%3N)" >> "$out/times.txt"
CUDA_VISIBLE_DEVICES=0 "$BENCH" --checkpoint "$ckpt" --attention sdpa --device cuda --batch "$batch" \
  --warmup "${WARMUP:-3}" --iters "${ITERS:-10}" --json "$out/forward.json" > "$out/forward.log" 2>&1
echo "forward end $(date -u +%T.%3N)" >> "$out/times.txt"
grep "B=" "$out/forward.log"

"$P" --bundles "$work/bundles" specs --suites libero_spatial --trials "$trials" -o "$work/where.parquet"
for where in other:$other_egl model:$model_egl; do
  name=renders-on-${where%%:*}-gpu
  rm -rf "${work:?}/runs/$name"
  echo "$name start $(date -u +%T.%3N)" >> "$out/times.txt"
  rc=0
  MUJOCO_EGL_DEVICE_ID=${where#*:} "$P" --bundles "$work/bundles" run "$work/where.parquet" --out "$work/runs/$name" \
    --max-steps "$steps" --jobs "$jobs" \
    --policy "openvla:$ckpt?unnorm=libero_spatial_no_noops&batch=$batch&devices=cuda:0" > "$out/$name.log" 2>&1 || rc=$?
  echo "$name end rc $rc $(date -u +%T.%3N)" >> "$out/times.txt"
  # a failed run or bench still leaves the other run to make
  "$P" --bundles "$work/bundles" bench run --run "$work/runs/$name" --no-rescoring > "$out/$name.bench.txt" 2>&1 || true
  grep -i "policy steps\|per forward\|cameras\|busy" "$out/$name.bench.txt" | head -8 || true
done
cat "$out/times.txt"
