#!/usr/bin/env bash
# Whether a process's GL contexts bound its renders: on a GPU machine, `pipeline bench render` with N
# threads of one process (N contexts, as a run's N workers have) against N processes of one thread
# each, for each N; every context on the GPU that MUJOCO_EGL_DEVICE_ID names (default 0). A run's
# renders took ~45 frames/s in all on two H100s wherever its contexts sat, while 16 processes got
# ~330 pairs/s from one GPU (data/benchmarks/gpu-two-h100-end-to-end-2026-11-27). Measured on an H100:
# N contexts of one process 30-50 pairs/s in all from N = 4 on, N processes ~400-500
# (data/benchmarks/gpu-render-threads-2026-11-27). The threads get a GL thread each
# (LIBERO_GL_THREADS=per-worker, unless set otherwise: on a GPU the default is one shared GL thread,
# libero_sim::gl_thread).
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_render_processes.sh CARRY OUT [N ...]
#   CARRY: scripts/bench/gpu_carry.sh's folder; OUT: where the figures go; N: default 1 4 16 32.
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); shift 2
counts=("${@:-1 4 16 32}")
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-render; mkdir -p "$work"
. scripts/bench/gpu_setup.sh
export MUJOCO_EGL_DEVICE_ID=${MUJOCO_EGL_DEVICE_ID:-0}
export LIBERO_GL_THREADS=${LIBERO_GL_THREADS:-per-worker}
render=("$P" --bundles "$work/bundles" bench render --suites libero_spatial --python none --frames 50)
for n in ${counts[*]}; do
  echo "::: $n threads of one process" | tee -a "$out/render.txt"
  "${render[@]}" --threads "$n" 2>&1 | tail -1 | tee -a "$out/render.txt"
  echo "::: $n processes of one thread (ms per pair, sorted)" | tee -a "$out/render.txt"
  for i in $(seq "$n"); do "${render[@]}" > "$work/p$i.txt" 2>&1 & done; wait
  cat "$work"/p*.txt | grep '^libero_spatial' | awk '{print $NF}' | sort -n | tr '\n' ' ' | tee -a "$out/render.txt"
  echo | tee -a "$out/render.txt"; rm -f "$work"/p*.txt
done
