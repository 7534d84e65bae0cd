"""Build the ALOHA-sim bundle and its reference episodes from the gym-aloha 0.1.5 PyPI wheel, in the
oracle venv (scripts/setup/aloha_ref_venv.sh: dm-control 1.0.34, mujoco 3.3.7, numpy 1.26.4).

OUT/
  assets/               the two joint-space task XMLs and their end-effector twins (mocap-welded grippers, where
                        the Rust scripted control records ACT's scripts), scene.xml, vx300s_*.xml and the STLs they reference,
                        byte-identical to the wheel's (the Rust env compiles these files; nothing is generated)
  provenance.json       the wheel (version, sha256), the oracle's versions, the control arithmetic, the sha256
                        of every file above and below (libero_sim::aloha::AlohaBundle checks them on open)
  reference_model.json  per task, the compiled model of the real env (dm_control's Physics on 3.3.7): sizes,
                        options, parameter arrays (the model-equality test); the bundle's files compile to it
  init_poses.json       per task and protocol seed, qpos[16:] as gym_aloha.utils draws it (RandomState(seed)):
                        lerobot's seeds 1000..1049 and openpi's first 50 (default_rng(0).integers(2**32 - 1))
  golden/               reference episodes of the REAL env, gymnasium.make(gym_aloha/..., pixels_agent_pos),
                        2 seeds x 2 tasks, fixed f32 actions: seed 1000 a scripted grasp (IK, every reward level),
                        seed 1001 a random walk (manifest.json lists them, with their rewards); per episode:
                          actions.npy            (T, 14) float32, what a policy sends
                          qpos/qvel/ctrl.npy     (T+1, n) float64, after reset then after every step
                          agent_pos.npy          (T+1, 14) float64, obs["agent_pos"]
                          reward.npy             (T, 1) float64, the reward of every step
                          top_sNNN.npy           (480, 640, 3) uint8, obs["pixels"]["top"] after step NNN (0: reset)

The env renders three cameras at every step (get_observation); here `Physics.render` draws only the `top`
frames recorded and returns zeros otherwise. Rendering reads the state and never changes it, and it is
most of the env's cost on a CPU.

Usage: python aloha_bundle.py OUT [--wheel WHEEL] [--steps 400]
"""
import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from importlib.metadata import version

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import mujoco
import numpy as np
from dm_control.mujoco import Physics

import gym_aloha  # noqa: F401  (registers the gymnasium ids)
import gym_aloha.utils as gu
from gym_aloha.constants import START_ARM_POSE

WHEEL = "gym_aloha-0.1.5-py3-none-any.whl"
WHEEL_SHA256 = "1794dd9a1146268a9b56f4a4931bcba69ca27714c2ac9ac146e471801bf0c7b3"
TASKS = {  # keep equal to libero_sim::aloha::AlohaTask
    "transfer_cube": ("bimanual_viperx_transfer_cube.xml", "gym_aloha/AlohaTransferCube-v0"),
    "insertion": ("bimanual_viperx_insertion.xml", "gym_aloha/AlohaInsertion-v0"),
}
LEROBOT_SEEDS = list(range(1000, 1050))  # lerobot-eval: seed 1000, episode i gets 1000 + i (aloha-sim.md §3)
OPENPI_EPISODES = 50  # openpi's aloha_sim: default_rng(0), each reset seeded int(rng.integers(2**32 - 1))
GOLDEN = ((1000, "scripted"), (1001, "random_walk"))  # (seed, actions) per task
# Compiled-model fields compared by libero_sim::scene::compare_with_reference (keep equal to
# build_bundles.py's MODEL_SIZES / MODEL_OPTIONS / MODEL_ARRAYS).
MODEL_SIZES = ["nq", "nv", "nu", "na", "nbody", "njnt", "ngeom", "nsite", "nmesh", "ntex", "nmat", "ncam", "nlight"]
MODEL_OPTIONS = ["timestep", "density", "viscosity", "impratio", "tolerance", "iterations", "integrator", "cone", "solver"]
MODEL_ARRAYS = [
    "body_parentid", "body_pos", "body_quat", "body_ipos", "body_iquat", "body_mass", "body_inertia",
    "jnt_type", "jnt_qposadr", "jnt_dofadr", "jnt_range", "jnt_stiffness", "dof_damping", "dof_armature",
    "dof_frictionloss", "geom_type", "geom_bodyid", "geom_group", "geom_contype", "geom_conaffinity",
    "geom_size", "geom_friction", "geom_solref", "geom_solimp", "geom_pos", "geom_quat",
    "actuator_ctrlrange", "actuator_gainprm", "actuator_biasprm", "actuator_forcerange",
    "site_pos", "site_size", "cam_pos", "cam_quat", "cam_fovy", "qpos0",
]
START = np.array(START_ARM_POSE, dtype=np.float64)


def sha256_bytes(b):
    return hashlib.sha256(b).hexdigest()


def sha256_file(path):
    with open(path, "rb") as f:
        return sha256_bytes(f.read())


def get_wheel(path):
    """The wheel: the given file, or `pip download --no-deps gym-aloha==0.1.5` into a temporary folder."""
    tmp = None
    if path is None:
        tmp = tempfile.mkdtemp(prefix="gym-aloha-")
        subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
                        "gym-aloha==0.1.5", "-d", tmp], check=True)
        path = os.path.join(tmp, WHEEL)
    with open(path, "rb") as f:
        data = f.read()
    if tmp:
        shutil.rmtree(tmp)
    got = sha256_bytes(data)
    if got != WHEEL_SHA256:
        sys.exit(f"{path}: sha256 {got}, expected gym-aloha 0.1.5's {WHEEL_SHA256}")
    return data


def copy_assets(wheel_bytes, out):
    """The task XMLs and everything they include or load, byte-identical; returns {relative path: sha256}."""
    import io
    z = zipfile.ZipFile(io.BytesIO(wheel_bytes))
    prefix = "gym_aloha/assets/"
    # the joint-space scenes, and their end-effector twins (mocap-welded grippers) that the Rust
    # scripted control records ACT's scripts in
    todo = [xml for xml, _ in TASKS.values()] + [f"bimanual_viperx_end_effector_{t}.xml" for t in TASKS]
    done = {}
    while todo:
        name = todo.pop()
        if name in done:
            continue
        data = z.read(prefix + name)
        done[name] = data
        if name.endswith(".xml"):
            todo.extend(re.findall(r'\bfile="([^"]+)"', data.decode()))
    expected = {"scene.xml", "vx300s_dependencies.xml", "vx300s_left.xml", "vx300s_right.xml", "tabletop.stl"}
    assert expected <= set(done), sorted(done)
    os.makedirs(os.path.join(out, "assets"))
    for name, data in sorted(done.items()):
        with open(os.path.join(out, "assets", name), "wb") as f:
            f.write(data)
    return {f"assets/{n}": sha256_bytes(d) for n, d in sorted(done.items())}


def model_record(m):
    return dict(
        sizes={k: int(getattr(m, k)) for k in MODEL_SIZES},
        options={k: (float(getattr(m.opt, k)) if k in ("timestep", "density", "viscosity", "impratio", "tolerance")
                     else int(getattr(m.opt, k))) for k in MODEL_OPTIONS},
        arrays={k: np.asarray(getattr(m, k)).tolist() for k in MODEL_ARRAYS},
        names=dict(
            bodies=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(m.nbody)],
            geoms=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, i) for i in range(m.ngeom)],
            cameras=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(m.ncam)],
            actuators=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(m.nu)],
        ),
    )


def make_env(task, steps):
    return gym.make(TASKS[task][1], obs_type="pixels_agent_pos", max_episode_steps=steps)


def physics_of(env):
    return env.unwrapped._env.physics


def reference_models(out):
    """The real env's compiled models; the bundle's copied files must compile to the same arrays."""
    models = {}
    for task, (xml, _) in TASKS.items():
        env = make_env(task, 1)
        live = physics_of(env).model.ptr
        ours = mujoco.MjModel.from_xml_path(os.path.join(out, "assets", xml))
        rec, ours_rec = model_record(live), model_record(ours)
        assert rec == ours_rec, f"{task}: the bundle's files compile to another model than the env's"
        models[task] = rec
        env.close()
    return models


def init_poses():
    rng = np.random.default_rng(seed=0)
    openpi = [int(rng.integers(2**32 - 1)) for _ in range(OPENPI_EPISODES)]
    assert openpi[:2] == [3653403230, 2735729614], openpi[:2]  # aloha-sim.md §3
    seeds = sorted(set(LEROBOT_SEEDS + openpi))
    tasks = {
        "transfer_cube": {str(s): gu.sample_box_pose(s).tolist() for s in seeds},
        "insertion": {str(s): np.concatenate(gu.sample_insertion_pose(s)).tolist() for s in seeds},
    }
    return dict(
        doc="qpos[16:] (position, then quaternion w,x,y,z, per object: the cube; or the peg then the socket) that "
            "gym_aloha.utils.sample_box_pose / sample_insertion_pose draw for each seed (np.random.RandomState(seed))",
        tasks=tasks, protocols=dict(lerobot=LEROBOT_SEEDS, openpi=openpi))


def qaxis(axis, deg):
    th = np.deg2rad(deg)
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(th / 2)], np.sin(th / 2) * axis])


def quat_mat(q):
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, q / np.linalg.norm(q))
    return r.reshape(3, 3)


def waypoints(task, objs):
    """(step, pinch point, world rotation from the start orientation, gripper) per arm: ACT's scripted policies'
    shape (pick, lift, meet, hand over; or pick both, meet, insert), re-targeted to the point between the
    fingers and to where the objects rest, so a joint-space replay of the IK grasps (reward 1..4)."""
    ident = np.array([1.0, 0, 0, 0])
    if task == "transfer_cube":
        box = objs[:3] * [1, 1, 0] + [0, 0, 0.02]
        pick, meetq, meet = qaxis([0, 1, 0], -60), qaxis([1, 0, 0], 90), np.array([0, 0.5, 0.25])
        left = [(0, None, ident, 0), (100, meet + [-0.12, 0, -0.05], meetq, 1), (240, meet + [-0.12, 0, -0.05], meetq, 1),
                (280, meet + [0, 0, -0.05], meetq, 1), (310, meet + [0, 0, -0.05], meetq, 0),
                (360, meet + [-0.1, 0, -0.05], ident, 0), (400, meet + [-0.1, 0, -0.05], ident, 0)]
        right = [(0, None, ident, 0), (90, box + [0, 0, 0.08], pick, 1), (130, box + [0, 0, 0.005], pick, 1),
                 (170, box + [0, 0, 0.005], pick, 0), (200, meet + [0.05, 0, 0], pick, 0),
                 (220, meet + [0.03, 0, 0], pick, 0), (310, meet + [0.03, 0, 0], pick, 0),
                 (330, meet + [0.03, 0, 0], pick, 1), (360, meet + [0.12, 0, 0], pick, 1),
                 (400, meet + [0.12, 0, 0], pick, 1)]
    else:
        peg, sock = objs[:3] * [1, 1, 0] + [0, 0, 0.015], objs[7:10] * [1, 1, 0] + [0, 0, 0.02]
        qr, ql, meet, lift = qaxis([0, 1, 0], -60), qaxis([0, 1, 0], 60), np.array([0, 0.5, 0.15]), 0.00715
        left = [(0, None, ident, 0), (120, sock + [0, 0, 0.08], ql, 1), (170, sock, ql, 1), (220, sock, ql, 0),
                (285, meet + [-0.1, 0, 0], ql, 0), (340, meet + [-0.02, 0, 0], ql, 0), (400, meet + [-0.02, 0, 0], ql, 0)]
        right = [(0, None, ident, 0), (120, peg + [0, 0, 0.08], qr, 1), (170, peg, qr, 1), (220, peg, qr, 0),
                 (285, meet + [0.1, 0, lift], qr, 0), (340, meet + [0.02, 0, lift], qr, 0),
                 (400, meet + [0.02, 0, lift], qr, 0)]
    return left, right


def interp(ws, t):
    for (t0, x0, q0, g0), (t1, x1, q1, g1) in zip(ws, ws[1:]):
        if t0 <= t <= t1:
            f = (t - t0) / (t1 - t0)
            return x0 + (x1 - x0) * f, q0 + (q1 - q0) * f, g0 + (g1 - g0) * f
    return ws[-1][1:]


def scripted_actions(task, m, objs, steps):
    """Joint targets from damped least-squares IK of the waypoints (pinch point and orientation of each gripper,
    forearm roll and wrist rotate held near the start pose), one solve per step, warm-started."""
    d = mujoco.MjData(m)
    d.qpos[:16] = START
    mujoco.mj_kinematics(m, d)
    arms, plans = [], []
    for side, ws in zip(("left", "right"), waypoints(task, objs)):
        b = m.body(f"vx300s_{side}/gripper_link").id
        g1, g2 = m.geom(f"vx300s_{side}/10_left_gripper_finger").id, m.geom(f"vx300s_{side}/10_right_gripper_finger").id
        r0 = d.xmat[b].reshape(3, 3).copy()
        mid = (d.geom_xpos[g1] + d.geom_xpos[g2]) / 2
        arms.append((b, np.arange(8 * len(arms), 8 * len(arms) + 6), r0, r0.T @ (mid - d.xpos[b])))
        plans.append([(t, mid.copy() if x is None else x, q, g) for t, x, q, g in ws])
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    lo, hi = m.jnt_range[:, 0], m.jnt_range[:, 1]
    posture = np.diag([0, 0, 0, 1e-3, 0, 1e-3])
    out = np.zeros((steps, 14))
    for t in range(1, steps + 1):
        for k, ((b, idx, r0, c), plan) in enumerate(zip(arms, plans)):
            x, q, g = interp(plan, t)
            rt = quat_mat(q) @ r0
            for _ in range(30):
                mujoco.mj_kinematics(m, d)
                mujoco.mj_comPos(m, d)
                rc = d.xmat[b].reshape(3, 3)
                p = d.xpos[b] + rc @ c
                e = np.concatenate([x - p, 0.5 * sum(np.cross(rc[:, i], rt[:, i]) for i in range(3))])
                mujoco.mj_jac(m, d, jacp, jacr, p, b)
                jac = np.vstack([jacp[:, idx], jacr[:, idx]])
                dq = np.linalg.solve(jac.T @ jac + posture + 1e-4 * np.eye(6),
                                     jac.T @ e + posture @ (START[idx] - d.qpos[idx]))
                d.qpos[idx] = np.clip(d.qpos[idx] + dq, lo[idx], hi[idx])
            out[t - 1, 7 * k:7 * k + 6] = d.qpos[idx]
            out[t - 1, 7 * k + 6] = g
    return out


def golden_actions(kind, task, seed, objs, model, steps):
    """Fixed f32 actions. `scripted`: the IK grasp above plus 0.01 rad of noise on the joint targets (it grasps,
    lifts and hands over / inserts: every reward level). `random_walk`: the arms wander far from the start pose
    (sweeping the table, touching the objects and each other), grippers anywhere in [0, 1]."""
    rng = np.random.default_rng([seed, list(TASKS).index(task)])
    if kind == "scripted":
        a = scripted_actions(task, model, objs, steps)
        noise = rng.normal(0.0, 0.01, a.shape)
        noise[:, [6, 13]] = 0
        return (a + noise).astype(np.float32)
    arm = np.concatenate([START[0:6], START[8:14]])
    walk = np.cumsum(rng.normal(0.0, 0.05, (steps, 12)), axis=0)
    joints = arm + np.clip(walk, -1.2, 1.2) + rng.normal(0.0, 0.05, (steps, 12))
    grip = rng.uniform(0.0, 1.0, (steps, 2))
    return np.concatenate([joints[:, :6], grip[:, :1], joints[:, 6:], grip[:, 1:]], axis=1).astype(np.float32)


RENDER_TOP = [False]
_render = Physics.render


def _gated_render(self, height=240, width=320, camera_id=-1, *args, **kwargs):
    if RENDER_TOP[0] and camera_id == "top":
        return _render(self, height, width, camera_id, *args, **kwargs)
    return np.zeros((height, width, 3), np.uint8)


def golden_episode(task, seed, kind, steps, frame_steps, bundle, out):
    env = make_env(task, steps)
    phys = physics_of(env)
    objs = gu.sample_box_pose(seed) if task == "transfer_cube" else np.concatenate(gu.sample_insertion_pose(seed))
    model = mujoco.MjModel.from_xml_path(os.path.join(bundle, "assets", TASKS[task][0]))
    actions = golden_actions(kind, task, seed, objs, model, steps)
    rows = {k: [] for k in ("qpos", "qvel", "ctrl", "agent_pos")}
    rewards = []

    def record(obs, t):
        rows["qpos"].append(phys.data.qpos.copy())
        rows["qvel"].append(phys.data.qvel.copy())
        rows["ctrl"].append(phys.data.ctrl.copy())
        rows["agent_pos"].append(np.asarray(obs["agent_pos"], np.float64))
        if t in frame_steps:
            frame = obs["pixels"]["top"]
            assert frame.shape == (480, 640, 3) and frame.any(), (task, seed, t)
            np.save(os.path.join(out, f"top_s{t:03d}.npy"), np.ascontiguousarray(frame))

    RENDER_TOP[0] = 0 in frame_steps
    obs, _ = env.reset(seed=seed)
    record(obs, 0)
    for t in range(1, steps + 1):
        RENDER_TOP[0] = t in frame_steps
        obs, reward, _terminated, _truncated, _ = env.step(actions[t - 1])
        rewards.append(float(reward))
        record(obs, t)
    RENDER_TOP[0] = False
    env.close()
    np.save(os.path.join(out, "actions.npy"), actions)
    for k, v in rows.items():
        np.save(os.path.join(out, f"{k}.npy"), np.array(v, np.float64))
    np.save(os.path.join(out, "reward.npy"), np.array(rewards, np.float64).reshape(-1, 1))
    r = np.array(rewards)
    return dict(task=task, seed=seed, actions=kind, dir=os.path.basename(out), steps=steps, frame_steps=sorted(frame_steps),
                rewards={str(k): int((r == k).sum()) for k in range(5)},
                first_success=next((i + 1 for i, x in enumerate(rewards) if x == 4), None))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--wheel", help="the gym-aloha 0.1.5 wheel (default: pip download it)")
    ap.add_argument("--steps", type=int, default=400, help="steps per reference episode (lerobot's cap: 400)")
    args = ap.parse_args()
    t0 = time.time()
    out = args.out
    if os.path.exists(out):
        shutil.rmtree(out)
    os.makedirs(out)
    files = copy_assets(get_wheel(args.wheel), out)

    with open(os.path.join(out, "reference_model.json"), "w") as f:
        json.dump(reference_models(out), f)
    with open(os.path.join(out, "init_poses.json"), "w") as f:
        json.dump(init_poses(), f, indent=1)
    for name in ("reference_model.json", "init_poses.json"):
        files[name] = sha256_file(os.path.join(out, name))

    Physics.render = _gated_render
    golden = os.path.join(out, "golden")
    episodes = []
    for task in TASKS:
        for seed, kind in GOLDEN:
            d = os.path.join(golden, f"{task}_seed{seed}")
            os.makedirs(d)
            episodes.append(golden_episode(task, seed, kind, args.steps, {0, 50, args.steps}, out, d))
            print(f"golden {task} seed {seed} ({kind}): rewards {episodes[-1]['rewards']}, first success "
                  f"{episodes[-1]['first_success']} ({time.time() - t0:.1f} s)")
    with open(os.path.join(golden, "manifest.json"), "w") as f:
        json.dump(dict(doc=__doc__.split("golden/")[1].split("The env renders")[0].strip(), episodes=episodes), f,
                  indent=1)

    provenance = dict(
        built_by="scripts/reference/aloha_bundle.py",
        wheel=dict(name=WHEEL, version="0.1.5", sha256=WHEEL_SHA256),
        mujoco=mujoco.__version__,
        oracle={p: version(p) for p in ("gym-aloha", "dm-control", "mujoco", "numpy", "gymnasium")},
        control=dict(
            dt=0.02, substeps=10, step="dm_control legacy_step: mj_step2, mj_step x 9, mj_step1",
            gripper="ctrl = +-(a * (0.058 - 0.01844) + 0.01844), a the f32 action promoted to float64 "
                    "(numpy 1.x scalar promotion; numpy 2 computes it in float32)"),
        sha256=files,
    )
    with open(os.path.join(out, "provenance.json"), "w") as f:
        json.dump(provenance, f, indent=1)
    print(f"ALOHA-sim bundle: {out} ({len(files)} files, {time.time() - t0:.1f} s)")


if __name__ == "__main__":
    main()
