#!/usr/bin/env bash
# Whether OpenVLA-7B runs on a card of GIB GiB (issue 22, item 2): a second process holds all of
# GPU 0 but GIB GiB (torch.empty of the rest, after its own CUDA context), then, per weight format:
#   model:   policies/benches/openvla.rs at B = 1 (load, warm-up, 3 calls), its exit status;
#   episode: one libero_spatial episode of 5 policy steps through `pipeline run` (agentview rendered
#            on the same GPU, as on a machine with one small card), whether it stored an error row.
# Unlike nvidia-smi's peak (scripts/bench/gpu_scaling.sh memory), this counts only what the run
# cannot do without: libtorch's caching allocator frees its unused blocks and retries before an
# allocation fails. PYTORCH_CUDA_ALLOC_CONF passes through (e.g. expandable_segments:True).
#
# usage (on the GPU machine, from the repo root): scripts/bench/gpu_card_fits.sh CARRY OUT GIB QUANT...
#   QUANT: none, int8 or int4. Prints and appends to OUT/fits.txt "GIB QUANT model ok|failed episode ok|failed".
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2"); gib=$3; shift 3
mkdir -p "$out"
work=${TMPDIR:-/tmp}/libero-gpu-fits; mkdir -p "$work"
. scripts/bench/gpu_setup.sh
"$P" --bundles "$work/bundles" specs --suites libero_spatial --tasks 0 --trials 1 -o "$work/one.parquet" > /dev/null

for q in "$@"; do
  rm -f "$work/ballast.ready"
  python3 - "$gib" "$work/ballast.ready" <<'PY' &
import sys, time, torch
keep = int(float(sys.argv[1]) * 2**30)
torch.cuda.init()
free, total = torch.cuda.mem_get_info(0)
ballast = torch.empty(max(free - keep, 0), dtype=torch.uint8, device="cuda:0")
free, _ = torch.cuda.mem_get_info(0)
print(f"ballast: {ballast.numel() / 2**30:.2f} GiB held, {free / 2**30:.2f} GiB of {total / 2**30:.2f} free", flush=True)
open(sys.argv[2], "w").close()
time.sleep(3600)
PY
  ballast=$!
  while [ ! -f "$work/ballast.ready" ]; do kill -0 $ballast; sleep 1; done
  model=failed
  "$BENCH" --checkpoint "$ckpt" --device cuda --attention sdpa --quant "$q" --batch 1 --warmup 1 --iters 3 \
    > "$out/fits-$gib-$q-model.log" 2>&1 && model=ok
  episode=failed
  q_opt=""; [ "$q" = none ] || q_opt="&quant=$q"
  rm -rf "$work/run-$q"
  "$P" --bundles "$work/bundles" run "$work/one.parquet" --out "$work/run-$q" --jobs 1 --max-steps 5 \
    --policy "openvla:$ckpt?unnorm=libero_spatial_no_noops$q_opt" > "$out/fits-$gib-$q-episode.log" 2>&1 &&
    errors=$("$P" sql --run "$work/run-$q" --csv "SELECT count(*) AS n FROM episodes WHERE error_kind IS NOT NULL" | tail -1) &&
    [ "$errors" = 0 ] && episode=ok
  kill $ballast; wait $ballast 2>/dev/null || true
  echo "$gib GiB $q model $model episode $episode" | tee -a "$out/fits.txt"
done
