#!/usr/bin/env bash
# The ALOHA-sim oracle venv: the real gym-aloha env, used at set-up by scripts/reference/aloha_bundle.py to
# build the ALOHA bundle (data/aloha) and its reference episodes (the parity tests' data); never at run time.
#   gym-aloha 0.1.5 (the PyPI wheel, --no-deps: its METADATA also asks for imageio[ffmpeg], which only
#   its example uses) on dm-control 1.0.34 + mujoco 3.3.7 (the library the Rust side links, so parity
#   can be exact; 1.0.34 accepts mujoco >= 3.3.6 and PyPI has no 1.0.35) + numpy 1.26.4 (gym-aloha's
#   poetry.lock and openpi pin it; numpy 2 computes the gripper control in float32, ~1e-9 off:
#   aloha-sim.md §2) + gymnasium.
# Everything goes in with --no-deps: only what `import gym_aloha`, its env and EGL rendering import
# (dm_control.suite imports every domain: lxml, scipy; OpenGL for EGL; absl, dm_env), checked by the
# import at the end. Not needed there, so not installed: dm-control's mjcf/locomotion/viewer dependencies
# (dm-tree, labmaze, protobuf, pyparsing, requests, tqdm), mujoco's glfw and etils, gymnasium's cloudpickle.
# The wheel is kept in $VENV/wheels (checked by hash) for aloha_bundle.py to copy the assets from.
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: aloha_ref_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/aloha_ref_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
PIP=("$VENV/bin/pip" install -q --disable-pip-version-check --no-deps)
"${PIP[@]}" numpy==1.26.4 mujoco==3.3.7 dm-control==1.0.34 dm-env==1.6 absl-py==2.5.1 pyopengl==3.1.10 \
  lxml==6.1.3 scipy==1.17.1 gymnasium==1.4.0 farama-notifications==0.0.6 typing-extensions==4.16.0
WHEEL=gym_aloha-0.1.5-py3-none-any.whl
"$VENV/bin/pip" download -q --disable-pip-version-check --no-deps gym-aloha==0.1.5 -d "$VENV/wheels"
echo "1794dd9a1146268a9b56f4a4931bcba69ca27714c2ac9ac146e471801bf0c7b3  $VENV/wheels/$WHEEL" | sha256sum -c --quiet
"${PIP[@]}" "$VENV/wheels/$WHEEL"
# The env must construct (dm_control physics, gym-aloha's registration) on the pinned versions.
MUJOCO_GL=egl "$VENV/bin/python" -c "
import gymnasium, gym_aloha, mujoco, numpy, dm_control
from importlib.metadata import version
assert (mujoco.__version__, numpy.__version__, version('dm-control')) == ('3.3.7', '1.26.4', '1.0.34')
gymnasium.make('gym_aloha/AlohaInsertion-v0', obs_type='pixels_agent_pos').reset(seed=1000)"
touch "$VENV/.complete-$KEY"
echo "ALOHA-sim oracle venv ready: $VENV"
