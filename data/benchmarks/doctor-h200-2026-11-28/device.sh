#!/usr/bin/env bash
# On the GPU machine, from the repository root: `pipeline doctor` and a tiny OpenVLA run, first with
# the set-up's CPU libraries alone (what a GPU user had before issue 44: no libtorch_cuda.so), then
# with LIBERO_TORCH_CUDA_LIB pointing at the machine's torch 2.11.0 (no LD_PRELOAD anywhere).
# usage: device.sh CARRY OUT   (CARRY made by make_carry.sh on the build machine)
. "$(dirname "$0")/prelude.sh"
echo; echo "=== 1. pipeline doctor, the set-up's CPU libraries only"
"$P" --bundles "$W/bundles" doctor; echo "rc=$?"
echo; echo "=== 2. the tiny OpenVLA without the CUDA backend: refused before any episode"
P_RUN no-backend
echo; echo "=== 3. the same with devices=cpu: runs on the CPU on purpose"
POLICY_OPTS="&devices=cpu" P_RUN on-cpu
echo; echo "=== 4. pipeline doctor with LIBERO_TORCH_CUDA_LIB=$TL"
LIBERO_TORCH_CUDA_LIB=$TL "$P" --bundles "$W/bundles" doctor; echo "rc=$?"
LIBERO_TORCH_CUDA_LIB=$TL "$P" --bundles "$W/bundles" doctor --json > "$OUT/doctor.json"
echo; echo "=== 5. the tiny OpenVLA with LIBERO_TORCH_CUDA_LIB=$TL"
P_RUN with-backend LIBERO_TORCH_CUDA_LIB="$TL"
echo; echo "=== 6. devices=cuda:7 on this one-GPU machine"
POLICY_OPTS="&devices=cuda:7" P_RUN cuda7 LIBERO_TORCH_CUDA_LIB="$TL"
