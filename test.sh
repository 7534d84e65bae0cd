#!/usr/bin/env bash
# The README's test command: the tests' own set-up, then every test of the workspace.
#   ./setup.sh --tests   the set-up's steps (cached: seconds), and what only the tests need: the oracle
#                        venvs, ALOHA-sim, golden trajectories, reference frames, the perturbation
#                        suites' reference episodes; the test binaries compile beside them;
#   cargo test --release with this script's arguments, e.g. ./test.sh --test e2e parity::
# Once set up, `cargo test --release` alone runs the same tests.
set -euo pipefail
cd "$(dirname "$0")"
./setup.sh --tests
echo "==> cargo test --release $*"
exec cargo test --release "$@"
