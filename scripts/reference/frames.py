"""Record camera frames from the reference env for the Rust render-parity tests (set-up time).

usage: frames.py OUT [--suites ...] [--tasks 0,1,...|all|suite/NN,...] [--inits 0] [--steps 0,40] [--golden DIR]
                 [--cameras agentview,robot0_eye_in_hand] [--size 256] [--also-size 360 --also-tasks 0] [--jobs J]

For each task and init state k the scene is episode k after env.seed(0) (the fixture poses the
Rust env's reset(k, 0) uses), then for each listed step s the sim state is set and the reference
renders its cameras exactly as the published loops get them (`OffScreenRenderEnv` observations):
  s = 0   the init state (after `set_init_state`, no step taken)
  s > 0   the golden trajectory's state after step s (`--golden`, recorded by golden.py)
Frames are saved as `OUT/<suite>__<NN>__init<k>__s<SSS>__<camera>.png` in the *reference
orientation* (OpenGL row order, as `obs[...]` holds them; they look upside down), plus
`OUT/meta.json` with the MuJoCo version that rendered them.

`--also-size S --also-tasks T` also renders the tasks T (of this call's) at S x S, init state
`--inits`' first, every listed step, into `OUT/S/` (same names): lerobot-eval's LIBERO env asks for
360 x 360 cameras. They come from the same env and state, through the call robosuite's camera
observable makes (`sim.render(camera_name, width, height, depth=False)`, rows in the
`IMAGE_CONVENTION` order): bit-identical to the observations of an env made at that size (checked
on libero_spatial task 0, both cameras, MuJoCo 3.2.3), without a second env and its resets.

Which MuJoCo renders is the venv's: the main reference venv (3.3.7, the linked library) or the
published stack's venv (3.2.3, `scripts/setup/reference_venv_mujoco323.sh`).
"""
import argparse
import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import libero_ref as L
from libero_ref import mujoco, np

from PIL import Image
from robosuite import macros
from robosuite.utils.mjcf_utils import IMAGE_CONVENTION_MAPPING

SEED = 0


def record(job):
    suite, task_id, inits, steps, cameras, size, also_size, golden, out = job
    b, task, bddl = L.task_of(suite, task_id)
    env = L.make_env(bddl, has_offscreen_renderer=True, use_camera_obs=True, camera_names=cameras,
                     camera_heights=size, camera_widths=size)
    init_states = L.task_init_states(suite, task_id)
    written = 0
    convention = IMAGE_CONVENTION_MAPPING[macros.IMAGE_CONVENTION]
    # The published loop: env.seed(SEED) once, one hard reset per episode; episode k is the
    # (k+1)-th reset (its fixture poses depend on every reset before it).
    assert env.env.hard_reset
    env.seed(SEED)
    for k in range(max(inits) + 1):
        env.reset()
        if k not in inits:
            continue
        for s in steps:
            if s == 0:
                state = init_states[k]
            else:
                states = np.load(os.path.join(golden, f"{suite}__{task_id:02d}__init{k}", "states.npy"))
                state = states[s - 1]
            obs = env.set_init_state(state)
            for cam in cameras:
                img = np.asarray(obs[f"{cam}_image"], dtype=np.uint8)
                name = f"{suite}__{task_id:02d}__init{k}__s{s:03d}__{cam}.png"
                Image.fromarray(img).save(os.path.join(out, name))
                written += 1
                if also_size and k == inits[0]:
                    img = env.env.sim.render(camera_name=cam, width=also_size, height=also_size, depth=False)
                    Image.fromarray(np.asarray(img[::convention], dtype=np.uint8)).save(
                        os.path.join(out, str(also_size), name))
                    written += 1
    env.close()
    return written


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--suites", default="libero_spatial,libero_object,libero_goal,libero_10")
    ap.add_argument("--tasks", default="0")
    ap.add_argument("--inits", default="0")
    ap.add_argument("--steps", default="0")
    ap.add_argument("--golden", default=None)
    ap.add_argument("--cameras", default="agentview,robot0_eye_in_hand")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--also-size", type=int, default=None)
    ap.add_argument("--also-tasks", default=None)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    steps = [int(x) for x in args.steps.split(",")]
    if any(s > 0 for s in steps) and not args.golden:
        sys.exit("frames.py: steps > 0 need --golden (the golden trajectories' states)")
    os.makedirs(args.out, exist_ok=True)
    if args.also_size:
        os.makedirs(os.path.join(args.out, str(args.also_size)), exist_ok=True)
    tasks = L.selected_tasks(args.suites, args.tasks)
    also = set(L.selected_tasks(args.suites, args.also_tasks or args.tasks)) if args.also_size else set()
    if not also <= set(tasks):
        sys.exit(f"frames.py: --also-tasks outside --tasks: {sorted(also - set(tasks))}")
    inits = [int(x) for x in args.inits.split(",")]
    cameras = args.cameras.split(",")
    jobs = []
    for s, t in tasks:
        also_size = args.also_size if (s, t) in also else None
        jobs.append((s, t, inits, steps, cameras, args.size, also_size, args.golden, args.out))
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        n = sum(ex.map(record, jobs))
    meta = dict(mujoco=mujoco.__version__, size=args.size, seed=SEED, orientation="reference (OpenGL rows)")
    json.dump(meta, open(os.path.join(args.out, "meta.json"), "w"))
    if args.also_size:
        json.dump(dict(meta, size=args.also_size), open(os.path.join(args.out, str(args.also_size), "meta.json"), "w"))
    print(f"{n} frames from mujoco {mujoco.__version__} -> {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
