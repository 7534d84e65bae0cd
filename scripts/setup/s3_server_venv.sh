#!/usr/bin/env bash
# A small venv for the S3 test (tests/cloud_store.rs): moto's S3 server (`python -m moto.server`),
# an S3-compatible endpoint on localhost that `pipeline run --out s3://...` writes a run to, and
# boto3 to look at the bucket independently of object_store. Only moto's S3 backend and the
# server's Flask (not `moto[server]`, which pulls every AWS service's dependencies: 140 MB vs 317 MB).
# Every package is pinned, the transitive ones too (a `pip freeze` of a fresh install on Python 3.11).
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: s3_server_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/s3_server_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
"$VENV/bin/pip" install -q --disable-pip-version-check \
  moto==5.2.5 Flask==3.1.3 flask-cors==6.0.5 \
  blinker==1.9.0 boto3==1.44.5 botocore==1.44.5 certifi==2026.10.18 cffi==2.1.1 charset-normalizer==3.5.2 \
  click==8.5.1 cryptography==50.0.2 idna==3.20 itsdangerous==2.2.0 Jinja2==3.1.6 jmespath==1.1.0 \
  MarkupSafe==3.0.4 py-partiql-parser==0.6.3 pycparser==3.12 python-dateutil==2.9.0.post0 PyYAML==6.0.3 \
  requests==2.34.2 responses==0.26.3 s3transfer==0.19.3 six==1.17.0 urllib3==2.8.0 Werkzeug==3.1.9 \
  xmltodict==1.0.4
"$VENV/bin/python" -c "import moto.server, boto3, flask_cors"
touch "$VENV/.complete-$KEY"
echo "S3 server venv ready: $VENV"
