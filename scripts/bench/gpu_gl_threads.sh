#!/usr/bin/env bash
# Shared GL threads against a GL thread per worker on a GPU machine
# (libero_sim::gl_thread; data/benchmarks/gpu-render-threads-2026-11-27 has the first figures):
#   `render`: `pipeline bench render --threads N` through one shared GL thread (N = 4, 16, 64) and
#     with a GL thread each (N = 16), every thread's last camera pair checked bit for bit against a
#     context of its own (the bench fails on a difference);
#   `MODE:JOBS:BATCH:TRIALS` (MODE shared or per-worker): real episodes through `pipeline run`
#     (scripts/bench/gpu_end_to_end.sh: OpenVLA-7B random weights, libero_spatial, episodes capped
#     at MAX_STEPS = 60) with LIBERO_GL_THREADS=MODE.
# The runs are packed into OUT/runs.tgz (the device tool returns a few files, not a run's tree).
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_gl_threads.sh CARRY OUT [STEP ...]
#   CARRY: scripts/bench/gpu_carry.sh's folder; OUT: where the figures go;
#   STEP: `render` or MODE:JOBS:BATCH:TRIALS; default: render shared:64:64:6 per-worker:64:64:6.
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); shift 2
[ $# -gt 0 ] || set -- render shared:64:64:6 per-worker:64:64:6
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-gl-threads; mkdir -p "$work"
. scripts/bench/gpu_setup.sh
runs=$work/runs; rm -rf "$runs"
for step in "$@"; do
  if [ "$step" = render ]; then
    render=("$P" --bundles "$work/bundles" bench render --suites libero_spatial --python none --frames 40)
    for n in 4 16 64; do LIBERO_GL_THREADS=shared "${render[@]}" --threads "$n" 2>&1 | tail -2 | tee -a "$out/render.txt"; done
    LIBERO_GL_THREADS=per-worker "${render[@]}" --threads 16 2>&1 | tail -2 | tee -a "$out/render.txt"
    continue
  fi
  mode=${step%%:*}; run=${step#*:}
  LIBERO_GL_THREADS=$mode MAX_STEPS=${MAX_STEPS:-60} bash scripts/bench/gpu_end_to_end.sh "$carry" "$runs/$mode-${run//:/-}" "$run" \
    2>&1 | grep -A5 'where the time goes' | sed "s/^/$step: /" | tee -a "$out/runs.txt"
done
[ -d "$runs" ] && tar -czf "$out/runs.tgz" -C "$runs" .
true
