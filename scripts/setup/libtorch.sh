#!/usr/bin/env bash
# libtorch for tch 0.24.0 from the PyPI torch==2.11.0 wheel (the GPU machine's version: a mismatch
# computes wrong results silently), plus the two small CUDA runtime wheels libtorch_cpu.so needs
# even on CPU. Unpacks only the CPU libraries + headers (~500 MB). Idempotent.
set -euo pipefail
DEST="${1:?usage: libtorch.sh DEST}"
TORCH_VERSION=2.11.0
if [ -f "$DEST/.complete-$TORCH_VERSION" ]; then exit 0; fi
rm -rf "$DEST"; mkdir -p "$DEST/whl"
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.11 \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_25_x86_64 --platform manylinux_2_17_x86_64 \
  -d "$DEST/whl" "torch==$TORCH_VERSION" "nvidia-cuda-runtime==13.0.96" "nvidia-cuda-cupti==13.0.85"
cd "$DEST"
unzip -q -o whl/torch-"$TORCH_VERSION"-*.whl 'torch/include/*' torch/version.py torch/lib/libtorch_cpu.so \
  torch/lib/libtorch.so torch/lib/libc10.so torch/lib/libgomp.so.1
unzip -q -o -j whl/nvidia_cuda_runtime-*.whl '*/libcudart.so.13' -d torch/lib
unzip -q -o -j whl/nvidia_cuda_cupti-*.whl '*/libcupti.so.13' -d torch/lib
grep -q "__version__ = '$TORCH_VERSION" torch/version.py
rm -rf whl
touch ".complete-$TORCH_VERSION"
echo "libtorch $TORCH_VERSION -> $DEST/torch"
