#!/usr/bin/env bash
# Real episodes through `pipeline run` on a GPU machine: rollout workers on its cores, cameras on
# NVIDIA EGL, OpenVLA-7B batched on the GPU; then `pipeline bench run` prints where a policy step's
# time goes, the episodes per hour, the model's busy fraction and the projected canonical protocol.
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_end_to_end.sh CARRY OUT [RUN ...]
#   CARRY: a folder made on the build machine by scripts/bench/gpu_carry.sh (the stripped pipeline,
#          libmujoco, the task bundles of libero_spatial, OpenVLA-7B's layout and the GL libraries);
#   OUT:   where the runs, their `bench run` figures and nvidia-smi's samples go (a run already
#          there is deleted first: every run starts afresh, none is resumed);
#   RUN:   JOBS:BATCH:TRIALS[:OPTIONS] (rollout workers, episodes per forward, trials per task of
#          libero_spatial's 10 tasks, more options of the policy, e.g. devices=cuda:0,cuda:1 or
#          quant=int8); default 32:32:4.
# MAX_STEPS=N caps every episode at N policy steps (default: the suite's cap, 220).
# MODEL=oft runs OpenVLA-OFT 7B (`oft:`; its heads drawn by scripts/reference/oft_from_openvla.py on
# OpenVLA-7B's random backbone) instead of OpenVLA-7B (`openvla:`, the default).
# PROCESSES=N runs the episodes in N processes (`pipeline run --processes N`: the policy's devices=
# dealt out, each process rendering on its own GPU). Unset, `pipeline run` decides: a process per GPU
# where devices= lists several GPUs; PROCESSES=1 keeps their replicas in one process.
# RENDER=cpu renders the cameras on Mesa's llvmpipe instead of the GPU; it needs MESA=STAGE (Mesa
# staged by gpu_mesa_stage.sh; see gpu_setup.sh).
# ENGINE=ballista://HOST:PORT runs the episodes on that cluster's executors instead of in this
# process (JOBS is then unused: the executors' slots decide how many run at once).
# What the machine needs: scripts/bench/gpu_setup.sh. Weights are random (none can be downloaded
# there): the figures are speed and memory, not success rates.
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); shift 2
runs=("${@:-32:32:4}")
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"

model=${MODEL:-openvla}
case "$model" in
  openvla | oft) ;;
  *) echo "MODEL=$model: openvla or oft" >&2; exit 2 ;;
esac
. scripts/bench/gpu_setup.sh
renders=()
case "${RENDER:-}" in
  "") ;;
  cpu) renders=(env MUJOCO_EGL_DEVICE_ID="${SOFTWARE_EGL_DEVICE:?RENDER=cpu needs MESA}") ;;
  *) echo "RENDER=$RENDER: cpu, or unset for the GPU" >&2; exit 2 ;;
esac

nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used,power.draw --format=csv,noheader -lms 250 > "$out/nvidia-smi.csv" &
smi=$!
trap 'kill $smi 2>/dev/null || true' EXIT
for r in "${runs[@]}"; do
  IFS=: read -r jobs batch trials options <<< "$r"
  name="$model-spatial-j${jobs}-b${batch}-t${trials}${options:+-$(echo "$options" | tr -c 'a-z0-9\n' '_')}${RENDER:+-$RENDER-renders}${PROCESSES:+-p$PROCESSES}"
  "$P" --bundles "$work/bundles" specs --suites libero_spatial --trials "$trials" -o "$work/$name.parquet"
  # a run left in OUT by an earlier call on the same (warm) machine would be resumed, run nothing,
  # and report its old figures as new
  rm -rf "${out:?}/$name"
  echo "::: $name: start $(date -u +%FT%T.%3NZ)" | tee -a "$out/runs.log"
  "${renders[@]}" "$P" --bundles "$work/bundles" run "$work/$name.parquet" --out "$out/$name" \
    --policy "$model:$ckpt?unnorm=libero_spatial_no_noops&batch=$batch${options:+&$options}" --jobs "$jobs" ${MAX_STEPS:+--max-steps "$MAX_STEPS"} ${PROCESSES:+--processes "$PROCESSES"} ${ENGINE:+--engine "$ENGINE"} 2>&1 | tee "$out/$name.log" | grep -v '^|\|^+' || true
  echo "::: $name: end $(date -u +%FT%T.%3NZ)" | tee -a "$out/runs.log"
  "$P" --bundles "$work/bundles" bench run --run "$out/$name" --no-rescoring | tee "$out/$name.bench.txt"
  # the attention the manifest records (with, for SDPA on a GPU, whether cuDNN's attention was kept last)
  python3 -c 'import json, sys; i = json.load(open(sys.argv[1]))["policy_identity"]; print("attention:", json.dumps({k: i.get(k) for k in ("attention", "sdpa_cudnn_environment")}))' \
    "$out/$name/manifest.json" | tee -a "$out/$name.bench.txt" || true
done
