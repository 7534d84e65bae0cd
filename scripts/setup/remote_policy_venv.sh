#!/usr/bin/env bash
# A small venv for the remote-policy test (policies/tests/openpi_client.rs): it runs
# scripts/reference/openpi_toy_server.py, a toy policy behind openpi's wire protocol, written with the
# PyPI `openpi-client` package's msgpack-numpy codec (the same module openpi's own
# `WebsocketPolicyServer` imports) and `websockets` (the server library openpi uses).
# No model, no torch, no MuJoCo: the test proves the Rust client speaks the protocol, nothing more.
# Every package is pinned, the transitive ones too (a `pip freeze` of a fresh install on Python 3.11);
# openpi-client 0.1.2 requires numpy<2.
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: remote_policy_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/remote_policy_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
"$VENV/bin/pip" install -q --disable-pip-version-check \
  openpi-client==0.1.2 websockets==17.4 \
  msgpack==1.2.4 numpy==1.26.4 pillow==13.0.0 dm-tree==0.1.10 absl-py==2.5.1 attrs==26.1.0 wrapt==2.5.2
"$VENV/bin/python" -c "import openpi_client.msgpack_numpy, websockets.asyncio.server"
touch "$VENV/.complete-$KEY"
echo "remote-policy venv ready: $VENV"
