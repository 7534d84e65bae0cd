#!/usr/bin/env bash
# Mesa's llvmpipe (EGL) for a GPU machine that lacks it, made on the build machine: libEGL_mesa,
# swrast_dri.so and every library they load except glibc's and the C++ runtime's (the machine's own
# serve those), with glvnd's vendor file naming it at STAGE (where scripts/bench/gpu_mesa_stage.sh
# unpacks it on the GPU machine). It does not fit in one device call's carry beside the pipeline
# (about 45 MB with LLVM), so one call stages it and the next, on the still-warm machine, uses it
# (gpu_setup.sh with MESA=STAGE).
# usage: scripts/bench/gpu_mesa_carry.sh CARRY [STAGE]   (STAGE default /tmp/mesa)
set -euo pipefail
carry=$(realpath -m "$1"); stage=${2:-/tmp/mesa}
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
mkdir -p "$carry" "$tmp/lib" "$tmp/dri"
cache=$(ldconfig -p)  # read once: an awk that exits early would fail `ldconfig -p |` under pipefail
egl=$(awk '/libEGL_mesa.so.0 .*x86-64/ {print $NF; exit}' <<< "$cache")
dri=$(dirname "$(awk '/libglapi.so.0 .*x86-64/ {print $NF; exit}' <<< "$cache")")/dri/swrast_dri.so
[ -f "$dri" ] || dri=/usr/lib/x86_64-linux-gnu/dri/swrast_dri.so
cp -L "$egl" "$tmp/lib/"; cp -L "$dri" "$tmp/dri/"
ldd "$egl" "$dri" | awk '$2 == "=>" && $3 ~ /^\// {print $3}' | sort -u |
  grep -v -E '/(libc|libm|libpthread|libdl|librt|ld-linux-x86-64|libstdc\+\+|libgcc_s)\.so' |
  while read -r f; do cp -L "$f" "$tmp/lib/"; done
printf '{"file_format_version": "1.0.0", "ICD": {"library_path": "%s/lib/libEGL_mesa.so.0"}}\n' "$stage" > "$tmp/50_mesa.json"
tar -C "$tmp" -cf - lib dri 50_mesa.json | xz -T0 -9e > "$carry/mesa.tar.xz"
du -sh "$carry/mesa.tar.xz"
