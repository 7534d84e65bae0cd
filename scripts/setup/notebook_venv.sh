#!/usr/bin/env bash
# A small venv for the notebook (notebooks/libero_eval.py): polars and pyarrow to read a run's Parquet,
# matplotlib for the plots, jupytext + nbclient + ipykernel (+ nbconvert, which `jupytext --execute` calls) to
# execute it headless (the notebook test).
# No Rust, no MuJoCo, nothing of the reference env: a run's tables are all the notebook reads.
# Every package is pinned, the transitive ones too (a `pip freeze` of a fresh install on Python 3.11).
# Idempotent: a stamp keyed by this file's hash skips the install when nothing changed.
set -euo pipefail
VENV="${1:?usage: notebook_venv.sh VENV_DIR}"
HERE="$(cd "$(dirname "$0")" && pwd)"
KEY=$(sha256sum "$HERE/notebook_venv.sh" | cut -c1-16)
if [ -f "$VENV/.complete-$KEY" ]; then exit 0; fi
rm -rf "$VENV"
python3 -m venv "$VENV"
"$VENV/bin/pip" install -q --disable-pip-version-check \
  polars==1.33.1 pyarrow==21.0.0 matplotlib==3.11.2 \
  jupytext==1.19.6 nbclient==0.11.0 nbformat==5.11.1 ipykernel==7.4.0 nbconvert==7.17.2 \
  asttokens==3.0.2 attrs==26.1.0 comm==0.2.3 contourpy==1.3.3 cycler==0.12.1 debugpy==1.8.22 \
  executing==2.3.0 fastjsonschema==2.22.3 fonttools==4.68.0 ipython==9.18.1 ipython_pygments_lexers==1.1.1 \
  jedi==0.20.1 jsonschema==4.26.0 jsonschema-specifications==2025.9.1 jupyter_client==8.10.0 \
  jupyter_core==5.9.1 kiwisolver==1.5.1 markdown-it-py==4.3.0 matplotlib-inline==0.2.2 mdit-py-plugins==0.7.0 \
  mdurl==0.1.2 nest-asyncio2==1.7.4 numpy==2.4.6 packaging==26.3 parso==0.8.7 pexpect==4.9.0 pillow==13.0.0 \
  platformdirs==4.14.7 prompt_toolkit==3.0.53 psutil==7.2.2 ptyprocess==0.7.0 pure_eval==0.2.4 Pygments==2.21.0 \
  pyparsing==3.3.3 python-dateutil==4.0.0 PyYAML==6.0.3 pyzmq==27.3.0 referencing==0.37.0 rpds-py==2026.9.1 \
  stack-data==0.6.3 tornado==6.6.1 traitlets==5.16.1 typing_extensions==4.16.0 tzdata==2026.6 wcwidth==0.9.4 \
  beautifulsoup4==4.15.0 bleach==6.4.0 defusedxml==0.7.1 Jinja2==3.1.6 jupyterlab_pygments==0.3.0 MarkupSafe==3.0.4 \
  mistune==3.4.0 pandocfilters==1.5.1 soupsieve==4.1.2 tinycss2==1.5.1 webencodings==0.6.1
# The notebook's kernel is this venv's Python (`python3` kernelspec), whoever runs jupytext.
"$VENV/bin/python" -m ipykernel install --prefix "$VENV" --name python3 --display-name "Python 3 (libero-eval notebook)" >/dev/null
touch "$VENV/.complete-$KEY"
echo "notebook venv ready: $VENV"
