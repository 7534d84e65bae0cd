#!/usr/bin/env bash
# The Python reference of the in-process OpenVLA test (policies/tests/openvla_parity.rs): it runs
# scripts/reference/openvla_tiny.py, which builds a tiny random-weight model of OpenVLA's Prismatic
# architecture with the layer types the real checkpoint uses (timm ViTs for the DINOv2 + SigLIP
# featurizers, transformers' LlamaForCausalLM), saves it in the Hugging Face checkpoint layout, and
# writes the reference logits, tokens and action the Rust port must reproduce.
# Versions: the ones openvla's modeling_prismatic.py accepts (timm 0.9.16 is one of its allowed
# versions; transformers 4.40.1 / tokenizers 0.19.1 are the versions it was written against) and
# torch 2.11.0, the libtorch version tch links. download.pytorch.org's CPU index is used when it is
# reachable, else PyPI's (CUDA) wheel with its dependencies (several GB; CPU is all the test uses).
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: openvla_ref_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/openvla_ref_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
PIP=("$VENV/bin/pip" install -q --disable-pip-version-check)
# torchvision is pinned to the release built for torch 2.11.0 and installed with it: timm pulls in
# torchvision, and an unpinned one (0.27.1) replaced torch with 2.12.1, silently.
if curl -sfI --max-time 10 https://download.pytorch.org/whl/cpu/torch/ >/dev/null 2>&1; then
  "${PIP[@]}" torch==2.11.0 torchvision==0.26.0 --index-url https://download.pytorch.org/whl/cpu
else
  "${PIP[@]}" torch==2.11.0 torchvision==0.26.0
fi
"${PIP[@]}" torch==2.11.0 torchvision==0.26.0 transformers==4.40.1 tokenizers==0.19.1 timm==0.9.16 \
  safetensors==0.4.5 numpy==1.26.4 sentencepiece==0.2.0
"$VENV/bin/python" -c "
import torch, torchvision, timm, transformers, tokenizers, safetensors
torch.zeros(1)
assert torch.__version__.split('+')[0] == '2.11.0', f'torch {torch.__version__}, not 2.11.0: the reference must run the libtorch tch links'
assert torchvision.__version__.split('+')[0] == '0.26.0', torchvision.__version__
"
touch "$VENV/.complete-$KEY"
echo "openvla reference venv ready: $VENV"
