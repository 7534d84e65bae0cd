#!/usr/bin/env bash
# libtorch's CUDA backend on a GPU machine: links LINK (third_party/libtorch-cuda), where `pipeline`
# looks for libtorch_cuda.so at start (policies/src/cuda_backend.rs), to the torch/lib folder of a
# torch 2.11.0 with CUDA whose CUDA libraries lie where that library's RPATH looks for them
# ($ORIGIN/../../nvidia/<lib>/lib: the nvidia-* wheels beside torch/, as in site-packages).
# The build still links only the CPU libraries (libtorch.sh), so one binary serves both machines.
#
# Only on a machine with an NVIDIA GPU (/proc/driver/nvidia/version, or `nvidia-smi -L` listing
# one): a CPU machine (CI) neither needs nor downloads the ~3 GB of CUDA libraries.
# LIBERO_SETUP_CUDA=1 or 0 overrides that answer (a container that shows neither; a GPU machine
# that should run models on its CPU). Where the CUDA parts come from, in order:
#   1. the torch of LIBERO_TORCH_PYTHON (default python3), when it is 2.11.0 with CUDA: reused
#      (nothing downloaded; the GPU machines of this project have one);
#   2. else the PyPI torch 2.11.0 wheel (the one libtorch.sh takes its CPU libraries from) and the
#      CUDA wheels its METADATA requires on Linux, at the versions it pins: torch/lib's CUDA
#      libraries and the wheels' nvidia/ trees unpacked into DEST (DEST/torch/lib beside
#      DEST/nvidia), cached with a stamp (~2.7 GB downloaded, ~3.5 GB unpacked).
# Idempotent. Usage: libtorch_cuda.sh DEST LINK
set -euo pipefail
DEST="${1:?usage: libtorch_cuda.sh DEST LINK}"
LINK="${2:?usage: libtorch_cuda.sh DEST LINK}"
TORCH_VERSION=2.11.0

case "${LIBERO_SETUP_CUDA:-}" in
  1) gpu="LIBERO_SETUP_CUDA=1" ;;
  0) echo "  skipped: LIBERO_SETUP_CUDA=0"; exit 0 ;;
  "")
    if [ -e /proc/driver/nvidia/version ]; then
      # `NVRM version: NVIDIA UNIX [Open Kernel Module for] x86_64 ... 580.159.04 ...`: the first dotted number
      gpu="NVIDIA driver $(head -1 /proc/driver/nvidia/version | grep -o '[0-9]\+\.[0-9.]\+' | head -1)"
    elif command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L 2>/dev/null | grep -q '^GPU '; then
      gpu="$(nvidia-smi -L | head -1)"
    else
      echo "  no NVIDIA GPU here (no /proc/driver/nvidia/version, nvidia-smi lists none): the CPU libraries are all it uses"
      exit 0
    fi ;;
  *) echo "libtorch_cuda.sh: LIBERO_SETUP_CUDA must be 1 or 0, not '$LIBERO_SETUP_CUDA'" >&2; exit 2 ;;
esac
echo "  GPU: $gpu"
# absolute: the unpacking below runs in DEST
LINK="$(cd "$(dirname "$LINK")" && pwd)/$(basename "$LINK")"

# 1. A torch 2.11.0 with CUDA this machine's Python already has.
PY="${LIBERO_TORCH_PYTHON:-python3}"
PROBE='
import os
try:
    import torch
except Exception as e:
    print(f"none\tno torch ({type(e).__name__})\t")
    raise SystemExit
lib = os.path.join(os.path.dirname(torch.__file__), "lib")
ok = torch.__version__.startswith("2.11.0") and torch.version.cuda and os.path.exists(os.path.join(lib, "libtorch_cuda.so"))
verdict = "reuse" if ok else "other"
print(f"{verdict}\ttorch {torch.__version__} (CUDA {torch.version.cuda})\t{lib}")
'
found=$("$PY" -c "$PROBE" 2>/dev/null || true)
IFS=$'\t' read -r verdict what lib <<< "${found:-none	no Python called $PY	}"
if [ "$verdict" = reuse ]; then
  ln -sfn "$lib" "$LINK"
  echo "  reusing $PY's $what: $LINK -> $lib"
  exit 0
fi
echo "  $PY has $what, not a torch $TORCH_VERSION with CUDA: fetching the CUDA libraries"

# 2. The wheels, unpacked in the site-packages layout.
mkdir -p "$DEST" && DEST="$(cd "$DEST" && pwd)"
if [ ! -f "$DEST/.complete-$TORCH_VERSION" ]; then
  rm -rf "$DEST"; mkdir -p "$DEST/whl"
  # pip takes --platform tags literally (no older glibc implied): the tags these wheels carry
  platforms=()
  for tag in manylinux_2_28 manylinux_2_27 manylinux_2_26 manylinux_2_25 manylinux_2_24 manylinux_2_18 manylinux_2_17 \
    manylinux_2_12 manylinux_2_5 manylinux2014 manylinux2010 manylinux1; do
    platforms+=(--platform "${tag}_x86_64")
  done
  platforms+=(--platform any)
  pip_download() { python3 -m pip download -q --only-binary=:all: --python-version 3.11 "${platforms[@]}" -d "$DEST/whl" "$@"; }
  pip_download --no-deps "torch==$TORCH_VERSION"
  whl=$(ls "$DEST"/whl/torch-"$TORCH_VERSION"-*.whl)
  # `Requires-Dist: nvidia-cudnn-cu13==9.19.0.56; platform_system == "Linux"`, and the cuda-toolkit
  # meta-package with the extras torch names (it pins the nvidia-* wheels); not triton or
  # cuda-bindings (Python only).
  mapfile -t reqs < <(unzip -p "$whl" "torch-$TORCH_VERSION.dist-info/METADATA" |
    sed -n 's/^Requires-Dist: \(\(nvidia-\|cuda-toolkit\)[^;]*\); platform_system == "Linux".*/\1/p' | tr -d ' ')
  if [ "${#reqs[@]}" = 0 ]; then
    echo "torch $TORCH_VERSION's METADATA names no nvidia-* requirement: has the wheel's layout changed?" >&2; exit 1
  fi
  echo "  CUDA wheels: ${reqs[*]}"
  pip_download "${reqs[@]}"
  (
    cd "$DEST"
    unzip -q -o "$whl" 'torch/lib/*cuda*' torch/lib/libtorch_nvshmem.so torch/lib/libcaffe2_nvrtc.so torch/version.py
    for w in whl/nvidia_*.whl; do
      unzip -q -o "$w" 'nvidia/*' -x '*/include/*'
    done
    grep -q "__version__ = '$TORCH_VERSION" torch/version.py
    # the folders libtorch_cuda.so's RPATH names
    for d in nvidia/cu13/lib nvidia/cudnn/lib nvidia/nccl/lib nvidia/cusparselt/lib nvidia/nvshmem/lib; do
      [ -d "$d" ] || { echo "libtorch_cuda.sh: $DEST/$d is missing after unpacking the wheels" >&2; exit 1; }
    done
  )
  rm -rf "$DEST/whl"
  touch "$DEST/.complete-$TORCH_VERSION"
fi
ln -sfn "$DEST/torch/lib" "$LINK"
echo "  $LINK -> $DEST/torch/lib"
