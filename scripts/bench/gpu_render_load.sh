#!/usr/bin/env bash
# How busy do renders alone keep the GPU? `pipeline bench render` on the GPU (one shared GL thread,
# reference quality, libero_spatial camera pairs at 256²) with 1 and with RENDER_THREADS threads,
# nvidia-smi's utilization sampled beside each. A GL thread that keeps the GPU busy is bound by the
# GPU's render work (which a model on the same GPU then waits for); one that leaves it mostly idle
# is bound by the CPU side of the renders, and what a model loses beside them is the switching.
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_render_load.sh CARRY OUT
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"
NO_OPENVLA=1 . scripts/bench/gpu_setup.sh > "$out/setup.log" 2>&1
for threads in 1 ${RENDER_THREADS:-32}; do
  frames=$(( threads == 1 ? 600 : 150 ))
  nvidia-smi dmon -s u -d 1 > "$out/dmon-$threads.txt" & d=$!
  nvidia-smi --query-gpu=timestamp,utilization.gpu --format=csv,noheader -lms 100 > "$out/util-$threads.csv" & s=$!
  "$P" --bundles "$work/bundles" bench render --suites libero_spatial --python none --threads "$threads" --frames "$frames" 2>&1 |
    grep -E 'threads of one process|rust reference|libero_spatial ' | tee "$out/render-$threads.txt"
  kill $d $s
  awk -F', ' '{u=$2+0; n++; s+=u} END {printf "threads %s: utilization.gpu mean %.1f%% over %d samples of 100 ms\n", t, s/n, n}' t="$threads" "$out/util-$threads.csv" | tee -a "$out/summary.txt"
done
