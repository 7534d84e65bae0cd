#!/usr/bin/env bash
# A small venv for the vla-eval policy test (tests/vla_eval_policy.rs): it runs
# scripts/reference/vla_eval_dummy_server.py, a dummy model behind vla-eval's OWN model server
# (PyPI `vla-eval` 0.8.0: `vla_eval.model_servers.serve`, `.predict`, `vla_eval.protocol.*`).
# No model, no torch, no MuJoCo, no LIBERO: the test proves the Rust client speaks the protocol.
# vla-eval goes in with --no-deps plus only what the server's import path needs (anyio,
# websockets, msgpack, numpy, pillow for the PNG image codec); its CLI and orchestrator
# dependencies (jsonargparse, omegaconf, rich, imageio, ...) are not needed to serve. Every package
# is pinned, the transitive ones too (a `pip freeze` of a fresh install on Python 3.11).
# Cold install (no pip cache): about 8 s on the 2-core CI machine.
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: vla_eval_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/vla_eval_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
"$VENV/bin/pip" install -q --disable-pip-version-check \
  anyio==4.16.0 idna==3.20 typing_extensions==4.16.0 websockets==17.4 msgpack==1.2.4 numpy==2.4.6 pillow==13.0.0
"$VENV/bin/pip" install -q --disable-pip-version-check --no-deps vla-eval==0.8.0
"$VENV/bin/python" -c "import vla_eval.model_servers.serve, vla_eval.model_servers.predict, PIL.Image"
touch "$VENV/.complete-$KEY"
echo "vla-eval venv ready: $VENV"
