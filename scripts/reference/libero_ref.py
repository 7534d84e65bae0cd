"""Import helper for the Python reference LIBERO env (the oracle), used at set-up and in tests only.

The reference venv built by `scripts/setup/reference_venv.sh` holds a non-interactive LIBERO config
and a `torch` stand-in; this module points the environment at them *before* `libero` is imported,
so every oracle script starts with `import libero_ref` and nothing else to remember.
"""
import os
import sys

_VENV = sys.prefix
os.environ.setdefault("LIBERO_CONFIG_PATH", os.path.join(_VENV, "libero_config"))
_SHIMS = os.path.join(_VENV, "shims")
if os.path.isdir(_SHIMS) and _SHIMS not in sys.path:
    sys.path.insert(0, _SHIMS)
os.environ.setdefault("MUJOCO_GL", "egl")

import logging  # noqa: E402

logging.getLogger("robosuite_logs").setLevel(logging.ERROR)

import numpy as np  # noqa: E402,F401
import mujoco  # noqa: E402
from libero.libero import benchmark, get_libero_path  # noqa: E402
from libero.libero.envs.env_wrapper import ControlEnv  # noqa: E402

logging.getLogger("robosuite_logs").setLevel(logging.ERROR)


def task_of(suite: str, task_id: int):
    """(benchmark, task, bddl path) of a suite's task."""
    b = benchmark.get_benchmark_dict()[suite]()
    task = b.get_task(task_id)
    bddl = os.path.join(get_libero_path("bddl_files"), task.problem_folder, task.bddl_file)
    return b, task, bddl


def make_env(bddl: str, **kw) -> ControlEnv:
    """The reference env as the published evaluations build it, without cameras (physics only)."""
    args = dict(use_camera_obs=False, has_offscreen_renderer=False, has_renderer=False)
    args.update(kw)
    return ControlEnv(bddl_file_name=bddl, **args)


def fixture_root_bodies(env) -> list:
    """Root body names of the fixtures, whose poses `reset()` re-samples from numpy's global RNG."""
    return [fx.root_body for fx in env.env.fixtures_dict.values()]


def fixture_poses(env) -> dict:
    m = env.sim.model._model
    out = {}
    for body in fixture_root_bodies(env):
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
        out[body] = dict(pos=m.body_pos[bid].tolist(), quat=m.body_quat[bid].tolist())
    return out


def set_fixture_poses(model, poses: dict):
    for body, pq in poses.items():
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
        model.body_pos[bid] = pq["pos"]
        model.body_quat[bid] = pq["quat"]


def fixture_pose_sequence(env, seed: int, n_episodes: int, xml_poses: dict) -> list:
    """Fixture poses of episodes 0..n-1 after `env.seed(seed)` and one `reset()` per episode.

    A hard reset rebuilds the model (0.7 s); a soft reset with the fixture bodies first put back at
    their XML poses (what a rebuilt model has) makes the same RNG draws in ~10 ms. The set-up
    verifies this equality against real hard resets on a sample (`verify_soft_resets`).
    """
    inner = env.env
    saved = inner.hard_reset
    inner.hard_reset = False
    try:
        env.seed(seed)
        seq = []
        for _ in range(n_episodes):
            set_fixture_poses(env.sim.model._model, xml_poses)
            env.reset()
            seq.append(fixture_poses(env))
        return seq
    finally:
        inner.hard_reset = saved


def hard_reset_pose_sequence(env, seed: int, n_episodes: int) -> list:
    """The same sequence the expensive, canonical way (what OpenVLA/openpi loops do)."""
    assert env.env.hard_reset
    env.seed(seed)
    seq = []
    for _ in range(n_episodes):
        env.reset()
        seq.append(fixture_poses(env))
    return seq
