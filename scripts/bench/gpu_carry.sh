#!/usr/bin/env bash
# The folder scripts/bench/gpu_end_to_end.sh needs on a GPU machine, made on the build machine
# (under 64 MiB: the device tool carries no more): the stripped pipeline and libmujoco, the task
# bundles of libero_spatial with only the assets they use (all of them, textures included), the
# layout of OpenVLA-7B (scripts/reference/openvla_layout.py; the weights are drawn there) and the
# GL libraries (glvnd's EGL dispatcher) as Debian packages.
#
# With the bench binary of policies/benches/openvla.rs when it is built (`cargo bench -p
# libero-policies --bench openvla --no-run`): scripts/bench/gpu_scaling.sh runs it.
#
# usage: scripts/bench/gpu_carry.sh CARRY   (after cargo build --release and ./setup.sh)
set -euo pipefail
cd "$(dirname "$0")/../.."
carry=$(realpath -m "$1"); mkdir -p "$carry/gl"
target=${CARGO_TARGET_DIR:-target}
strip -o "$carry/pipeline" "$target/release/pipeline"; xz -T0 -9 -f "$carry/pipeline"
bench=$(ls -t "$target"/release/deps/openvla-* 2>/dev/null | grep -v '\.d$' | head -1 || true)
if [ -n "$bench" ]; then strip -o "$carry/openvla-bench" "$bench"; xz -T0 -9 -f "$carry/openvla-bench"; fi
# libmujoco compressed (5.1 MB to ~1.5): with it the bench binary fits beside the pipeline;
# gpu_setup.sh unpacks it into $work/lib
rm -rf "$carry/lib"; xz -T0 -9 -c third_party/mujoco-3.3.7/lib/libmujoco.so.3.3.7 > "$carry/libmujoco.so.3.3.7.xz"
bundles=$(realpath data/bundles)
# every file the suite's provenance hashes, and the folders a relative asset path walks through
python3 - "$bundles" "$carry" <<'PY'
import json, os, sys
bundles, carry = sys.argv[1:]
files, dirs = {"index.json"}, set()
for task in sorted(os.listdir(os.path.join(bundles, "libero_spatial"))):
    t = os.path.join("libero_spatial", task)
    files.update(os.path.join(t, f) for f in os.listdir(os.path.join(bundles, t)))
    for v in json.load(open(os.path.join(bundles, t, "provenance.json")))["sha256"].values():
        for a in v if isinstance(v, dict) else []:
            path = os.path.join("assets", a)
            files.add(os.path.normpath(path))
            parts = path.split("/")
            dirs.update("/".join(parts[:i]) for i in range(1, len(parts)) if ".." not in parts[:i])
open(os.path.join(carry, "files.txt"), "w").write("\n".join(sorted(files)) + "\n")
open(os.path.join(carry, "dirs.txt"), "w").write("\n".join(sorted(dirs)) + "\n")
PY
tar -chf - -C "$bundles" -T "$carry/files.txt" -C "$carry" dirs.txt | xz -T0 -9 > "$carry/bundles.tar.xz"
rm "$carry/files.txt" "$carry/dirs.txt"
[ -f /tmp/openvla-7b-layout/layout.json ] || "$(ls -d "${LIBERO_EVAL_CACHE:-$HOME/.cache/libero-eval}"/openvla-venv-* | head -1)/bin/python" scripts/reference/openvla_layout.py /tmp/openvla-7b-layout
mkdir -p "$carry/openvla-7b"; cp /tmp/openvla-7b-layout/* "$carry/openvla-7b/"
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
mkdir -p /tmp/amd64/partial; apt-get $o update -qq
(cd "$carry/gl" && apt-get $o download -qq libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 2>/dev/null)
du -sh "$carry"; du -sh "$carry"/*
