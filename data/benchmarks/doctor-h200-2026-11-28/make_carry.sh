#!/usr/bin/env bash
# The folder device.sh needs on the GPU machine, made on the build machine (under 64 MiB): the
# stripped pipeline, libmujoco, libero_spatial task 0's bundle with the assets it uses, the tiny
# random-weight OpenVLA of the parity tests (scripts/reference/openvla_tiny.py) and glvnd's EGL
# dispatcher as Debian packages.
# usage: make_carry.sh CARRY   (after cargo build --release and ./setup.sh)
set -euo pipefail
cd "$(dirname "$0")/../../.."
carry=$(realpath -m "$1"); mkdir -p "$carry/gl"
target=${CARGO_TARGET_DIR:-target}
strip -o "$carry/pipeline" "$target/release/pipeline"; xz -T0 -9 -f "$carry/pipeline"
xz -T0 -9 -c third_party/mujoco-3.3.7/lib/libmujoco.so.3.3.7 > "$carry/libmujoco.so.3.3.7.xz"
bundles=$(realpath data/bundles)
python3 - "$bundles" "$carry" <<'PY'
import json, os, sys
bundles, carry = sys.argv[1:]
index = json.load(open(os.path.join(bundles, "index.json")))
index["tasks"] = [t for t in index["tasks"] if t["suite"] == "libero_spatial" and t["task_id"] == 0]
json.dump(index, open(os.path.join(carry, "index.json"), "w"))
t = index["tasks"][0]["path"]
files, dirs = {os.path.join(t, f) for f in os.listdir(os.path.join(bundles, t))}, set()
for v in json.load(open(os.path.join(bundles, t, "provenance.json")))["sha256"].values():
    for a in v if isinstance(v, dict) else []:
        path = os.path.join("assets", a)
        files.add(os.path.normpath(path))
        # the folders a relative asset path walks through (`scenes/../textures/x.png`)
        parts = path.split("/")
        dirs.update("/".join(parts[:i]) for i in range(1, len(parts)) if ".." not in parts[:i])
open(os.path.join(carry, "files.txt"), "w").write("\n".join(sorted(files)) + "\n")
open(os.path.join(carry, "dirs.txt"), "w").write("\n".join(sorted(dirs)) + "\n")
PY
tar -chf - -C "$bundles" -T "$carry/files.txt" -C "$carry" index.json dirs.txt | xz -T0 -9 > "$carry/bundles.tar.xz"
rm "$carry/files.txt" "$carry/index.json" "$carry/dirs.txt"
# the tiny OpenVLA, made smaller for the carry: one bf16 shard, the LM head tied to the embeddings
# (its 32064-token vocabulary is most of its weights)
py="$(ls -d "${LIBERO_EVAL_CACHE:-$HOME/.cache/libero-eval}"/openvla-venv-* | head -1)/bin/python"
if [ ! -f "$carry/openvla-tiny/model.safetensors" ]; then
  rm -rf "$carry/openvla-tiny"
  "$py" scripts/reference/openvla_tiny.py "$carry/openvla-tiny" > /dev/null
  (cd "$carry/openvla-tiny" && "$py" - <<'PY'
import json, os, torch
from safetensors.torch import load_file, save_file
index = json.load(open("model.safetensors.index.json"))
state = {}
for f in sorted(set(index["weight_map"].values())):
    state.update(load_file(f))
    os.remove(f)
del state["language_model.lm_head.weight"]
state = {k: (v.to(torch.bfloat16) if v.is_floating_point() else v).contiguous() for k, v in state.items()}
save_file(state, "model.safetensors", metadata={"format": "pt"})
os.remove("model.safetensors.index.json")
config = json.load(open("config.json"))
config["text_config"]["tie_word_embeddings"] = True
json.dump(config, open("config.json", "w"), indent=2)
PY
  )
fi
rm -rf "$carry/openvla-tiny/reference"
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
mkdir -p /tmp/amd64/partial; apt-get $o update -qq
(cd "$carry/gl" && apt-get $o download -qq libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 2>/dev/null)
du -sh "$carry"; du -sh "$carry"/*
