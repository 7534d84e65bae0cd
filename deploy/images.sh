#!/usr/bin/env bash
# Builds the `pipeline` runtime images here, from the release binary this checkout built: the CPU
# image and, with --cuda, the CUDA one (libtorch's CUDA backend and the nvidia-* libraries added).
# Then, with --check, runs `pipeline doctor` and a one-episode run inside each image.
#
# What works on a machine without Docker or a registry (Debian 12, as root): buildah with chroot
# isolation (no daemon, no runtime), from a Debian base made here by debootstrap and tagged
# localhost/debian:12 (no registry is reached). `apt-get install buildah debootstrap`.
#
#   deploy/images.sh [--cuda] [--check] [--tag NAME]     (default NAME: localhost/libero-pipeline)
#
# Images: NAME:cpu, NAME:cuda. To push them: `buildah push NAME:cpu docker://REGISTRY/libero-pipeline:TAG`
# (and :cuda); deploy/k8s/ names REGISTRY/libero-pipeline:TAG. A machine with network and Docker can
# build the same runtime, binary included, with deploy/Dockerfile.
#
# The binary: $LIBERO_PIPELINE_BIN, else ${CARGO_TARGET_DIR:-target}/release/pipeline (./setup.sh
# builds it). The libraries: third_party/ as ./setup.sh placed them; for --cuda,
# third_party/libtorch-cuda (a GPU machine's set-up), else libtorch 2.11.0's CUDA wheels fetched by
# scripts/setup/libtorch_cuda.sh into the cache (~2.7 GB, once).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"
CACHE="${LIBERO_EVAL_CACHE:-$HOME/.cache/libero-eval}"
NAME=localhost/libero-pipeline
CUDA=0
CHECK=0
while [ $# -gt 0 ]; do
  case "$1" in
    --cuda) CUDA=1; shift ;;
    --check) CHECK=1; shift ;;
    --tag) NAME="$2"; shift 2 ;;
    *) echo "images.sh: unknown option $1 (options: --cuda, --check, --tag NAME)" >&2; exit 2 ;;
  esac
done
t0=$(date +%s)
step() { echo "==> $* ($(( $(date +%s) - t0 )) s)"; }
for tool in buildah debootstrap strip; do
  command -v "$tool" >/dev/null || { echo "images.sh needs $tool: apt-get install buildah debootstrap binutils" >&2; exit 1; }
done
[ "$(id -u)" = 0 ] || { echo "images.sh: run as root (buildah's chroot isolation and debootstrap need it)" >&2; exit 1; }
BIN="${LIBERO_PIPELINE_BIN:-${CARGO_TARGET_DIR:-$ROOT/target}/release/pipeline}"
[ -x "$BIN" ] || { echo "no pipeline binary at $BIN: run ./setup.sh (or set LIBERO_PIPELINE_BIN)" >&2; exit 1; }
for lib in third_party/mujoco-3.3.7/lib/libmujoco.so.3.3.7 third_party/libtorch/lib/libtorch_cpu.so; do
  [ -f "$lib" ] || { echo "no $lib: run ./setup.sh" >&2; exit 1; }
done
# buildah's own storage, kept apart from any other container storage on the machine.
export BUILDAH_ISOLATION=chroot
STORAGE=(--root "$CACHE/buildah/storage" --runroot "$CACHE/buildah/run" --storage-driver vfs)
bh() { buildah "${STORAGE[@]}" "$@"; }

BASE=localhost/debian:12
if ! bh inspect --type image "$BASE" >/dev/null 2>&1; then
  step "base image $BASE from debootstrap --variant=minbase bookworm"
  rootfs=$(mktemp -d)
  debootstrap --variant=minbase bookworm "$rootfs" http://deb.debian.org/debian >/dev/null
  ctr=$(bh from scratch)
  mnt=$(bh mount "$ctr")
  cp -a "$rootfs"/. "$mnt"/
  bh umount "$ctr" >/dev/null
  bh commit --quiet --rm "$ctr" "$BASE" >/dev/null
  rm -rf "$rootfs"
fi

# Stage a build context: the stripped binary and the libraries at the image's paths.
stage() {
  local ctx="$1" variant="$2"
  mkdir -p "$ctx/bin" "$ctx/opt/libtorch-2.11.0/torch/lib" "$ctx/opt/mujoco-3.3.7/lib"
  strip --strip-debug -o "$ctx/bin/pipeline" "$BIN"
  cp -L third_party/mujoco-3.3.7/lib/libmujoco.so.3.3.7 "$ctx/opt/mujoco-3.3.7/lib/"
  cp -L third_party/libtorch/lib/*.so* "$ctx/opt/libtorch-2.11.0/torch/lib/"
  # version.py beside lib/: how `pipeline doctor` tells which torch the libraries are
  cp -L third_party/libtorch/version.py "$ctx/opt/libtorch-2.11.0/torch/"
  if [ "$variant" = cuda ]; then
    local link="third_party/libtorch-cuda"
    if [ ! -e "$link/libtorch_cuda.so" ]; then
      link="$CACHE/images-libtorch-cuda-link"
      LIBERO_SETUP_CUDA=1 bash scripts/setup/libtorch_cuda.sh "$CACHE/libtorch-cuda-2.11.0" "$link"
    fi
    local lib; lib=$(readlink -f "$link")
    # torch/lib's CUDA libraries beside the CPU ones (the loader looks beside libtorch_cpu.so), and
    # the nvidia/ tree where their RUNPATH looks ($ORIGIN/../../nvidia).
    cp -Ln "$lib"/*.so* "$ctx/opt/libtorch-2.11.0/torch/lib/" 2>/dev/null || true
    [ -f "$ctx/opt/libtorch-2.11.0/torch/lib/libtorch_cuda.so" ] || { echo "no libtorch_cuda.so in $lib" >&2; exit 1; }
    cp -rL "$lib/../../nvidia" "$ctx/opt/libtorch-2.11.0/nvidia"
  fi
}

VARIANTS=cpu
[ "$CUDA" = 1 ] && VARIANTS="cpu cuda"
for variant in $VARIANTS; do
  step "$NAME:$variant: staging the binary and libraries"
  ctx=$(mktemp -d)
  stage "$ctx" "$variant"
  echo "  context: $(du -sh "$ctx" | cut -f1)"
  step "$NAME:$variant: buildah bud (deploy/Containerfile, FROM $BASE)"
  bh bud --quiet --isolation chroot --layers=false -f "$ROOT/deploy/Containerfile" --build-arg BASE="$BASE" \
    -t "$NAME:$variant" "$ctx" >/dev/null
  rm -rf "$ctx"
  echo "  $(bh images --format '{{.Name}}:{{.Tag}} {{.Size}}' "$NAME:$variant")"
done

if [ "$CHECK" = 1 ]; then
  BUNDLES=$(readlink -f data/bundles)
  for variant in $VARIANTS; do
    out=$(mktemp -d); chmod 777 "$out"
    ctr=$(bh from --quiet "$NAME:$variant")
    run() { bh run --isolation chroot -v "$BUNDLES:/bundles:ro" -v "$out:/out" "$ctr" -- "$@"; }
    step "$NAME:$variant: pipeline doctor inside the image"
    run pipeline doctor   # a FAIL fails the check; a CPU machine's missing GPU is no FAIL
    step "$NAME:$variant: one episode inside the image (libero_spatial task 0, random, 20 steps)"
    run pipeline specs --suites libero_spatial --tasks 0 --trials 1 -o /out/specs.parquet
    run pipeline run /out/specs.parquet --out /out/run --policy random --max-steps 20 >/dev/null
    run pipeline results --run /out/run
    bh rm "$ctr" >/dev/null
    rm -rf "$out"
  done
fi
step "done"
