#!/usr/bin/env bash
# On the GPU machine, from the repository root: the set-up's step for the CUDA libraries
# (scripts/setup/libtorch_cuda.sh: the GPU found, python3's torch 2.11.0 reused), its link made
# where this binary looks (third_party/libtorch-cuda of the checkout it was built in, /work/main),
# then `pipeline doctor` and the tiny OpenVLA with no variable set at all.
# usage: device_setup.sh CARRY OUT   (CARRY made by make_carry.sh on the build machine)
LOG=device_setup.log . "$(dirname "$0")/prelude.sh"
echo; echo "=== 7. scripts/setup/libtorch_cuda.sh (as ./setup.sh calls it), linked in the build's checkout"
mkdir -p /work/main/third_party
(cd "$REPO" && bash scripts/setup/libtorch_cuda.sh /tmp/libero-eval/libtorch-cuda-2.11.0 /work/main/third_party/libtorch-cuda)
echo "rc=$?"; ls -la /work/main/third_party/
echo; echo "=== 8. pipeline doctor, no variable"
"$P" --bundles "$W/bundles" doctor; echo "rc=$?"
"$P" --bundles "$W/bundles" doctor --json > "$OUT/doctor_setup.json"
echo; echo "=== 9. the tiny OpenVLA, no variable"
P_RUN after-setup
echo; echo "=== 10. devices=cuda:7 on this one-GPU machine"
POLICY_OPTS="&devices=cuda:7" P_RUN cuda7
