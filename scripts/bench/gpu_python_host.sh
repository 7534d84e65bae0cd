#!/usr/bin/env bash
# The Python host on a GPU machine (issue 45): lerobot 0.6.1 installed there from carried wheels
# (the machine has no network; its python3 has torch 2.11.0 with CUDA, used through
# --system-site-packages), a full-size π0.5 (4.1 B, random bf16 weights, lerobot's own classes)
# built there, then
#   host: the host's cost per call against the adapter called directly (python_host_overhead.py);
#   run:  `pipeline run --policy lerobot:...` on libero_spatial episodes, the throughput end to end
#         (the carry of scripts/bench/gpu_carry.sh in $CARRY: the pipeline, libmujoco, bundles, EGL).
# usage (device tool, repo root): scripts/bench/gpu_python_host.sh build|host|run [B] [EPISODES] [STEPS]
set -euo pipefail
phase=$1; B=${2:-32}; EPISODES=${3:-64}; STEPS=${4:-60}
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
W=.devcarry; V=$W/lrvenv; CKPT=$W/pi05
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$OUT/gpu.txt"
python3 -c 'import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.is_available())' | tee "$OUT/python.txt"
if [ ! -f "$V/.complete" ]; then
  rm -rf "$V"
  t=$(date +%s)
  python3 -m venv --system-site-packages "$V"
  # every carried wheel (numpy, pillow, torchvision too): the venv does not see a user-site or
  # PYTHONPATH install of the machine's, only its system site-packages (torch)
  wheels=$(ls $W/wheels/*.whl)
  # the machine's torch wherever it lies (PYTHONPATH, user site): appended to the venv's path, so
  # the venv's own packages come first
  python3 -c 'import os, torch, numpy; print(torch.__file__, numpy.__file__, os.environ.get("PYTHONPATH"))' | tee -a "$OUT/python.txt"
  python3 -c 'import os, torch; print(os.path.dirname(os.path.dirname(torch.__file__)))' > "$("$V/bin/python" -c 'import site; print(site.getsitepackages()[0])')/machine_torch.pth"
  "$V/bin/pip" install -q --no-index --no-deps $wheels
  "$V/bin/python" -c 'import lerobot, transformers, torch; from importlib.metadata import version as v; print("lerobot", v("lerobot"), "transformers", transformers.__version__, "torch", torch.__version__)' | tee -a "$OUT/python.txt"
  echo "venv in $(( $(date +%s) - t )) s" | tee -a "$OUT/python.txt"
  touch "$V/.complete"
fi
if [ ! -f "$CKPT/model.safetensors" ]; then
  "$V/bin/python" scripts/bench/python_host_overhead.py build "$CKPT" | tee "$OUT/build.json"
fi
case "$phase" in
  build) ;;  # the venv and the checkpoint only (a call of its own when the carry is too big for one)
  host)
    "$V/bin/python" scripts/bench/python_host_overhead.py time "$CKPT" "$OUT/host_overhead.json" \
      --device cuda:0 --batches 1,8,32,64 --reps 5 2>&1 | grep -v -i warn | tee "$OUT/host_overhead.log"
    ;;
  run)
    carry=$W/run; work=$W/work; mkdir -p "$work"
    # shellcheck source=/dev/null
    NO_OPENVLA=1 . scripts/bench/gpu_setup.sh
    "$P" specs --bundles "$work/bundles" --suites libero_spatial --trials $(( (EPISODES + 9) / 10 )) -o "$work/specs.parquet"
    policy="lerobot:$PWD/$CKPT?python=$PWD/$V/bin/python&tokenizer=$PWD/$CKPT/tokenizer&devices=cuda:0&batch=$B"
    /usr/bin/time -v "$P" run "$work/specs.parquet" --bundles "$work/bundles" --out "$work/run" --policy "$policy" \
      --jobs "$B" --max-steps "$STEPS" 2> >(grep -v '^\[python host' | tee "$OUT/run.stderr" >&2) | tee "$OUT/run.stdout"
    cp "$work/run/manifest.json" "$OUT/"; cp -r "$work/run/sessions" "$OUT/" 2>/dev/null || true
    "$P" sql "SELECT count(*) AS episodes, sum(n_policy_steps) AS policy_steps, avg(policy_s / n_policy_steps) * 1e3 AS policy_ms_per_step, avg(render_s / n_policy_steps) * 1e3 AS render_ms_per_step, avg(sim_s / n_policy_steps) * 1e3 AS sim_ms_per_step, sum(CASE WHEN error IS NULL THEN 0 ELSE 1 END) AS errors FROM episodes" --run "$work/run" | tee "$OUT/split.txt"
    ;;
esac
