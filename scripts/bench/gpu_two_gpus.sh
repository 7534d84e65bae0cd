#!/usr/bin/env bash
# One GPU against two on the same machine (issue 22, item 3), real episodes through `pipeline run`
# (scripts/bench/gpu_end_to_end.sh: OpenVLA-7B random weights, libero_spatial, MAX_STEPS, default 60):
#   one: a replica on cuda:0 with the renders on that GPU too (MUJOCO_EGL_DEVICE_ID: what a machine
#        with one GPU does), JOBS workers, TRIALS trials per task;
#   two: a replica on each of the first GPUS GPUs (default 2) in one process (`--processes 1`) with
#        its one GL thread, GPUS times the workers and the episodes (the same per GPU);
#   split: the same in a process per GPU, `pipeline run --processes GPUS`, which is what `pipeline run`
#        does by itself for several GPUs (each process its replica, its share of the workers and its
#        renders on its own GPU: issue 46, item 1);
#   processes: the same as two (two GPUs), in a process per GPU: a localhost Ballista cluster of two
#        `pipeline executor`s, each with one GPU (CUDA_VISIBLE_DEVICES, MUJOCO_EGL_DEVICE_ID: its
#        own replica, GL thread and renders) and JOBS slots;
# then the ratio of each to one's policy steps/s, and vmstat's samples over each run (the cores it
# used). Machines of one kind differ by up to ~15% from
# lease to lease (data/benchmarks/gpu-two-h100-one-gl-thread-2026-11-27): a ratio means something
# only within one call. MODES (default "one two") picks the runs and their order; EGL_DEVICES (see
# below) skips the EGL probes.
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_two_gpus.sh CARRY OUT [JOBS:TRIALS]
#   CARRY: scripts/bench/gpu_carry.sh's folder; OUT: each run's `bench run` figures, logs and
#   nvidia-smi samples (the runs themselves stay in $TMPDIR: the device tool returns small files).
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); IFS=: read -r jobs trials <<< "${3:-32:12}"
mkdir -p "$out"
# gpu_end_to_end.sh's folder: the random weights are written once, where its runs read them
work=${TMPDIR:-/tmp}/libero-gpu-e2e; mkdir -p "$work"
. scripts/bench/gpu_setup.sh

# The EGL device of CUDA device $1 in a process that sees the GPUs $2 (CUDA_VISIBLE_DEVICES; default $1),
# from the device `bench render` reports: EGL lists the GPUs whatever CUDA_VISIBLE_DEVICES says (the
# GPU then reports its own index) or only the visible ones (renumbered from CUDA device 0).
egl_of() {
  local id line fallback=""
  for id in 0 1 2 3; do
    line=$(CUDA_VISIBLE_DEVICES=${2-$1} MUJOCO_EGL_DEVICE_ID=$id "$P" --bundles "$work/bundles" bench render \
      --suites libero_spatial --python none --frames 2 --threads 2 2>/dev/null | grep 'threads per' || true)
    if [[ $line == *"(($id, Some($1)))"* ]]; then echo "$id"; return; fi
    if [[ -z $fallback && $line == *"(($id, Some(0)))"* ]]; then fallback=$id; fi
  done
  [ -n "$fallback" ] || { echo "EGL lists no device for CUDA device $1" >&2; exit 1; }
  echo "$fallback"
}
# EGL_DEVICES="E0 E1 E0ALL" skips the probes where a call of this machine kind already printed them.
if [ -n "${EGL_DEVICES:-}" ]; then read -r e0 e1 egl0 <<< "$EGL_DEVICES"; egl=("$e0" "$e1")
else egl=("$(egl_of 0)" "$(egl_of 1)"); egl0=$(egl_of 0 0,1); fi
[ -n "${egl[0]}" ] && [ -n "${egl[1]}" ] && [ -n "$egl0" ] || exit 1
echo "EGL devices of CUDA 0 and 1, each seen alone: ${egl[*]}; of CUDA 0 seen with all: $egl0" | tee -a "$out/figures.txt"

pids=()
trap 'kill "${pids[@]}" 2>/dev/null || true' EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

gpus=${GPUS:-2}
all_devices=$(seq -s, -f 'cuda:%g' 0 $((gpus - 1)))
one() { MUJOCO_EGL_DEVICE_ID=$egl0 run_e2e one "$jobs:64:$trials:devices=cuda:0"; }
two() { PROCESSES=1 run_e2e two "$((gpus * jobs)):64:$((gpus * trials)):devices=$all_devices"; }
split() { PROCESSES=$gpus run_e2e split "$((gpus * jobs)):64:$((gpus * trials)):devices=$all_devices"; }
processes() {
  local port; port=$(free_port)
  "$P" scheduler --bind 127.0.0.1 --port "$port" 2> "$out/processes-scheduler.log" & pids+=($!)
  until (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null; do sleep 0.2; done
  for cuda in 0 1; do
    CUDA_VISIBLE_DEVICES=$cuda MUJOCO_EGL_DEVICE_ID=${egl[$cuda]} "$P" --bundles "$work/bundles" executor \
      --scheduler "127.0.0.1:$port" --port "$(free_port)" --grpc-port "$(free_port)" --vcores "$jobs" \
      --work-dir "$work/executor-$cuda" 2> "$out/processes-executor-$cuda.log" & pids+=($!)
  done
  sleep 3 # the executors register
  ENGINE="ballista://127.0.0.1:$port" run_e2e processes "$((2 * jobs)):64:$((2 * trials)):devices=cuda:0"
}
run_e2e() {
  local name=$1 run=$2
  vmstat -t 5 > "$out/$name-vmstat.txt" & local v=$!
  MAX_STEPS=${MAX_STEPS:-60} bash scripts/bench/gpu_end_to_end.sh "$carry" "$work/runs/$name" "$run" > "$out/$name.log" 2>&1 ||
    echo "$name failed: $(tail -3 "$out/$name.log")" | tee -a "$out/figures.txt"
  kill $v 2>/dev/null || true
  find "$work/runs/$name" -maxdepth 1 -type f \( -name '*.txt' -o -name '*.csv' -o -name '*.log' \) \
    -exec sh -c 'cp "$1" "$2/'"$name"'-$(basename "$1")"' _ {} "$out" \;
  grep -A6 'where the time goes' "$out/$name.log" | sed "s/^/$name: /" | tee -a "$out/figures.txt"
}
modes=(${MODES:-one two})
for mode in "${modes[@]}"; do "$mode"; done
rate() { grep -o '[0-9.]* policy steps/s' "$out/$1.log" | head -1 | cut -d' ' -f1; }
for mode in "${modes[@]}"; do
  [ "$mode" = one ] || [ ! -f "$out/one.log" ] || echo "$mode / one: $(rate "$mode") / $(rate one) = \
$(python3 -c "print(round($(rate "$mode") / $(rate one), 3))") (JOBS=$jobs TRIALS=$trials per GPU, GPUS=$gpus; EGL devices ${egl[*]})" |
    tee -a "$out/figures.txt"
done
