#!/usr/bin/env bash
# Renders on the CPU against renders on the model's GPU, on a one-GPU machine, in one call (issue 46,
# items 2 and 3): llvmpipe's camera pairs/s on the machine's cores (by LP_NUM_THREADS, its rasteriser
# threads per context) and NVIDIA's, the model's forward alone (gpu_forward.sh), then the same runs
# with their cameras on the GPU and on the CPU (gpu_end_to_end.sh, RENDER=cpu), vmstat beside them.
# usage (on the GPU machine, from the repo root, after gpu_mesa_stage.sh):
#   scripts/bench/gpu_cpu_renders.sh CARRY OUT MODEL BATCHES RUN...
#   MODEL, BATCHES as gpu_forward.sh takes them; RUN (and MAX_STEPS) as gpu_end_to_end.sh does. MESA
#   (default /tmp/mesa) is where Mesa is staged; only the CPU run and the CPU renders see it.
#   FORWARD=0 skips the forward alone, GPU_RUN=0 the runs with renders on the GPU. LP_SWEEP (default
#   "default 1 2") lists the LP_NUM_THREADS values measured, with CPU_RENDER_THREADS (32) threads of
#   CPU_RENDER_FRAMES (4) pairs each; the CPU run takes the fastest. vmstat samples every phase.
# A run that hits the call's limit before its episodes end stores only those that ended: `bench run`
# then counts the steps of those alone (a lower bound of the run's rate).
set -euo pipefail
shopt -s nullglob
carry=$(realpath "$1"); out=$(realpath -m "$2"); model=$3; batches=$4; shift 4
mesa=${MESA:-/tmp/mesa}
mkdir -p "$out"; work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"
v=
trap 'if [ -n "$v" ]; then kill $v 2>/dev/null || true; fi' EXIT
sample() { vmstat -t 5 > "$out/vmstat-$1.txt" & v=$!; }
stop_sampling() { kill $v 2>/dev/null || true; v=; }

MESA=$mesa MODEL=$model
. scripts/bench/gpu_setup.sh > "$out/setup.log" 2>&1
sw=$SOFTWARE_EGL_DEVICE
# what the GPU's figures run with: the vendors without Mesa's (the CPU's add it back)
gpu_vendors=${__EGL_VENDOR_LIBRARY_FILENAMES%:$MESA/50_mesa.json}
gpu_env=(env -u LIBGL_DRIVERS_PATH __EGL_VENDOR_LIBRARY_FILENAMES="$gpu_vendors" MESA=)
cpu_env=(env MESA="$mesa")
unset MESA
lscpu | grep -E '^(Model name|CPU\(s\)|Thread|Core|Socket)' | tee "$out/cpu.txt"
render() { "$P" --bundles "$work/bundles" bench render --suites libero_spatial --python none "$@" 2>&1 | grep -E 'threads of one process|bit for bit' || true; }
best=; best_rate=0
sample renders
for lp in ${LP_SWEEP:-default 1 2}; do
  echo "== CPU, LP_NUM_THREADS=$lp" | tee -a "$out/renders.txt"
  line=$( (if [ "$lp" != default ]; then export LP_NUM_THREADS=$lp; fi
          export MUJOCO_EGL_DEVICE_ID=$sw; render --threads "${CPU_RENDER_THREADS:-32}" --frames "${CPU_RENDER_FRAMES:-4}") | tee -a "$out/renders.txt")
  rate=$(echo "$line" | sed -n 's/.* \([0-9.]*\) pairs\/s in all.*/\1/p')
  if [ -n "$rate" ] && awk -v a="$rate" -v b="$best_rate" 'BEGIN {exit !(a > b)}'; then best=$lp; best_rate=$rate; fi
done
echo "== GPU" | tee -a "$out/renders.txt"
(export __EGL_VENDOR_LIBRARY_FILENAMES="$gpu_vendors"; unset LIBGL_DRIVERS_PATH; render --threads 32 --frames 20) | tee -a "$out/renders.txt"
echo "LP_NUM_THREADS for the CPU run: ${best:-none measured, so Mesa default} ($best_rate pairs/s)" | tee -a "$out/renders.txt"
stop_sampling
[ "${FORWARD:-1}" = 0 ] || "${gpu_env[@]}" scripts/bench/gpu_forward.sh "$carry" "$out/alone" "$model" "$batches" > "$out/alone.log" 2>&1 ||
  echo "forward failed: $(tail -3 "$out/alone.log")"
if [ "${GPU_RUN:-1}" != 0 ]; then
  sample gpu
  "${gpu_env[@]}" MODEL="$model" scripts/bench/gpu_end_to_end.sh "$carry" "$out/gpu" "$@" > "$out/gpu.log" 2>&1 ||
    echo "GPU-render run failed: $(tail -3 "$out/gpu.log")"
  stop_sampling
fi
sample cpu
(if [ -n "$best" ] && [ "$best" != default ]; then export LP_NUM_THREADS=$best; fi
 "${cpu_env[@]}" MODEL="$model" RENDER=cpu scripts/bench/gpu_end_to_end.sh "$carry" "$out/cpu" "$@" > "$out/cpu.log" 2>&1) ||
  echo "CPU-render run failed: $(tail -3 "$out/cpu.log")"
stop_sampling
grep -h -E "B= *[0-9]+:" "$out/alone.log" 2>/dev/null || true
for f in "$out"/gpu/*.bench.txt "$out"/cpu/*.bench.txt; do echo "== $f"; head -40 "$f"; done
