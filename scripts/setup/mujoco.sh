#!/usr/bin/env bash
# MuJoCo 3.3.7 shared library + headers from the PyPI wheel, for mujoco-rs 2.3.5+mj-3.3.7.
# Idempotent: does nothing when the pinned library is already in place.
set -euo pipefail
MJ_VER=3.3.7
DEST="${1:?usage: mujoco.sh DEST}"
DEST="$(mkdir -p "$DEST" && cd "$DEST" && pwd)"
WHEEL_SHA256=9371506f0df2d82152685fc8d38465843abcea8d371745ea7c125001e8f3f2d8
LIB="$DEST/lib/libmujoco.so.$MJ_VER"
if [ -f "$DEST/.complete" ] && [ -f "$LIB" ]; then exit 0; fi
tmp="$(mktemp -d)"; trap 'rm -rf "$tmp"' EXIT
python3 -m pip download -q --no-deps --only-binary=:all: \
    --python-version 3.11 --platform manylinux_2_28_x86_64 "mujoco==$MJ_VER" -d "$tmp"
whl=$(ls "$tmp"/mujoco-$MJ_VER-*.whl)
echo "$WHEEL_SHA256  $whl" | sha256sum -c --quiet || { echo "mujoco wheel checksum mismatch" >&2; exit 1; }
mkdir -p "$DEST/lib" "$DEST/include/mujoco"
unzip -q -j -o "$whl" "mujoco/libmujoco.so.$MJ_VER" -d "$DEST/lib"
unzip -q -j -o "$whl" 'mujoco/include/mujoco/*.h' -x 'mujoco/include/mujoco/*/*' -d "$DEST/include/mujoco"
ln -sf "libmujoco.so.$MJ_VER" "$DEST/lib/libmujoco.so"
touch "$DEST/.complete"
echo "MuJoCo $MJ_VER -> $DEST"
