#!/usr/bin/env bash
# What running on Ballista costs per episode, against the local engine with as many episode slots:
# the same spec table (libero_spatial, TASKS tasks x TRIALS trials, the random policy capped at
# MAX_STEPS policy steps) run locally with --jobs SLOTS, then on a localhost cluster of one
# `pipeline scheduler` and SLOTS `pipeline executor`s of one slot each. Each run's wall time is
# its `sessions/*.json` record (what `pipeline run` stores). Prints both and the overhead per
# episode; writes them to OUT/overhead.csv with the command line.
#
#   scripts/bench/distributed_overhead.sh OUT [SLOTS=2] [TASKS=4] [TRIALS=10] [MAX_STEPS=20]
set -euo pipefail
OUT=${1:?usage: distributed_overhead.sh OUT [SLOTS] [TASKS] [TRIALS] [MAX_STEPS]}
SLOTS=${2:-2} TASKS=${3:-4} TRIALS=${4:-10} MAX_STEPS=${5:-20}
cd "$(dirname "$0")/../.."
BIN=${LIBERO_PIPELINE_BIN:-${CARGO_TARGET_DIR:-target}/release/pipeline}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
work=$(mktemp -d)
pids=()
trap 'kill "${pids[@]}" 2>/dev/null || true; rm -rf "$work"' EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

tasks=$(seq -s, 0 $((TASKS - 1)))
"$BIN" specs --suites libero_spatial --tasks "$tasks" --trials "$TRIALS" -o "$work/specs.parquet" >/dev/null
episodes=$((TASKS * TRIALS))
wall_of() { python3 -c 'import json,glob,sys; print(sum(json.load(open(f))["wall_s"] for f in glob.glob(sys.argv[1] + "/sessions/*.json")))' "$1"; }

"$BIN" run "$work/specs.parquet" --out "$work/local" --policy random --max-steps "$MAX_STEPS" --jobs "$SLOTS" >/dev/null 2>"$work/local.log"
local_s=$(wall_of "$work/local")

port=$(free_port)
"$BIN" scheduler --bind 127.0.0.1 --port "$port" 2>"$work/scheduler.log" & pids+=($!)
until (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null; do sleep 0.2; done
for i in $(seq 1 "$SLOTS"); do
  "$BIN" executor --scheduler "127.0.0.1:$port" --port "$(free_port)" --grpc-port "$(free_port)" --vcores 1 \
    --work-dir "$work/executor-$i" 2>"$work/executor-$i.log" & pids+=($!)
done
sleep 3 # the executors register
"$BIN" run "$work/specs.parquet" --out "$work/cluster" --policy random --max-steps "$MAX_STEPS" \
  --engine "ballista://127.0.0.1:$port" >/dev/null 2>"$work/cluster.log"
cluster_s=$(wall_of "$work/cluster")
same=$(diff <("$BIN" sql "SELECT * EXCLUDE (wall_s, sim_s, policy_s, render_s, started_at) FROM episodes ORDER BY episode_key" --run "$work/local" --csv) \
            <("$BIN" sql "SELECT * EXCLUDE (wall_s, sim_s, policy_s, render_s, started_at) FROM episodes ORDER BY episode_key" --run "$work/cluster" --csv) >/dev/null && echo yes || echo no)

python3 - "$OUT/overhead.csv" "$episodes" "$SLOTS" "$MAX_STEPS" "$local_s" "$cluster_s" "$same" "$*" <<'PY'
import sys
path, n, slots, cap, local, cluster, same, argv = sys.argv[1:]
n, slots, local, cluster = int(n), int(slots), float(local), float(cluster)
per_episode_ms = (cluster - local) / n * slots * 1000
with open(path, "w") as f:
    f.write(f"# scripts/bench/distributed_overhead.sh {argv}\n")
    f.write("episodes,slots,max_steps,local_wall_s,cluster_wall_s,local_episodes_per_s,cluster_episodes_per_s,overhead_per_episode_slot_ms,rows_equal\n")
    f.write(f"{n},{slots},{cap},{local:.2f},{cluster:.2f},{n/local:.3f},{n/cluster:.3f},{per_episode_ms:.0f},{same}\n")
print(f"{n} episodes, {slots} slots, random policy capped at {cap} policy steps")
print(f"local engine (--jobs {slots}): {local:.1f} s ({n/local:.2f} episodes/s)")
print(f"Ballista, {slots} executors x 1 slot: {cluster:.1f} s ({n/cluster:.2f} episodes/s)")
print(f"overhead: {per_episode_ms:.0f} ms per episode per slot; episode rows equal to the local run's: {same}")
PY
