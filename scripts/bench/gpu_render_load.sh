#!/usr/bin/env bash
# How busy do renders alone keep the GPU? `pipeline bench render` on the GPU (one shared GL thread,
# reference quality, libero_spatial camera pairs at 256²) with 1 and with RENDER_THREADS threads,
# nvidia-smi's utilization sampled beside each (every 100 ms; `dmon` every second). Only the
# rendering is averaged: the longest run of samples above 50%. Busy time a pair is the GPU time a
# model on the same GPU waits for it. CAMERAS (default "pair") lists what each thread renders, in
# turn: pair (agentview + wrist, what OFT sees) or one camera (agentview: all OpenVLA sees), e.g.
# CAMERAS="pair agentview" for both in one call. Compare them at RENDER_THREADS: with one thread a
# pair renders on a context of its own and a single camera through the GL thread.
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_render_load.sh CARRY OUT
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"
samplers=
trap 'if [ -n "$samplers" ]; then kill $samplers 2>/dev/null || true; fi' EXIT
MODEL=openvla NO_OPENVLA=1 . scripts/bench/gpu_setup.sh > "$out/setup.log" 2>&1
for camera in ${CAMERAS:-pair}; do
  for threads in 1 ${RENDER_THREADS:-32}; do
    frames=$(( threads == 1 ? 600 : 150 ))
    # files of the pair keep their old names; a camera's carry its name
    tag=$threads; [ "$camera" = pair ] || tag=$threads-$camera
    one=(); [ "$camera" = pair ] || one=(--camera "$camera")
    nvidia-smi dmon -s u -d 1 > "$out/dmon-$tag.txt" & samplers="$!"
    nvidia-smi --query-gpu=timestamp,utilization.gpu --format=csv,noheader -lms 100 > "$out/util-$tag.csv" & samplers="$samplers $!"
    "$P" --bundles "$work/bundles" bench render --suites libero_spatial --python none --threads "$threads" --frames "$frames" ${one[@]+"${one[@]}"} \
      > "$out/render-$tag.log" 2>&1 || echo "bench render ($camera) with $threads thread(s) failed: $(tail -3 "$out/render-$tag.log")"
    kill $samplers 2>/dev/null || true; samplers=
    grep -E 'threads of one process|rust reference|libero_spatial ' "$out/render-$tag.log" | tee "$out/render-$tag.txt" || true
    # the rendering: the longest run of samples above 50% (the GPU idles while the bench loads its
    # bundles, and works in bursts while it compares pixels after, each thread on a context of its own)
    awk -F', ' '{u = $2 + 0; if (u > 50) { if (!len) { s = 0 } len++; s += u; if (len > best) { best = len; mean = s / len } } else len = 0}
      END { if (!best) { print c ", threads " t ": no busy samples"; exit }
            printf "%s, threads %s: utilization.gpu mean %.1f%% over the longest run of samples above 50%%: %d of 100 ms\n", c, t, mean, best }' \
      c="$camera" t="$threads" "$out/util-$tag.csv" | tee -a "$out/summary.txt"
  done
done
