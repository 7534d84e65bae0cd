#!/usr/bin/env bash
# Does rendering on the model's GPU slow the model's forward? policies/benches/openvla.rs (MODEL,
# BATCHES as gpu_forward.sh takes them) three times in one call: alone; while `pipeline bench render`
# draws camera pairs on the same GPU through one shared GL thread (RENDER_THREADS workers, 256²,
# reference quality), as a run's renders do; and while every core spins (CPU contention alone, no GPU
# work), to tell the GPU's time-slicing between the GL and CUDA contexts from a busy host.
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_render_interference.sh CARRY OUT MODEL BATCHES
set -euo pipefail
carry=$1; out=$(realpath -m "$2"); model=$3; batches=$4
mkdir -p "$out"; work=${TMPDIR:-/tmp}/libero-gpu-e2e
scripts/bench/gpu_forward.sh "$carry" "$out/alone" "$model" "$batches" > "$out/alone.log" 2>&1
. scripts/bench/gpu_setup.sh > /dev/null
cp "$P" "$work/pipeline-render"  # gpu_forward.sh unpacks $P again while this one renders
LIBERO_GL_THREADS=shared "$work/pipeline-render" --bundles "$work/bundles" bench render --suites libero_spatial --python none \
  --frames "${RENDER_FRAMES:-4000}" --threads "${RENDER_THREADS:-8}" > "$out/render.log" 2>&1 &
render=$!
sleep 8
scripts/bench/gpu_forward.sh "$carry" "$out/rendering" "$model" "$batches" > "$out/rendering.log" 2>&1
kill $render 2>/dev/null || true; wait $render 2>/dev/null || true
for i in $(nproc --all | xargs seq); do timeout 90 sh -c 'while :; do :; done' & done
scripts/bench/gpu_forward.sh "$carry" "$out/cpu-busy" "$model" "$batches" > "$out/cpu-busy.log" 2>&1
pkill -f 'while :; do :; done' || true
for c in alone rendering cpu-busy; do echo "== $c"; grep -E "B= *[0-9]+:" "$out/$c.log"; done | tee "$out/summary.txt"
tail -5 "$out/render.log"
