# Sourced by device.sh and device_setup.sh on the GPU machine (CARRY in $1, OUT in $2): unpacks the
# carry into /tmp/doctor-work, sets up NVIDIA's EGL, and rebuilds the set-up's CPU libtorch folder
# from the machine's torch (no libtorch_cuda.so in it); sets $P, $W, $TL, $REPO (the repository root) and P_RUN.
set -u
REPO=$PWD; C=$(realpath "$1"); OUT=$(realpath -m "$2"); W=/tmp/doctor-work; mkdir -p "$W" "$OUT"
exec > >(tee "$OUT/${LOG:-device.log}") 2>&1
# NVIDIA's EGL through glvnd (the machine has the vendor library, not always the dispatcher)
ldconfig -p | grep -q libEGL.so.1 || { for f in "$C"/gl/*.deb; do dpkg -x "$f" /; done; ldconfig; }
V=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$V" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$V
xz -dc "$C/pipeline.xz" > "$W/pipeline"; chmod +x "$W/pipeline"; P=$W/pipeline
mkdir -p "$W/mujoco" "$W/bundles"; xz -dc "$C/libmujoco.so.3.3.7.xz" > "$W/mujoco/libmujoco.so.3.3.7"
xz -dc "$C/bundles.tar.xz" | tar -xf - -C "$W/bundles"; (cd "$W/bundles" && xargs -r mkdir -p < dirs.txt)
# The set-up's CPU folder (third_party/libtorch/lib: libtorch_cpu, libtorch, libc10, libgomp and
# the two CUDA runtime libraries), copied from the machine's torch: the same torch 2.11.0 wheel.
TL=$(python3 -c 'import os, torch; print(os.path.join(os.path.dirname(torch.__file__), "lib"))')
SP=$(dirname "$(dirname "$TL")")
mkdir -p "$W/libtorch/lib"
cp "$TL"/{libtorch_cpu.so,libtorch.so,libc10.so,libgomp.so.1} "$SP"/nvidia/cu13/lib/{libcudart.so.13,libcupti.so.13} "$W/libtorch/lib/"
cp "$TL/../version.py" "$W/libtorch/"
export LD_LIBRARY_PATH=$W/libtorch/lib:$W/mujoco
unset LD_PRELOAD LIBERO_TORCH_CUDA_LIB
echo "machine: $(nvidia-smi -L | head -2); python3's torch: $(python3 -c 'import torch; print(torch.__version__)') at $TL"
cd "$W"
"$P" --version
P_RUN() { # NAME ENV... : a tiny OpenVLA run of libero_spatial task 0, 1 episode, 3 policy steps
  local name=$1; shift
  env "$@" "$P" --bundles "$W/bundles" run "$W/specs.parquet" --out "$W/$name" --max-steps 3 \
    --policy "openvla:$C/openvla-tiny?unnorm=libero_spatial_no_noops${POLICY_OPTS:-}"
  echo "rc=$?"
  [ -f "$W/$name/manifest.json" ] && python3 -c 'import json, sys; i = json.load(open(sys.argv[1]))["policy_identity"]; print("manifest:", json.dumps({k: i.get(k) for k in ("dtype", "replicas", "attention")}))' "$W/$name/manifest.json"
}
"$P" --bundles "$W/bundles" specs --suites libero_spatial --tasks 0 --trials 1 -o "$W/specs.parquet"
