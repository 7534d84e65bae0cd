#!/usr/bin/env bash
# The lerobot 0.6.1 venv of the Python-policy tests (tests/python_policy.rs): lerobot's own classes
# build tiny random-weight checkpoints (SmolVLA with a tiny local SmolVLM, ACT) and the Python host
# runs them through `lerobot:` exactly as lerobot-eval feeds them; the same venv serves a user's
# lerobot checkpoints (`lerobot:<dir>?python=.lerobot-venv/bin/python`).
# lerobot 0.6.1 needs Python >= 3.12 (Debian 12's python3 is 3.11): the first of python3.12,
# pyenv's 3.12, python3.13, pyenv's 3.13 that runs (3.12 first: the GPU machine's, and the one
# lerobot was probed on). torch is 2.11.0, the libtorch tch links; PyPI's torch wheel brings its
# CUDA libraries (download.pytorch.org's CPU index is not reachable everywhere), and pip's cache
# shares them with the OpenVLA reference venv.
# The `dataset` extra (datasets, pandas, pyarrow, PyAV, torchcodec) lets the export tests read a
# `pipeline export --format lerobot` dataset back with lerobot's own LeRobotDataset
# (tests/export.rs); datasets 4.8 needs fsspec <= 2026.2.0.
# Versions pinned to a fresh resolve of lerobot[pi,smolvla,dataset]==0.6.1 (2026-11-28).
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: lerobot_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/lerobot_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
PYTHON=""
for p in python3.12 "$HOME"/.pyenv/versions/3.12*/bin/python3 python3.13 "$HOME"/.pyenv/versions/3.13*/bin/python3 python3; do
  if "$p" -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null; then PYTHON="$p"; break; fi
done
if [ -z "$PYTHON" ]; then
  echo "lerobot 0.6.1 needs Python >= 3.12 and none was found (python3.12, python3.13, pyenv); install one (e.g. apt install python3.12-venv on Debian 13 / Ubuntu 24.04, or pyenv install 3.12)" >&2
  exit 1
fi
rm -rf "$VENV"
"$PYTHON" -m venv "$VENV"
"$VENV/bin/pip" install -q --disable-pip-version-check torch==2.11.0 torchvision==0.26.0 \
  'lerobot[pi,smolvla,dataset]==0.6.1' transformers==5.5.4 tokenizers==0.22.2 numpy==2.2.6 safetensors==0.8.0 \
  accelerate==1.15.0 huggingface_hub==1.33.0 datasets==4.8.5 pandas==2.3.3 pyarrow==26.0.1 av==15.1.0 \
  torchcodec==0.11.1 fsspec==2026.2.0
"$VENV/bin/python" -c "
import torch, lerobot, transformers
from importlib.metadata import version
assert torch.__version__.split('+')[0] == '2.11.0', torch.__version__
assert version('lerobot') == '0.6.1', version('lerobot')
from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.datasets.lerobot_dataset import LeRobotDataset
import av
"
touch "$VENV/.complete-$KEY"
echo "lerobot venv ready: $VENV ($("$VENV/bin/python" --version))"
