#!/usr/bin/env bash
# On the GPU machine: unpacks what scripts/bench/gpu_mesa_carry.sh made into STAGE, keeping only the
# libraries the machine lacks (its own serve the rest, so nothing it loads elsewhere is replaced),
# and says whether llvmpipe's driver then finds every library it needs.
# usage: scripts/bench/gpu_mesa_stage.sh CARRY [STAGE]   (STAGE default /tmp/mesa)
set -euo pipefail
carry=$(realpath "$1"); stage=${2:-/tmp/mesa}
mkdir -p "$stage"; xz -dc "$carry/mesa.tar.xz" | tar -xf - -C "$stage"
stage=$(realpath "$stage")
printf '{"file_format_version": "1.0.0", "ICD": {"library_path": "%s/lib/libEGL_mesa.so.0"}}\n' "$stage" > "$stage/50_mesa.json"
own=$(ldconfig -p | awk '{print $1}')  # read once: `ldconfig -p | grep -q` fails under pipefail
for f in "$stage"/lib/*; do
  n=$(basename "$f")
  case "$n" in libEGL_mesa*) continue ;; esac
  if grep -qxF "$n" <<< "$own"; then rm "$f"; echo "the machine's own: $n"; fi
done
missing=$(LD_LIBRARY_PATH="$stage/lib" ldd "$stage/dri/swrast_dri.so" "$stage/lib/libEGL_mesa.so.0" | grep 'not found' || true)
[ -z "$missing" ] || { echo "still missing: $missing" >&2; exit 1; }
echo "staged in $stage: $(ls "$stage/lib" | wc -l) libraries, $(du -sh "$stage" | cut -f1)"
