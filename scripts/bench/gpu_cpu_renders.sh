#!/usr/bin/env bash
# Renders on the CPU against renders on the model's GPU, on a one-GPU machine, in one call (issue 46,
# items 2 and 3): llvmpipe's camera pairs/s on the machine's cores (by LP_NUM_THREADS, its rasteriser
# threads per context) and NVIDIA's, the model's forward alone (gpu_forward.sh), then the same runs
# with their cameras on the GPU and on the CPU (gpu_end_to_end.sh, RENDER=cpu), vmstat beside them.
# usage (on the GPU machine, from the repo root, after gpu_mesa_stage.sh):
#   scripts/bench/gpu_cpu_renders.sh CARRY OUT MODEL BATCHES RUN...
#   MODEL, BATCHES as gpu_forward.sh takes them; RUN as gpu_end_to_end.sh does. MESA (default
#   /tmp/mesa) is where Mesa is staged. FORWARD=0 skips the forward alone, GPU_RUN=0 the runs with
#   renders on the GPU. LP_SWEEP (default "default 1 2") lists the LP_NUM_THREADS values measured,
#   with CPU_RENDER_THREADS (32) threads of CPU_RENDER_FRAMES (4) pairs each; the CPU run takes the
#   fastest. vmstat samples every phase.
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); model=$3; batches=$4; shift 4
export MESA=${MESA:-/tmp/mesa} MODEL=$model
mkdir -p "$out"; work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"
. scripts/bench/gpu_setup.sh > "$out/setup.log" 2>&1
lscpu | grep -E '^(Model name|CPU\(s\)|Thread|Core|Socket)' | tee "$out/cpu.txt"
render() { "$P" --bundles "$work/bundles" bench render --suites libero_spatial --python none "$@" 2>&1 | grep -E 'threads of one process|bit for bit'; }
best=; best_rate=0
vmstat -t 5 > "$out/vmstat-renders.txt" & v=$!
for lp in ${LP_SWEEP:-default 1 2}; do
  echo "== CPU, LP_NUM_THREADS=$lp" | tee -a "$out/renders.txt"
  line=$( (if [ $lp != default ]; then export LP_NUM_THREADS=$lp; fi
          MUJOCO_EGL_DEVICE_ID=$SOFTWARE_EGL_DEVICE render --threads "${CPU_RENDER_THREADS:-32}" --frames "${CPU_RENDER_FRAMES:-4}") | tee -a "$out/renders.txt")
  rate=$(echo "$line" | sed -n 's/.* \([0-9.]*\) pairs\/s in all.*/\1/p')
  if [ -n "$rate" ] && awk -v a="$rate" -v b="$best_rate" 'BEGIN {exit !(a > b)}'; then best=$lp; best_rate=$rate; fi
done
echo "== GPU" | tee -a "$out/renders.txt"; render --threads 32 --frames 20 | tee -a "$out/renders.txt"
echo "LP_NUM_THREADS for the CPU run: $best ($best_rate pairs/s)" | tee -a "$out/renders.txt"
kill $v
[ "${FORWARD:-1}" = 0 ] || scripts/bench/gpu_forward.sh "$carry" "$out/alone" "$model" "$batches" > "$out/alone.log" 2>&1
if [ "${GPU_RUN:-1}" != 0 ]; then
  vmstat -t 5 > "$out/vmstat-gpu.txt" & v=$!
  scripts/bench/gpu_end_to_end.sh "$carry" "$out/gpu" "$@" > "$out/gpu.log" 2>&1 || echo "GPU-render run failed: $(tail -3 "$out/gpu.log")"
  kill $v
fi
vmstat -t 5 > "$out/vmstat-cpu.txt" & v=$!
(if [ "$best" != default ]; then export LP_NUM_THREADS=$best; fi
 RENDER=cpu scripts/bench/gpu_end_to_end.sh "$carry" "$out/cpu" "$@" > "$out/cpu.log" 2>&1) || echo "CPU-render run failed: $(tail -3 "$out/cpu.log")"
kill $v
grep -h -E "B= *[0-9]+:" "$out/alone.log" 2>/dev/null || true
for f in "$out"/gpu/*.bench.txt "$out"/cpu/*.bench.txt; do echo "== $f"; head -40 "$f"; done
