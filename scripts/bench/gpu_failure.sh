#!/usr/bin/env bash
# A GPU that fails mid-run (issue 46, item 4), forced on a GPU machine. OpenVLA-7B (random bf16
# weights) serves libero_spatial episodes from one replica per device in DEVICES; once the replicas
# have loaded and run for WARM seconds, another process takes all the free memory of HOG_DEVICE for
# HOLD seconds, so that device's forwards run out of memory, and then frees it. The pipeline runs
# with PYTORCH_NO_CUDA_MEMORY_CACHING=1: every forward asks the driver for its memory, as a forward
# on a full device does, instead of reusing what libtorch's cache kept from earlier forwards (which
# would hide the hog).
#
# What must hold (checked at the end, exit 1 otherwise): the run ends by itself within DEADLINE s
# (never a hang) with status 0. A forward that runs out of memory is tried again after pauses of
# 1, 2, 4 and 8 s (policies::batching): a hog shorter than those 15 s costs no episode (HOLD=6);
# a longer one (HOLD=40) makes the episodes of the forwards that failed every try error rows that
# name the device and the out-of-memory, and episodes started after the memory came back run to
# their cap without error. A lost device (Xid, fallen off the bus) cannot be forced here without
# resetting the accelerator, which this machine's rules forbid.
#
# usage (device tool, repo root): scripts/bench/gpu_failure.sh CARRY OUT
#   CARRY: scripts/bench/gpu_carry.sh's folder; OUT: the run, its log and the checks' figures.
#   DEVICES=cuda:0 (or cuda:0,cuda:1), HOG_DEVICE=cuda:0, WARM=8, HOLD=6, TRIALS=8 (x 10 tasks),
#   JOBS=16, BATCH=16, MAX_STEPS=30, DEADLINE=480; PROCESSES=N passes --processes N (unset, two
#   DEVICES run in a process per GPU, `pipeline run`'s default; PROCESSES=1 keeps one process).
set -euo pipefail
carry=$(realpath "$1"); out=$(realpath -m "$2")
DEVICES=${DEVICES:-cuda:0}; HOG_DEVICE=${HOG_DEVICE:-${DEVICES##*,}}
WARM=${WARM:-8}; HOLD=${HOLD:-6}; TRIALS=${TRIALS:-8}; JOBS=${JOBS:-16}; BATCH=${BATCH:-16}
MAX_STEPS=${MAX_STEPS:-30}; DEADLINE=${DEADLINE:-480}
mkdir -p "$out"; work=${TMPDIR:-/tmp}/libero-gpu-failure; mkdir -p "$work"
. scripts/bench/gpu_setup.sh
nvidia-smi --query-gpu=index,name,memory.total --format=csv,noheader | tee "$out/gpus.txt"

"$P" --bundles "$work/bundles" specs --suites libero_spatial --trials "$TRIALS" -o "$work/specs.parquet"
rm -rf "$out/run"
start=$(date +%s.%N)
PYTORCH_NO_CUDA_MEMORY_CACHING=1 timeout --signal=KILL "$DEADLINE" "$P" --bundles "$work/bundles" run "$work/specs.parquet" \
  --out "$out/run" --policy "openvla:$ckpt?unnorm=libero_spatial_no_noops&batch=$BATCH&devices=$DEVICES" \
  --jobs "$JOBS" --max-steps "$MAX_STEPS" ${PROCESSES:+--processes "$PROCESSES"} > "$out/run.stdout" 2> "$out/run.stderr" &
run=$!

# the replicas are loaded once the run's first episode part is written; then WARM s of forwards
until ls "$out/run/episodes"/*.parquet >/dev/null 2>&1 || ! kill -0 "$run" 2>/dev/null; do sleep 1; done
sleep "$WARM"
python3 - "$HOG_DEVICE" "$HOLD" > "$out/hog.json" <<'PY'
import json, sys, time, torch
device, hold = sys.argv[1], float(sys.argv[2])
held = []
for size in (1 << 30, 256 << 20, 16 << 20, 1 << 20):  # every free byte, largest blocks first
    while True:
        try:
            held.append(torch.empty(size, dtype=torch.uint8, device=device))
        except torch.OutOfMemoryError:
            break
taken = time.time()
free, total = torch.cuda.mem_get_info(device)
time.sleep(hold)
del held
torch.cuda.empty_cache()
print(json.dumps({"device": device, "taken_at": taken, "released_at": time.time(),
                  "free_while_held_mib": free >> 20, "total_mib": total >> 20}))
PY
cat "$out/hog.json"
status=0; wait "$run" || status=$?
end=$(date +%s.%N)
echo "run exit status $status after $(python3 -c "print(round($end - $start, 1))") s (deadline $DEADLINE s)" | tee "$out/summary.txt"
grep -v '^|\|^+' "$out/run.stderr" | tail -n 20 || true

# the checks, from the stored episodes
released=$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["released_at"])' "$out/hog.json")
taken=$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["taken_at"])' "$out/hog.json")
"$P" sql "SELECT count(*) AS episodes,
    sum(CASE WHEN error_kind IS NULL THEN 0 ELSE 1 END) AS error_rows,
    sum(CASE WHEN error_kind IS NOT NULL AND lower(error) LIKE '%out of memory%' THEN 1 ELSE 0 END) AS out_of_memory_rows,
    sum(CASE WHEN started_at > $released AND error_kind IS NULL AND n_policy_steps = $MAX_STEPS THEN 1 ELSE 0 END) AS after_release_complete,
    sum(CASE WHEN started_at > $released AND error_kind IS NOT NULL THEN 1 ELSE 0 END) AS after_release_errors,
    sum(CASE WHEN started_at + wall_s < $taken AND error_kind IS NULL THEN 1 ELSE 0 END) AS before_hog_complete
  FROM episodes" --run "$out/run" --csv | tee "$out/checks.csv"
"$P" sql "SELECT DISTINCT substr(error, 1, 400) AS error FROM episodes WHERE error IS NOT NULL" --run "$out/run" --csv \
  | tee "$out/errors.csv"
grep -c "; trying again" "$out/run.stderr" | sed 's/^/tries again (a forward tried again counts once per pause): /' | tee -a "$out/summary.txt" || true
python3 - "$out/checks.csv" "$status" "$HOLD" "$out/errors.csv" "$HOG_DEVICE" <<'PY'
import csv, sys
row = next(csv.DictReader(open(sys.argv[1])))
n = {k: int(float(v or 0)) for k, v in row.items()}
passing = float(sys.argv[3]) < 15  # the retries' pauses add up to 15 s
errors = open(sys.argv[4]).read()
checks = {"the run ended by itself with status 0": sys.argv[2] == "0"}
if passing:
    checks["a hog shorter than the retries cost no episode"] = n["error_rows"] == 0
else:
    checks.update({
        "some episodes are error rows": n["error_rows"] > 0,
        "every error row says out of memory": n["error_rows"] == n["out_of_memory_rows"],
        "the error rows name the device": f"the model on {sys.argv[5]} failed" in errors,
        "episodes started after the release ran to the cap": n["after_release_complete"] > 0,
        "no episode started after the release failed": n["after_release_errors"] == 0,
    })
for what, ok in checks.items():
    print(("PASS " if ok else "FAIL ") + what)
sys.exit(0 if all(checks.values()) else 1)
PY
