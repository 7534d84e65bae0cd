#!/usr/bin/env bash
# One-command set-up on a fresh machine (Debian 12 image + package registries), idempotent and fast
# when already done:
#   1. Debian packages (EGL/Mesa for headless rendering, ffmpeg, a font, Chromium for the report's
#      browser test) when run as root;
#   2. MuJoCo 3.3.7 library + headers from the PyPI wheel (third_party/, for mujoco-rs 2.3.5);
#   2b. libtorch 2.11.0 (for tch 0.24.0) from the PyPI torch wheel, cached, linked as third_party/libtorch;
#   3. the Python reference LIBERO env (the oracle) in a cached venv, linked as .venv, and the notebook's
#      small venv (polars, matplotlib, jupytext), linked as .nb-venv;
#   4. the task bundles of the four suites, cached and linked as data/bundles;
#   5. `cargo build --release` of the workspace, and the main job on a small default (random, lift and the
#      scripted expert side by side on 20 real episodes each) and the smoke pictures.
# Caches live in $LIBERO_EVAL_CACHE (default ~/.cache/libero-eval), keyed by the scripts that make them.
# Options: --suites LIST (default: the four canonical suites; e.g. add libero_90), --no-build.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")" && pwd)"
cd "$ROOT"
CACHE="${LIBERO_EVAL_CACHE:-$HOME/.cache/libero-eval}"
SUITES="libero_spatial,libero_object,libero_goal,libero_10"
BUILD=1
while [ $# -gt 0 ]; do
  case "$1" in
    --suites) SUITES="$2"; shift 2 ;;
    --no-build) BUILD=0; shift ;;
    *) echo "setup.sh: unknown option $1 (options: --suites LIST, --no-build)" >&2; exit 2 ;;
  esac
done
t0=$(date +%s)
step() { echo "==> $* ($(( $(date +%s) - t0 )) s)"; }

step "Debian packages"
PKGS="libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libgles2 libosmesa6 ffmpeg fonts-dejavu-core unzip chromium"
if ! dpkg -s $PKGS >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $PKGS >/dev/null
  else
    echo "missing Debian packages; as root run: apt-get install $PKGS" >&2; exit 1
  fi
fi

step "MuJoCo 3.3.7"
bash scripts/setup/mujoco.sh third_party/mujoco-3.3.7

step "libtorch 2.11.0 for tch 0.24.0 (CPU libraries + headers from the PyPI wheel)"
bash scripts/setup/libtorch.sh "$CACHE/libtorch-2.11.0"
ln -sfn "$CACHE/libtorch-2.11.0/torch" third_party/libtorch

# The release build needs only MuJoCo and libtorch: it runs in the background while the
# (single-threaded) reference data is made, which saves ~10 min on a fresh 2-core machine.
if [ "$BUILD" = 1 ]; then
  step "cargo build --release (in the background; log: $CACHE/setup-build.log)"
  mkdir -p "$CACHE"
  rm -f "$CACHE/setup-build.rc"
  ( set +e; cargo build --release --quiet > "$CACHE/setup-build.log" 2>&1; echo $? > "$CACHE/setup-build.rc" ) &
  BUILD_PID=$!
  trap 'pkill -P $BUILD_PID 2>/dev/null; kill $BUILD_PID 2>/dev/null || true' EXIT
fi

step "reference venv (hf-libero 0.1.4, robosuite 1.4.0, mujoco 3.3.7)"
VENV_KEY=$(cat scripts/setup/reference_venv.sh | sha256sum | cut -c1-12)
VENV="$CACHE/ref-venv-$VENV_KEY"
bash scripts/setup/reference_venv.sh "$VENV"
ln -sfn "$VENV" .venv

# A test-only venv: made by scripts/setup/SCRIPT, cached as $CACHE/PREFIX-<hash of the script>,
# linked at LINK in the repository.
test_venv() {
  local script="scripts/setup/$1" dir
  dir="$CACHE/$2-$(sha256sum "scripts/setup/$1" | cut -c1-12)"
  bash "$script" "$dir"
  ln -sfn "$dir" "$3"
}

step "notebook venv (polars, pyarrow, matplotlib, jupytext, nbclient, ipykernel)"
test_venv notebook_venv.sh nb-venv .nb-venv

step "remote-policy venv (openpi-client, websockets: the toy openpi server of the remote-policy test)"
test_venv remote_policy_venv.sh remote-venv .remote-venv

step "OpenVLA reference venv (torch 2.11.0, transformers 4.40.1, timm 0.9.16: the tiny model of the OpenVLA parity test)"
test_venv openvla_ref_venv.sh openvla-venv .openvla-venv

step "S3 server venv (moto's S3 server, boto3: the s3:// run location test)"
test_venv s3_server_venv.sh s3-venv .s3-venv

step "task bundles ($SUITES)"
BUNDLE_KEY=$(cat scripts/setup/reference_venv.sh scripts/reference/build_bundles.py scripts/reference/libero_ref.py | sha256sum | cut -c1-12)
BUNDLES="$CACHE/bundles-$BUNDLE_KEY"
mkdir -p "$BUNDLES"
missing=""
for s in ${SUITES//,/ }; do
  [ -f "$BUNDLES/.complete-$s" ] || missing="${missing:+$missing,}$s"
done
if [ -n "$missing" ]; then
  (cd scripts/reference && "$VENV/bin/python" build_bundles.py "$BUNDLES" --suites "$missing" \
      2> >(grep -v "WARNING\|^\[info\]" >&2))
  for s in ${missing//,/ }; do touch "$BUNDLES/.complete-$s"; done
fi
mkdir -p data
ln -sfn "$BUNDLES" data/bundles

step "golden reference trajectories for the parity tests"
GOLDEN_KEY=$(cat scripts/setup/reference_venv.sh scripts/reference/build_bundles.py scripts/reference/libero_ref.py scripts/reference/golden.py | sha256sum | cut -c1-12)
GOLDEN="$CACHE/golden-$GOLDEN_KEY"
missing=""
for s in ${SUITES//,/ }; do
  case "$s" in libero_spatial|libero_object|libero_goal|libero_10) ;; *) continue ;; esac
  [ -f "$GOLDEN/.complete-$s" ] || missing="${missing:+$missing,}$s"
done
if [ -n "$missing" ]; then
  mkdir -p "$GOLDEN"
  (cd scripts/reference && "$VENV/bin/python" golden.py "$GOLDEN" --suites "$missing" 2> >(grep -v "WARNING\|^\[info\]" >&2) >/dev/null)
  for s in ${missing//,/ }; do touch "$GOLDEN/.complete-$s"; done
fi
ln -sfn "$GOLDEN" data/golden

step "reference camera frames for the render-parity tests (MuJoCo 3.3.7, and 3.2.3 for the published look)"
VENV323_KEY=$(cat scripts/setup/reference_venv.sh scripts/setup/reference_venv_mujoco323.sh | sha256sum | cut -c1-12)
VENV323="$CACHE/ref-venv-mujoco323-$VENV323_KEY"
bash scripts/setup/reference_venv_mujoco323.sh "$VENV323" "$VENV"
FRAMES_KEY=$(cat scripts/setup/reference_venv.sh scripts/setup/reference_venv_mujoco323.sh scripts/reference/build_bundles.py \
  scripts/reference/libero_ref.py scripts/reference/golden.py scripts/reference/frames.py | sha256sum | cut -c1-12)
FRAMES="$CACHE/frames-$FRAMES_KEY"
if [ ! -f "$FRAMES/.complete" ]; then
  rm -rf "$FRAMES"
  (cd scripts/reference &&
    "$VENV/bin/python" frames.py "$FRAMES/mujoco-3.3.7" --tasks 0 --inits 0,1,2 --steps 0,40 --golden "$GOLDEN" >/dev/null \
      2> >(grep -v "WARNING\|^\[info\]" >&2) &&
    "$VENV323/bin/python" frames.py "$FRAMES/mujoco-3.2.3" --tasks all --inits 0 --steps 0 >/dev/null \
      2> >(grep -v "WARNING\|^\[info\]" >&2))
  touch "$FRAMES/.complete"
fi
ln -sfn "$FRAMES" data/frames

if [ "$BUILD" = 1 ]; then
  step "waiting for cargo build --release"
  wait "$BUILD_PID" || true
  trap - EXIT
  if [ "$(cat "$CACHE/setup-build.rc" 2>/dev/null)" != 0 ]; then
    cat "$CACHE/setup-build.log" >&2
    echo "cargo build --release failed (log above, also in $CACHE/setup-build.log)" >&2
    exit 1
  fi
  step "main job, small default: random, lift and the expert on libero_spatial + libero_object, 1 trial per task"
  rm -rf outputs/smoke
  P="${CARGO_TARGET_DIR:-target}/release/pipeline"
  "$P" specs --suites libero_spatial,libero_object --trials 1 -o outputs/smoke/specs.parquet
  for policy in random lift expert; do
    "$P" run outputs/smoke/specs.parquet --out "outputs/smoke/$policy" --policy "$policy" >/dev/null
  done
  # One table, the three policies side by side: the baselines must fail (<= 5%), the expert succeed.
  "$P" results --run outputs/smoke/random --run outputs/smoke/lift --run outputs/smoke/expert --out outputs/smoke
  step "smoke pictures: outputs/smoke/<suite>.png (agentview | eye-in-hand, task 0, init 0)"
  "$P" smoke --out outputs/smoke
  step "report: outputs/report.html (the expert's failures as videos, the baselines beside it)"
  "$P" report --run outputs/smoke/expert --run outputs/smoke/random --run outputs/smoke/lift --videos --out outputs >/dev/null
fi
step "set-up done: bundles in data/bundles -> $BUNDLES"
