# Sourced by the GPU-machine scripts (gpu_end_to_end.sh, gpu_forward.sh, gpu_scaling.sh and the
# others of scripts/bench/gpu_*.sh): unpacks what
# scripts/bench/gpu_carry.sh made into $work, sets up NVIDIA's EGL and libtorch from the machine's
# torch, and writes OpenVLA-7B's random bf16 weights (with MODEL=oft, OFT-7B's heads too). Expects
# $carry and $work (and MESA, below, to render on the CPU); sets $P (the pipeline), $ckpt (the checkpoint: OpenVLA-7B's, or OFT-7B's with
# MODEL=oft) and, where the carry has it, $BENCH (policies/benches/openvla.rs).
# The machine needs python3 with torch 2.11 (libtorch for tch, and the random 7B weights) and the
# NVIDIA driver's EGL. Weights are random (none can be downloaded there).

# NVIDIA's EGL through glvnd (the machine has the vendor library, not always the dispatcher)
if [[ $(ldconfig -p) != *libEGL.so.1* ]]; then  # not `| grep -q`: under pipefail its early exit fails the test
  for f in "$carry"/gl/*.deb; do dpkg -x "$f" /; done; ldconfig
fi
[ -f /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json ] &&
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
# MESA=STAGE (staged by gpu_mesa_stage.sh): Mesa's llvmpipe beside the NVIDIA driver, as in the
# :cuda image; $SOFTWARE_EGL_DEVICE is then its EGL device index (MUJOCO_EGL_DEVICE_ID renders there)
unset SOFTWARE_EGL_DEVICE
if [ -n "${MESA:-}" ]; then
  [ -f "$MESA/50_mesa.json" ] || { echo "MESA=$MESA: nothing staged there (scripts/bench/gpu_mesa_stage.sh)" >&2; exit 1; }
  MESA=$(realpath "$MESA")
  if [ -z "${__EGL_VENDOR_LIBRARY_FILENAMES:-}" ]; then
    __EGL_VENDOR_LIBRARY_FILENAMES=$(ls /usr/share/glvnd/egl_vendor.d/*.json /etc/glvnd/egl_vendor.d/*.json 2>/dev/null | paste -sd: || true)
  fi
  case ":$__EGL_VENDOR_LIBRARY_FILENAMES:" in
    *":$MESA/50_mesa.json:"*) ;;
    *) __EGL_VENDOR_LIBRARY_FILENAMES="${__EGL_VENDOR_LIBRARY_FILENAMES:+$__EGL_VENDOR_LIBRARY_FILENAMES:}$MESA/50_mesa.json" ;;
  esac
  export __EGL_VENDOR_LIBRARY_FILENAMES LIBGL_DRIVERS_PATH="$MESA/dri"
fi

# the pipeline, the bench, libmujoco and the bundles
xz -dc "$carry/pipeline.xz" > "$work/pipeline"; chmod +x "$work/pipeline"
if [ -f "$carry/openvla-bench.xz" ]; then
  xz -dc "$carry/openvla-bench.xz" > "$work/openvla-bench"; chmod +x "$work/openvla-bench"; BENCH="$work/openvla-bench"
fi
mkdir -p "$work/lib"
if [ -f "$carry/libmujoco.so.3.3.7.xz" ]; then
  xz -dc "$carry/libmujoco.so.3.3.7.xz" > "$work/lib/libmujoco.so.3.3.7"
else
  cp "$carry"/lib/* "$work/lib/"  # a carry made before libmujoco travelled compressed
fi
mkdir -p "$work/bundles"; xz -dc "$carry/bundles.tar.xz" | tar -xf - -C "$work/bundles"
(cd "$work/bundles" && xargs -r mkdir -p < dirs.txt)

# libtorch from the machine's torch (the version tch was built against), CUDA's libraries beside it
torch_lib=$(python3 -c 'import os, torch; print(os.path.join(os.path.dirname(torch.__file__), "lib"))')
nv_libs=$(python3 -c 'import glob, os, torch; r = os.path.dirname(os.path.dirname(torch.__file__)); print(":".join(sorted(glob.glob(os.path.join(r, "nvidia", "*", "lib")) + glob.glob(os.path.join(r, "nvidia", "cu*", "lib")))))')
export LD_LIBRARY_PATH="$torch_lib:$nv_libs:$work/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}${MESA:+:$MESA/lib}"
# libtorch's CUDA backend: the binary loads it at start from here (no LD_PRELOAD); the folders on
# LD_LIBRARY_PATH serve the CPU libraries and NVRTC for our kernels
export LIBERO_TORCH_CUDA_LIB="$torch_lib"
P="$work/pipeline"
"$P" --version
if [ -n "${MESA:-}" ]; then
  # `pipeline doctor` lists EGL's devices: "devices [0: hardware, CUDA device 0, 1: software (Mesa llvmpipe)]"
  SOFTWARE_EGL_DEVICE=$("$P" --bundles "$work/bundles" doctor 2>&1 | sed -n 's/.*[[ ]\([0-9][0-9]*\): software (Mesa llvmpipe).*/\1/p' | head -1 || true)
  echo "Mesa's software EGL device: ${SOFTWARE_EGL_DEVICE:?not among the EGL devices pipeline doctor lists}"
fi

# OpenVLA-7B: the layout carried, the random bf16 weights written here (unless NO_OPENVLA is set:
# scripts/bench/gpu_python_host.sh brings its own model)
if [ -z "${NO_OPENVLA:-}" ]; then
  ckpt="$work/openvla-7b"; mkdir -p "$ckpt"; cp "$carry"/openvla-7b/* "$ckpt"/
  [ -f "$ckpt/model-00004-of-00004.safetensors" ] || python3 scripts/reference/fill_random_weights.py "$ckpt"
fi

# OFT-7B (MODEL=oft): OpenVLA-7B's random backbone with OFT's two heads drawn on it, in the released
# layout (scripts/reference/oft_from_openvla.py); $ckpt then names it
if [ "${MODEL:-openvla}" = oft ]; then
  [ -f "$work/oft-7b/action_head--150000_checkpoint.pt" ] || python3 scripts/reference/oft_from_openvla.py "$ckpt" "$work/oft-7b"
  ckpt="$work/oft-7b"
fi
