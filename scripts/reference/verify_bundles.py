"""Check every recorded fixture pose of built bundles against the published loop, in full.

usage: verify_bundles.py BUNDLES [--suites libero_spatial,...] [--tasks libero_10/09,...] [--jobs J]

The set-up (build_bundles.py) checks each task and seed on a spread of episodes. This command runs
the published loop itself for every recorded episode: per task and seed, a freshly constructed
reference env, `env.seed(seed)`, then one hard `reset()` per episode (50 resets, 0.6-1.7 s each),
comparing the fixture root-body poses with `fixtures.json` bit for bit. It records the result in
each bundle's `provenance.json` under `checks.published_loop_full` (which the run's bundle identity
ignores: checks describe a bundle, they do not change it) and exits non-zero on any difference.
On 2 cores the four canonical suites take about 25 minutes.
"""
import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import libero_ref as L
from build_bundles import _write, max_pose_diff


def check(job):
    root, path, seed = job
    task = json.load(open(os.path.join(root, path, "task.json")))
    recorded = json.load(open(os.path.join(root, path, "fixtures.json")))["seeds"][str(seed)]
    bddl = os.path.join(L.get_libero_path("bddl_files"), task["bddl_file"])
    t0 = time.time()
    loop = L.published_loop_pose_sequence(bddl, seed, len(recorded))
    diffs = [max_pose_diff(a, b) for a, b in zip(recorded, loop)]
    differing = [k for k, d in enumerate(diffs) if d != 0.0]
    row = dict(path=path, seed=seed, episodes=len(loop), differing_episodes=differing,
               max_abs_diff=max(diffs, default=0.0), seconds=round(time.time() - t0, 1))
    print(json.dumps(row), flush=True)
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bundles")
    ap.add_argument("--suites", help="comma-separated; default: every suite in index.json")
    ap.add_argument("--tasks", help="comma-separated bundle paths (suite/NN); default: every task of the suites")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    only = set(args.tasks.split(",")) if args.tasks else None
    index = json.load(open(os.path.join(args.bundles, "index.json")))
    suites = set(args.suites.split(",")) if args.suites else {t["suite"] for t in index["tasks"]}
    jobs = []
    for t in index["tasks"]:
        if t["suite"] in suites and (only is None or t["path"] in only):
            seeds = json.load(open(os.path.join(args.bundles, t["path"], "task.json")))["fixture_seeds"]
            jobs += [(args.bundles, t["path"], s) for s in seeds]
    t0 = time.time()
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        rows = list(ex.map(check, jobs))
    by_path = {}
    for r in rows:
        by_path.setdefault(r["path"], []).append(r)
    for path, checks in by_path.items():
        prov_path = os.path.join(args.bundles, path, "provenance.json")
        prov = json.load(open(prov_path))
        prov["checks"]["published_loop_full"] = dict(
            seeds=[c["seed"] for c in checks], episodes=checks[0]["episodes"],
            differing_episodes={str(c["seed"]): c["differing_episodes"] for c in checks},
            max_abs_diff=max(c["max_abs_diff"] for c in checks), seconds=sum(c["seconds"] for c in checks),
            checked_at=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
        _write(prov_path, json.dumps(prov, indent=1))
    bad = [r for r in rows if r["differing_episodes"]]
    n_eps = sum(r["episodes"] for r in rows)
    print(f"{len(by_path)} tasks, {len(rows)} (task, seed) loops, {n_eps} episodes checked by real hard resets "
          f"in {time.time() - t0:.0f} s: {len(bad)} loops differ", file=sys.stderr)
    for r in bad:
        print(f"  {r['path']} seed {r['seed']}: episodes {r['differing_episodes']} differ by up to "
              f"{r['max_abs_diff']}", file=sys.stderr)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
