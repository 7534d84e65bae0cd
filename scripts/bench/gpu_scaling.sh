#!/usr/bin/env bash
# Issue 22's GPU figures for OpenVLA-7B (random bf16 weights) on a GPU machine, in parts:
#
#   quant          per weight format (bf16, int8, int4; QUANTS="int4" for fewer): the GPU memory one
#                  episode needs (the bench at B = 1 in a process of its own, nvidia-smi sampling
#                  the memory in use every 100 ms, its peak less the idle GPU's: weights,
#                  activations, the CUDA context and the allocator's cache, what a smaller card
#                  must hold); then policies/benches/openvla.rs at B = 1, 8, 32, 64 (SDPA
#                  attention): ms per call, actions/s, the fraction of the compute bound; int8's
#                  and int4's tokens against bf16 on 32 random inputs; int4's tinygemm path
#                  against its dequantised weight.
#   memory         only quant's first step: the GPU memory one episode needs per weight format
#                  (QUANTS), the bench at B = 1 in a process of its own; with ALLOC=expandable also
#                  with PYTORCH_CUDA_ALLOC_CONF=expandable_segments:True (the caching allocator
#                  grows its segments instead of adding new ones: less memory reserved and unused);
#                  with BLOCKS="int8 int4" also each of those formats quantised both ways, in blocks
#                  of 16 Mi weights and whole layers (the bench's --quantize-block), whole, blocks,
#                  blocks, whole: the A/B of the load's peak on one machine (models::quant).
#   fused          the language model's launch-saving kernels (`Fusion`, the bench's --fusion), bf16,
#                  in one process per attention: none (transformers' operations one by one), each
#                  part alone, and all, SDPA at B = 1, 8, 32, 64 and eager (OpenVLA's own) at
#                  B = 1, 64; each set's tokens and logits against none on 32 random inputs.
#   serve:W:S      the serving path without the simulator (the bench's --serve: W worker threads per
#                  GPU, OpenVLA's preprocessing on each, the shared replicas' batchers), S seconds,
#                  on cuda:0 and then on every GPU of the machine (W x GPUs workers: each replica
#                  batches W episodes, as one GPU alone does).
#   episodes:T     real libero_spatial episodes (T trials per task), one policy step each, through
#                  `pipeline run`: bf16 twice, then int8 and int4, every episode's first query in
#                  one forward (batch = jobs = episodes); `pipeline compare` of each against the
#                  first bf16 run gives the first actions' agreement on the same rendered
#                  observations (queries/compare_first_actions.sql).
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_scaling.sh CARRY OUT PART...
#   CARRY: made by scripts/bench/gpu_carry.sh (with the bench binary); OUT: figures and logs.
# What the machine needs: scripts/bench/gpu_setup.sh.
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); shift 2
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-scaling; mkdir -p "$work"
. scripts/bench/gpu_setup.sh
gpus=$(nvidia-smi --query-gpu=index --format=csv,noheader | wc -l)
all_gpus=$(seq -s, 0 $((gpus - 1)) | sed 's/\([0-9]\+\)/cuda:\1/g')
nvidia-smi --query-gpu=index,name,driver_version,memory.total --format=csv,noheader | tee "$out/gpus.txt"

# runs "$@" while nvidia-smi samples GPU 0's memory in use; appends "LABEL peak_mib idle_mib" to memory.txt
with_memory() {
  local label=$1; shift
  local idle; idle=$(nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits --id=0)
  nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits --id=0 -lms 100 > "$out/memory-$label.csv" &
  local smi=$!
  "$@"
  kill $smi; wait $smi 2>/dev/null || true
  local peak; peak=$(sort -n "$out/memory-$label.csv" | tail -1)
  echo "$label peak_mib=$peak idle_mib=$idle model_mib=$((peak - idle))" | tee -a "$out/memory.txt"
}

# the memory a card needs for one episode (B = 1) with weights stored as $1, in a process of its own;
# $2 labels the variant, $3... are further bench flags
memory_b1() {
  local q=$1 label=${2:-}; shift 2 || shift $#
  with_memory "b1-$q${label:+-$label}" "$BENCH" --checkpoint "$ckpt" --device cuda --attention sdpa --quant "$q" \
    --batch 1 --warmup 1 --iters 3 "$@" > "$out/memory-b1-$q${label:+-$label}.log" 2>&1
}

for part in "$@"; do
  IFS=: read -r what a b <<< "$part"
  case $what in
    quant)
      for q in ${QUANTS:-none int8 int4}; do
        memory_b1 $q
        agree=(); [ $q = none ] || agree=(--agreement)
        "$BENCH" --checkpoint "$ckpt" --device cuda --attention sdpa --quant $q \
          --batch 1,8,32,64 --warmup 3 --iters 10 "${agree[@]}" --json "$out/quant-$q.json" 2>&1 | tee -a "$out/quant.log"
      done ;;
    memory)
      for q in ${QUANTS:-none int8 int4}; do
        memory_b1 $q
        [ "${ALLOC:-}" = expandable ] || continue
        PYTORCH_CUDA_ALLOC_CONF=expandable_segments:True memory_b1 $q expandable
      done
      for q in ${BLOCKS:-}; do
        # whole, blocks, blocks, whole: a steady drift of the machine weighs on both alike
        memory_b1 $q whole-1 --quantize-block 1000000000000
        memory_b1 $q blocks-1 --quantize-block 16777216
        memory_b1 $q blocks-2 --quantize-block 16777216
        memory_b1 $q whole-2 --quantize-block 1000000000000
      done ;;
    fused)
      "$BENCH" --checkpoint "$ckpt" --device cuda --attention sdpa --fusion none/norm/qkv/gate_up/rotary_fma/static_cache/rotary_kernel/norm_kernel/swiglu_kernel/all \
        --batch 1,8,32,64 --warmup 3 --iters 10 --json "$out/fusion-sdpa.json" 2>&1 | tee -a "$out/fused.log"
      "$BENCH" --checkpoint "$ckpt" --device cuda --attention eager --fusion none/all \
        --batch 1,64 --warmup 3 --iters 10 --json "$out/fusion-eager.json" 2>&1 | tee -a "$out/fused.log" ;;
    serve)
      for devices in cuda:0 "$all_gpus"; do
        workers=$((a * $(echo "$devices" | tr ',' '\n' | wc -l)))
        "$BENCH" --checkpoint "$ckpt" --serve "$workers" --seconds "$b" --devices "$devices" \
          --json "$out/serve-$(echo "$devices" | tr -c 'a-z0-9\n' '_').json" 2>&1 | tee -a "$out/serve.log"
      done ;;
    episodes)
      n=$((10 * a))
      "$P" --bundles "$work/bundles" specs --suites libero_spatial --trials "$a" -o "$work/first.parquet"
      for r in bf16 bf16-again int8 int4; do
        q=""; case $r in int8|int4) q="&quant=$r" ;; esac
        "$P" --bundles "$work/bundles" run "$work/first.parquet" --out "$out/first-$r" --max-steps 1 --jobs "$n" \
          --policy "openvla:$ckpt?unnorm=libero_spatial_no_noops&batch=$n&wait_ms=60000$q" 2>&1 | tail -5 | tee -a "$out/episodes.log"
      done
      for r in bf16-again int8 int4; do
        echo "::: compare first-bf16 first-$r" | tee -a "$out/episodes.log"
        "$P" compare "$out/first-bf16" "$out/first-$r" --out "$out/compare-$r" 2>&1 | tail -3 | tee -a "$out/episodes.log"
      done ;;
    *) echo "unknown part $part (quant, memory, fused, serve:W:S, episodes:T)" >&2; exit 2 ;;
  esac
done
