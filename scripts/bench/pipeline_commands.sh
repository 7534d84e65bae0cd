#!/usr/bin/env bash
# Seconds of the user-facing commands of one pipeline binary on a small real job (the README's main
# job at 150 steps a episode), to compare builds (e.g. the pipeline crate's opt-level):
#   scripts/bench/pipeline_commands.sh BINARY OUT_DIR
# Prints one line per command: seconds and the command. Needs data/bundles (./setup.sh).
set -euo pipefail
P=$1
O=$2
rm -rf "$O"
mkdir -p "$O"
timed() {
  local s
  s=$(date +%s.%N)
  "$P" "$@" >/dev/null 2>"$O/last.err" || { cat "$O/last.err" >&2; exit 1; }
  printf '%7.2f s  %s\n' "$(echo "$(date +%s.%N) - $s" | bc)" "$1"
}
timed specs --suites libero_spatial,libero_object --trials 1 -o "$O/specs.parquet"
timed run "$O/specs.parquet" --out "$O/expert" --policy expert --max-steps 150
timed run "$O/specs.parquet" --out "$O/lift" --policy lift --max-steps 150
timed results --run "$O/expert" --run "$O/lift" --out "$O"
timed smoke --out "$O"
timed report --run "$O/expert" --run "$O/lift" --videos --out "$O"
