#!/usr/bin/env bash
# A 7B-class model's forward on a GPU machine, Python reference then Rust (tch) on the same
# random-weight bf16 checkpoint, in one call: OpenVLA (`openvla`, scripts/reference/openvla_bench.py)
# or OpenVLA-OFT (`oft`, scripts/reference/oft_bench.py); the Rust side is
# policies/benches/openvla.rs (`--oft` for OFT), which also compares its B = 1 prediction with the
# Python side's.
#
# usage (on the GPU machine, from the repo root):
#   scripts/bench/model_7b_gpu.sh MODEL WHEELS BENCH OUT [BATCHES] [ATTENTIONS]
#   MODEL:  openvla | oft
#   WHEELS: a folder of the reference's wheels for the machine's python (transformers 4.40.1,
#           tokenizers 0.19.1, timm 0.9.16, huggingface_hub 0.36.2, safetensors 0.4.5, numpy 1.26.4),
#           made on the build machine with `pip download --only-binary=:all: --python-version 3.12
#           --platform manylinux2014_x86_64 --no-deps -d WHEELS <those>`;
#   BENCH:  the bench binary built here (`cargo bench -p libero-policies --bench openvla --no-run`),
#           stripped and xz-compressed;
#   OUT:    python.json, rust-<attention>.json and the log;
#   BATCHES: default 1,8,32;
#   ATTENTIONS: the Rust side's passes, each `model` (the model's own: SDPA on a GPU, for both
#           models since 2026-11-27), `eager` or `sdpa`; default `model`.
# The machine needs python3 with torch 2.11 (the libtorch tch links) and its CUDA libraries.
set -euo pipefail
model=$1; wheels=$(realpath "$2"); bench=$(realpath "$3"); out=$(realpath -m "$4"); batches=${5:-1,8,32}
attentions=${6:-model}
mkdir -p "$out"; work=${TMPDIR:-/tmp}/libero-7b-bench; mkdir -p "$work"
case $model in
  openvla) script=scripts/reference/openvla_bench.py; flag=() ;;
  oft) script=scripts/reference/oft_bench.py; flag=(--oft) ;;
  *) echo "MODEL must be openvla or oft, not $model" >&2; exit 2 ;;
esac
python3 -m pip install -q --no-deps --target "$work/site" "$wheels"/*.whl
ckpt="$work/$model-7b"; rm -rf "$ckpt"
PYTHONPATH="$work/site" USE_FLAX=0 USE_TF=0 python3 "$script" "$ckpt" --batch "$batches" --warmup 5 --iters 20 \
  --json "$out/python.json" 2>&1 | grep -v Warning | tee "$out/bench.log"
torch_lib=$(python3 -c 'import os, torch; print(os.path.join(os.path.dirname(torch.__file__), "lib"))')
nv_libs=$(python3 -c 'import glob, os, torch; r = os.path.dirname(os.path.dirname(torch.__file__)); print(":".join(sorted(glob.glob(os.path.join(r, "nvidia", "*", "lib")) + glob.glob(os.path.join(r, "nvidia", "cu*", "lib")))))')
xz -dc "$bench" > "$work/bench"; chmod +x "$work/bench"
for a in $attentions; do
  att=(); [ "$a" = model ] || att=(--attention "$a")
  LD_LIBRARY_PATH="$torch_lib:$nv_libs:${LD_LIBRARY_PATH:-}" LIBERO_TORCH_CUDA_LIB="$torch_lib" \
    "$work/bench" --checkpoint "$ckpt" "${flag[@]}" "${att[@]}" --device cuda --batch "$batches" --warmup 5 \
    --iters 20 --json "$out/rust-$a.json" 2>&1 | tee -a "$out/bench.log"
done
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee -a "$out/bench.log"
