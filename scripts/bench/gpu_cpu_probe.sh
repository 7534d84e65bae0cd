#!/usr/bin/env bash
# Where a GPU run's CPU goes: one `pipeline run` (MODEL, JOBS:BATCH:TRIALS as gpu_end_to_end.sh takes
# them) with `top -H` sampled every 5 s from PROBE_AFTER s (default 35) after the run starts (threads
# by CPU share, grouped by name), vmstat every 2 s, the process's minor faults, user and system ticks
# every 2 s (faults.txt: time, minflt, utime, stime), then the forwards' batch sizes from the stored rows.
# usage: scripts/bench/gpu_cpu_probe.sh CARRY OUT LABEL RUN   (env: MODEL, MAX_STEPS, and any
# variable to try, e.g. OMP_NUM_THREADS=1)
set -euo pipefail
carry=$1; out=$(realpath -m "$2"); label=$3; spec=$4
mkdir -p "$out"
( until [ -f "$out/$label/runs.log" ]; do sleep 1; done; sleep ${PROBE_AFTER:-35}; for i in 1 2 3 4; do top -H -b -n 1 -d 1 -w 200 | sed -n '1,5p;8,400p' > "$out/$label.top$i.txt"; sleep 5; done ) &
probe=$!
vmstat -w 2 > "$out/$label.vmstat.txt" &
vm=$!
( until pid=$(pgrep -of "pipeline.*run .*--out $out/$label/") ; do sleep 1; done
  while kill -0 $pid 2>/dev/null; do echo "$(date +%s) $(awk '{print $10, $14, $15}' /proc/$pid/stat 2>/dev/null)"; sleep 2; done ) > "$out/$label.faults.txt" &
scripts/bench/gpu_end_to_end.sh "$carry" "$out/$label" "$spec" > "$out/$label.txt" 2>&1 || true
kill $probe $vm 2>/dev/null || true
run=$(ls -d "$out/$label"/*/ | head -1)
P=${TMPDIR:-/tmp}/libero-gpu-e2e/pipeline
export LD_LIBRARY_PATH=$(python3 -c 'import os, torch; print(os.path.join(os.path.dirname(torch.__file__), "lib"))'):${TMPDIR:-/tmp}/libero-gpu-e2e/lib
"$P" sql --run "$run" "SELECT forward_batch / 8 * 8 AS batch_from, COUNT(*) AS forwards, AVG(forward_ms) AS ms FROM (SELECT DISTINCT forward_id, forward_batch, forward_ms FROM steps WHERE forward_id IS NOT NULL) GROUP BY 1 ORDER BY 1" > "$out/$label.batches.txt" 2>&1 || true
for f in "$out/$label".top*.txt; do
  echo "== $f"; head -5 "$f"
  awk 'NR>5 && $9+0>0 {n=$12; gsub(/[0-9]+$/,"",n); cpu[n]+=$9; c[n]++} END {for (k in cpu) printf "  %-24s threads %4d cpu%% %7.1f\n", k, c[k], cpu[k]}' "$f" | sort -k5 -nr | head -12
done > "$out/$label.cpu.txt"
grep -A3 "where the time goes" "$out/$label.txt" | tail -4 > "$out/$label.summary.txt"; cat "$out/$label.summary.txt" "$out/$label.batches.txt" "$out/$label.cpu.txt"
