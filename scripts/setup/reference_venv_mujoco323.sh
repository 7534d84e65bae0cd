#!/usr/bin/env bash
# The published stack's MuJoCo (3.2.3) beside the reference venv, for one job only: rendering the
# frames that define "the published look" (scripts/reference/frames.py). Physics parity stays on the
# main reference venv (3.3.7, the library the Rust side links).
#
# The venv holds mujoco==3.2.3 alone and reaches everything else (robosuite, hf-libero, numpy...)
# through a .pth file pointing at the main venv's site-packages; its own site-packages come first
# on sys.path, so `import mujoco` is 3.2.3. Idempotent (stamp keyed by this file's hash).
set -euo pipefail
VENV="${1:?usage: reference_venv_mujoco323.sh VENV_DIR MAIN_REFERENCE_VENV}"
MAIN="$(cd "${2:?usage: reference_venv_mujoco323.sh VENV_DIR MAIN_REFERENCE_VENV}" && pwd)"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(cat "$HERE/reference_venv_mujoco323.sh" "$HERE/reference_venv.sh" | sha256sum | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
"$VENV/bin/pip" install -q --disable-pip-version-check --no-deps mujoco==3.2.3
SP=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
MAIN_SP=$("$MAIN/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
echo "$MAIN_SP" > "$SP/reference_venv.pth"
# libero_ref.py finds the LIBERO config and the torch stand-in under sys.prefix.
ln -sfn "$MAIN/libero_config" "$VENV/libero_config"
ln -sfn "$MAIN/shims" "$VENV/shims"
"$VENV/bin/python" -c 'import mujoco, robosuite; assert mujoco.__version__ == "3.2.3", mujoco.__version__' 2>/dev/null
touch "$VENV/.complete-$KEY"
echo "reference venv with mujoco 3.2.3 ready: $VENV"
