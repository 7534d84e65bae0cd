"""Add to built LIBERO bundles the fixture poses of env seeds set right before one hard reset
(lerobot's LIBERO protocol), checked against the reference env (set-up time only).

usage: seeded_fixtures.py BUNDLES [--tasks libero_spatial,libero_goal/03,...] [--seeds 1000-1049]
                          [--verify 2] [--jobs J]

lerobot-eval (lerobot 0.6.1, `envs/libero.py` `LiberoEnv.reset`) seeds the env at *every* reset:
episode k of a task runs `env.seed(1000 + k)`, one hard `reset()`, then
`set_init_state(init_states[k])`. The bundles' `fixtures.json` holds the poses of the OpenVLA/openpi
loops instead (`env.seed(s)` once per task, episode k after k+1 resets). This script records, per
task, the fixture root-body poses after `env.seed(s)` and the first hard `reset()` of a freshly
built env, for every seed asked, into `OUT/<suite>/<NN>/fixtures_seeded.json`, and their sha256,
seeds and checks into the task's `provenance.json` under `seeded_at_reset` (the pipeline reads the
file only when that record is there and the hash matches).

The poses are computed by the cheap exact path (`libero_ref.fixture_pose_sequence`: a soft reset
that makes a rebuilt model's draws) and checked bit for bit against the real thing for `--verify`
seeds per task (the first and last asked, then spread): a fresh env, `env.seed(s)`, one hard
`reset()`, as lerobot's `LiberoEnv.reset` makes them. Any difference stops the set-up.

A separate script (not `build_bundles.py`) so that recording lerobot's seeds neither rebuilds the
bundles nor changes what the canonical protocol's runs hash (the bundle cache key, fixtures.json).

Scope: lerobot-eval runs a task's episodes on `batch_size` sub-envs, each built once and reset once
per episode it runs, so episode k is its sub-env's (k // batch_size + 1)-th reset. LIBERO appends
object-property samplers at every model load (`libero_ref.published_property_samplers`), which draw
before the fixtures are placed in the four canonical tasks whose `:init` sets an articulated object
(libero_spatial 4, libero_10 3, 8, 9): for those, the poses recorded here are lerobot's when the
episode is its sub-env's first reset (k < batch_size, e.g. batch_size >= n_episodes); for every other
task they are lerobot's whatever the batch size.
"""
import argparse
import hashlib
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

import libero_ref as L
from build_bundles import _write, max_pose_diff


def parse_seeds(text):
    """`1000-1049`, `1000,1001` or a mix."""
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return sorted(set(out))


def verified_seeds(seeds, n):
    """The seeds checked by the real loop: the first, the last, then spread between."""
    if n <= 0 or not seeds:
        return []
    if n == 1:
        return [seeds[0]]
    picks = {seeds[round(i * (len(seeds) - 1) / (n - 1))] for i in range(n)}
    return sorted(picks)


def seeded_task(job):
    out, suite, task_id, seeds, n_verify = job
    t0 = time.time()
    folder = os.path.join(out, suite, f"{task_id:02d}")
    prov_path = os.path.join(folder, "provenance.json")
    prov = json.load(open(prov_path))
    done = prov.get("seeded_at_reset") or {}
    if set(seeds) <= set(done.get("seeds", [])) and os.path.exists(os.path.join(folder, "fixtures_seeded.json")):
        return dict(suite=suite, task_id=task_id, skipped=True)
    seeds = sorted(set(seeds) | set(done.get("seeds", [])))
    task_json = json.load(open(os.path.join(folder, "task.json")))
    xml_poses = task_json["fixture_xml_poses"]
    _, _, bddl = L.task_of(suite, task_id)
    env = L.make_env(bddl)
    try:
        poses = {str(s): L.fixture_pose_sequence(env, s, 1, xml_poses)[0] for s in seeds}
        samplers = len(getattr(env, L.PROPERTY_SAMPLERS_PER_LOAD))
    finally:
        env.close()
    t_verify = time.time()
    checked = verified_seeds(seeds, n_verify)
    worst = 0.0
    for s in checked:
        # lerobot's LiberoEnv.reset on a freshly built env: env.seed(s), one hard reset()
        real = L.published_loop_pose_sequence(bddl, s, 1)[0]
        worst = max(worst, max_pose_diff(poses[str(s)], real))
    if worst != 0.0:
        raise SystemExit(f"{suite} task {task_id}: fixture poses after env.seed(s) and one hard reset differ "
                         f"from the reference env's by {worst} (seeds {checked})")
    text = json.dumps(dict(
        doc="fixture root-body poses after env.seed(seed) and the first hard reset() of a freshly built env "
            "(lerobot-eval's LIBERO protocol: seeded at every reset); quat is (w,x,y,z)",
        seeds=poses))
    _write(os.path.join(folder, "fixtures_seeded.json"), text)
    prov["seeded_at_reset"] = dict(
        sha256=hashlib.sha256(text.encode()).hexdigest(), seeds=seeds,
        checks=dict(reference_hard_reset_seeds=checked, max_abs_diff=worst,
                    property_samplers_per_load=samplers, seconds=round(time.time() - t_verify, 2)),
        built_seconds=round(time.time() - t0, 2))
    _write(prov_path, json.dumps(prov, indent=1))
    return dict(suite=suite, task_id=task_id, seeds=len(seeds), verified=checked, secs=round(time.time() - t0, 1))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", help="the bundles folder (data/bundles), already built")
    ap.add_argument("--tasks", default="libero_spatial,libero_object,libero_goal,libero_10",
                    help="base suites and single tasks (libero_goal/03); their bundles must be built")
    ap.add_argument("--seeds", default="1000-1049", help="env seeds (lerobot-eval: 1000 + episode index)")
    ap.add_argument("--verify", type=int, default=2,
                    help="seeds per task checked against the reference env's real hard reset")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    seeds = parse_seeds(args.seeds)
    tasks = L.selected_tasks("", args.tasks)
    for suite, _ in tasks:
        if L.suite_parts(suite)[1] is not None:
            raise SystemExit(f"{suite}: lerobot evaluates the LIBERO suites; seeded fixture poses are for those only")
    t0 = time.time()
    jobs = [(args.out, suite, task_id, seeds, args.verify) for suite, task_id in tasks]
    with ProcessPoolExecutor(max_workers=min(args.jobs, len(jobs))) as ex:
        for future in as_completed([ex.submit(seeded_task, job) for job in jobs]):
            print(json.dumps(future.result()), flush=True)
    print(f"seeded fixture poses for {len(jobs)} tasks in {time.time() - t0:.1f} s -> {args.out}")


if __name__ == "__main__":
    main()
