"""Record LIBERO-Plus camera-viewpoint and robot-init episodes from the reference env (set-up time).

usage: plus_oracle.py WHEEL OUT_DIR

The reference env is hf-libero's (the one every bundle is exported from), with LIBERO-Plus's own
code put where LIBERO-Plus puts it:
  camera   the wheel's `_setup_camera` of the task's problem class (exec'd from the wheel's
           `envs/problems/*.py`, with its `rotate_around_*` / `scale_distance_from_pivot` helpers)
           replaces hf-libero's agentview pose before the model is compiled, so MuJoCo's compiler
           normalises the quaternion exactly as it does in LIBERO-Plus;
  robot    `MountedPanda` / `OnTheGroundPanda` get the wheel's `MountedPanda{N}.init_qpos`, which is
           all that class changes (`envs/robots/mounted_panda.py`); robosuite's reset then builds
           the controller there, and `set_init_state` overwrites the arm as in the published loop.

Per case `OUT/<case>/`:
  case.json       suite, task, parameters, the compiled agentview `cam_pos` / `cam_quat`
  agentview.png   (camera cases) the agentview image after set_init_state, 256x256, reference
                  orientation, as `obs["agentview_image"]`
  actions.npy     (robot cases) 10 wait steps then seeded random actions (golden.py's)
  states.npy      (robot cases) the sim state after every step
Every episode is episode 0 after env.seed(0): the fixture poses the Rust env's reset(0, 0) uses.
"""
import ast
import json
import os
import re
import sys
import zipfile

import libero_ref as L
from libero_ref import np
from PIL import Image
from scipy.spatial.transform import Rotation

import torch  # the reference venv's stand-in for LIBERO's init-state loading: scipy's array-API
if not hasattr(torch, "Tensor"):  # check asks it for a Tensor class, which no real array is
    torch.Tensor = type("Tensor", (), {})

import golden

ROOT = "liberoplus/liberoplus/"
STEPS = 70

# (case name, suite, task id, view (H, V, S, R, E) or None, robot init N or None)
CASES = [
    ("camera_tabletop", "libero_spatial", 0, (30, 15, 150, 4, 356), None),
    ("camera_nominal_kitchen", "libero_goal", 0, (0, 0, 100, 0, 0), None),
    ("camera_floor", "libero_object", 0, (180, 0, 120, 0, 0), None),
    ("camera_study", "libero_10", 5, (345, 15, 100, 10, 2), None),
    ("camera_living_room", "libero_10", 0, (90, 0, 110, 352, 6), None),
    ("robot_1_tabletop", "libero_spatial", 0, None, 1),
    ("robot_141_floor", "libero_object", 0, None, 141),
    ("robot_341_living_room", "libero_10", 0, None, 341),
    ("robot_500_kitchen", "libero_goal", 1, None, 500),
]


def plus_setup_camera(z: zipfile.ZipFile, problem: str):
    """The wheel's `_setup_camera` for a problem class's module, bound to its own helpers."""
    source = z.read(f"{ROOT}envs/problems/{problem}.py").decode()
    tree = ast.parse(source)
    helpers = [n for n in tree.body if isinstance(n, ast.FunctionDef)]
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    method = next(m for c in classes for m in c.body if isinstance(m, ast.FunctionDef) and m.name == "_setup_camera")
    env = {"np": np, "Rotation": Rotation}
    exec(compile(ast.Module(body=helpers + [method], type_ignores=[]), problem, "exec"), env)
    return env["_setup_camera"]


def init_qpos(z: zipfile.ZipFile, n: int):
    source = z.read(f"{ROOT}envs/robots/mounted_panda.py").decode()
    m = re.search(r"^class MountedPanda" + str(n) + r"\(.*?return np\.array\(\[(.*?)\]\)", source, re.S | re.M)
    return np.array([float(x) for x in m.group(1).replace("\n", " ").split(",")])


def run_case(z, out, name, suite, task_id, view, robot):
    from libero.libero.envs.bddl_base_domain import TASK_MAPPING
    from libero.libero.envs.robots import mounted_panda, on_the_ground_panda

    b, task, bddl = L.task_of(suite, task_id)
    problem = json.load(open(os.path.join(os.environ["LIBERO_BUNDLES"], suite, f"{task_id:02d}", "task.json")))["problem"]
    cls = TASK_MAPPING[problem]
    original_camera = cls._setup_camera
    original_qpos = (mounted_panda.MountedPanda.init_qpos, on_the_ground_panda.OnTheGroundPanda.init_qpos)
    if view is not None:
        plus = plus_setup_camera(z, problem)

        def setup_camera(self, arena):
            original_camera(self, arena)  # hf-libero's other cameras, then LIBERO-Plus's agentview
            (self.horizon_view, self.vertical_view, s, self.end_point_rot, self.end_point_vertical) = view
            self.scale_factor = float(int(s) / 100)
            plus(self, arena)

        cls._setup_camera = setup_camera
    if robot is not None:
        q = init_qpos(z, robot)
        mounted_panda.MountedPanda.init_qpos = property(lambda self: q)
        on_the_ground_panda.OnTheGroundPanda.init_qpos = property(lambda self: q)
    try:
        kw = dict(has_offscreen_renderer=True, use_camera_obs=True, camera_names=["agentview"],
                  camera_heights=256, camera_widths=256) if view is not None else {}
        env = L.make_env(bddl, **kw)
        env.seed(0)
        env.reset()
        init_states = L.task_init_states(suite, task_id)
        obs = env.set_init_state(init_states[0])
        model = env.sim.model
        cam = model.camera_name2id("agentview")
        d = os.path.join(out, name)
        os.makedirs(d, exist_ok=True)
        meta = {"suite": suite, "task_id": task_id, "problem": problem, "view": view, "robot_init": robot,
                "cam_pos": model.cam_pos[cam].tolist(), "cam_quat": model.cam_quat[cam].tolist()}
        if robot is not None:
            meta["robot_init_qpos"] = init_qpos(z, robot).tolist()
            meta["controller_initial_joint"] = np.asarray(env.env.robots[0].controller.initial_joint).tolist()
        if view is not None:
            Image.fromarray(np.asarray(obs["agentview_image"], dtype=np.uint8)).save(os.path.join(d, "agentview.png"))
        else:
            acts = golden.actions(STEPS, 1000 + task_id)
            states = []
            for a in acts:
                env.step(a)
                states.append(env.sim.get_state().flatten())
            np.save(os.path.join(d, "actions.npy"), acts)
            np.save(os.path.join(d, "states.npy"), np.array(states))
        with open(os.path.join(d, "case.json"), "w") as f:
            json.dump(meta, f, indent=1)
        env.close()
    finally:
        cls._setup_camera = original_camera
        mounted_panda.MountedPanda.init_qpos, on_the_ground_panda.OnTheGroundPanda.init_qpos = original_qpos


def main():
    wheel, out = sys.argv[1], sys.argv[2]
    z = zipfile.ZipFile(wheel)
    os.makedirs(out, exist_ok=True)
    for case in CASES:
        run_case(z, out, *case)
        print("recorded", case[0])


if __name__ == "__main__":
    main()
