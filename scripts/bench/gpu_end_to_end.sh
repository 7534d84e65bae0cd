#!/usr/bin/env bash
# Real episodes through `pipeline run` on a GPU machine: rollout workers on its cores, cameras on
# NVIDIA EGL, OpenVLA-7B batched on the GPU; then `pipeline bench run` prints where a policy step's
# time goes, the episodes per hour, the model's busy fraction and the projected canonical protocol.
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_end_to_end.sh CARRY OUT [RUN ...]
#   CARRY: a folder made on the build machine by scripts/bench/gpu_carry.sh (the stripped pipeline,
#          libmujoco, the task bundles of libero_spatial, OpenVLA-7B's layout and the GL libraries);
#   OUT:   where the runs, their `bench run` figures and nvidia-smi's samples go;
#   RUN:   JOBS:BATCH:TRIALS (rollout workers, episodes per forward, trials per task of
#          libero_spatial's 10 tasks); default 32:32:4.
# The machine needs python3 with torch 2.11 (libtorch for tch, and the random 7B weights) and the
# NVIDIA driver's EGL. Weights are random (none can be downloaded there): the figures are speed and
# memory, not success rates.
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); shift 2
runs=("${@:-32:32:4}")
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"

# NVIDIA's EGL through glvnd (the machine has the vendor library, not always the dispatcher)
if ! ldconfig -p | grep -q libEGL.so.1; then
  for f in "$carry"/gl/*.deb; do dpkg -x "$f" /; done; ldconfig
fi
[ -f /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json ] &&
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json

# the pipeline, libmujoco and the bundles
xz -dc "$carry/pipeline.xz" > "$work/pipeline"; chmod +x "$work/pipeline"
mkdir -p "$work/bundles"; xz -dc "$carry/bundles.tar.xz" | tar -xf - -C "$work/bundles"
(cd "$work/bundles" && xargs -r mkdir -p < dirs.txt)

# libtorch from the machine's torch (the version tch was built against), CUDA's libraries beside it
torch_lib=$(python3 -c 'import os, torch; print(os.path.join(os.path.dirname(torch.__file__), "lib"))')
nv_libs=$(python3 -c 'import glob, os, torch; r = os.path.dirname(os.path.dirname(torch.__file__)); print(":".join(sorted(glob.glob(os.path.join(r, "nvidia", "*", "lib")) + glob.glob(os.path.join(r, "nvidia", "cu*", "lib")))))')
export LD_LIBRARY_PATH="$torch_lib:$nv_libs:$carry/lib:${LD_LIBRARY_PATH:-}"
export LD_PRELOAD="$torch_lib/libtorch_cuda.so"
P="$work/pipeline"
"$P" --version

# OpenVLA-7B: the layout carried, the random bf16 weights written here
ckpt="$work/openvla-7b"; mkdir -p "$ckpt"; cp "$carry"/openvla-7b/* "$ckpt"/
[ -f "$ckpt/model-00004-of-00004.safetensors" ] || python3 scripts/reference/fill_random_weights.py "$ckpt"

nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used,power.draw --format=csv,noheader -lms 250 > "$out/nvidia-smi.csv" &
smi=$!
trap 'kill $smi 2>/dev/null || true' EXIT
for r in "${runs[@]}"; do
  IFS=: read -r jobs batch trials <<< "$r"
  name="spatial-j${jobs}-b${batch}-t${trials}"
  "$P" --bundles "$work/bundles" specs --suites libero_spatial --trials "$trials" -o "$work/$name.parquet"
  echo "::: $name: start $(date -u +%FT%T.%3NZ)" | tee -a "$out/runs.log"
  "$P" --bundles "$work/bundles" run "$work/$name.parquet" --out "$out/$name" \
    --policy "openvla:$ckpt?unnorm=libero_spatial_no_noops&batch=$batch" --jobs "$jobs" 2>&1 | tee "$out/$name.log" | grep -v '^|\|^+' || true
  echo "::: $name: end $(date -u +%FT%T.%3NZ)" | tee -a "$out/runs.log"
  "$P" --bundles "$work/bundles" bench run --run "$out/$name" --no-rescoring | tee "$out/$name.bench.txt"
done
