"""Record LIBERO-PRO robustness episodes from the reference env (set-up time), and the objects'
footprint radii the placement perturbations need.

usage: pro_robustness_oracle.py radii OUT_JSON     horizontal_radius per object class of this venv's
                                                   LIBERO (merged into OUT_JSON if it exists; a
                                                   class both venvs know must agree)
       pro_robustness_oracle.py cases OUT_DIR      the reference episodes below

The reference env is hf-libero's (the one every bundle is exported from), edited after
`set_init_state` as LIBERO-PRO's robustness code edits it (`perturbation-spec.md` §C2, the
`robustness_perturbations.py` semantics the spec records; that code is not on PyPI):
  lighting     every light on, ambient/diffuse/specular broadcast, light_intensity 0
  camera       agentview cam_pos/cam_quat written raw (the shipped quaternion is not unit)
  appearance   group-1 geoms of the object's subtree or name prefix: geom_rgba, mat_rgba, textures off
  dark noise   clip(float32(img) * b + N(0, sd), 0, 255) -> uint8, the draws numpy's own
               (default_rng(142)), saved so the Rust transform can be fed the same draws
  initial pose the free joint's orientation set to a yaw, then the first safe candidate delta
  runtime move the first safe candidate delta, before the step where the gripper is near or the
               fallback step is reached
The candidate list and safety checks are implemented here from the spec, independently of the
Rust code, on the reference env's own MuJoCo data.

Per case `OUT/<case>/`: case.json (suite, task, parameters, what was applied), agentview.png (the
256x256 agentview after the edits, reference orientation), and for dark noise clean.png,
noise.npy, noisy.png; for placement cases actions.npy / states.npy (70 steps).
Every episode is episode 0 after env.seed(0): the fixture poses the Rust env's reset(0, 0) uses.
"""
import json
import math
import os
import sys

import libero_ref as L
from libero_ref import np, mujoco
from PIL import Image

import golden

STEPS = 70
SIZE = 256
DARK = dict(ambient=0.020, diffuse=0.16, specular=0.010)
PRO_CAMERA = dict(pos=[0.48, 0.24, 1.62], quat=[0.6099232, 0.3594558, 0.3594558, 0.6099232])

# (case, suite, task id, edits)
CASES = [
    ("lighting_kitchen", "libero_goal", 8, dict(lighting=DARK)),
    ("lighting_floor", "libero_object", 0, dict(lighting=DARK)),
    ("camera_tabletop", "libero_spatial", 0, dict(camera=PRO_CAMERA)),
    ("camera_floor", "libero_object", 0, dict(camera=PRO_CAMERA)),
    ("appearance_tabletop", "libero_spatial", 0, dict(appearance=(["plate_1"], [0.72, 0.63, 0.50, 1.0]))),
    ("appearance_floor", "libero_object", 0, dict(appearance=(["basket_1"], [0.35, 0.34, 0.32, 1.0]))),
    ("appearance_study", "libero_10", 5, dict(appearance=(["desk_caddy_1"], [0.50, 0.36, 0.20, 1.0]))),
    ("all_visual_living_room", "libero_10", 0,
     dict(lighting=DARK, camera=PRO_CAMERA, appearance=(["basket_1"], [0.30, 0.20, 0.12, 1.0]))),
    ("dark_noise_tabletop", "libero_spatial", 0, dict(dark_noise=(0.68, 12.0))),
    ("initial_pose_tabletop", "libero_spatial", 0,
     dict(initial_pose=("akita_black_bowl_1", [0.17, -0.06], 0.18, math.pi / 4))),
    ("initial_pose_floor", "libero_object", 0,
     dict(initial_pose=("alphabet_soup_1", [0.17, -0.06], 0.18, math.pi / 4))),
    ("runtime_move_kitchen", "libero_goal", 8,
     dict(runtime_move=("akita_black_bowl_1", [0.17, 0.06], 0.18, 0.09, 30))),
    ("runtime_move_study", "libero_10", 5,
     dict(runtime_move=("black_book_1", [0.17, 0.06], 0.18, 0.09, 25))),
]


def horizontal_radii() -> dict:
    from libero.libero.envs.base_object import OBJECTS_DICT
    out = {}
    for category, cls in sorted(OBJECTS_DICT.items()):
        try:
            r = cls(name=f"{category}_1").horizontal_radius
        except Exception:  # classes whose assets this package lacks, or with no footprint
            continue
        out[cls.__name__] = float(r)
    return out


def write_radii(path: str):
    mine = horizontal_radii()
    data = {"radii": {}, "sources": []}
    if os.path.exists(path):
        data = json.load(open(path))
    for cls, r in mine.items():
        old = data["radii"].get(cls)
        if old is not None and old != r:
            raise SystemExit(f"{cls}: horizontal_radius {r} here, {old} in the other package")
        data["radii"][cls] = r
    data["sources"].append(sys.prefix)
    json.dump(data, open(path, "w"), indent=1, sort_keys=True)


# --- placement: the candidate deltas and their checks (perturbation-spec.md §C2) ---

def candidates(delta, min_norm):
    norm = math.hypot(*delta)
    r = max(norm, min_norm)
    a = math.atan2(delta[1], delta[0]) if norm > 0 else 0.0
    at = lambda radius, ang: (radius * math.cos(ang), radius * math.sin(ang))
    out = [at(r, a)]
    for radius in (r, max(0.9 * r, min_norm, 0.06), 1.1 * r, 1.25 * r):
        for off in (0, math.pi / 2, -math.pi / 2, math.pi, math.pi / 4, -math.pi / 4, 3 * math.pi / 4, -3 * math.pi / 4):
            out.append(at(radius, a + off))
    f = max(min_norm, 0.06)
    d = f / math.sqrt(2)
    out += [(f, 0.0), (-f, 0.0), (0.0, f), (0.0, -f), (d, d)]
    seen, unique = set(), []
    for c in out:
        k = (round(c[0] * 1e4), round(c[1] * 1e4))
        if k not in seen:
            seen.add(k)
            unique.append(c)
    return unique[:32]


def subtree(m, root):
    def inside(b):
        while True:
            if b == root:
                return True
            if b == 0:
                return False
            b = m.body_parentid[b]
    return inside


def safe(env, name, radii, m, d):
    e = env.env
    bodies = {n: m.body(o.root_body).id for n, o in {**e.objects_dict, **e.fixtures_dict}.items()}
    b = bodies[name]
    p = d.xpos[b]
    if abs(p[0]) > 0.6 or abs(p[1]) > 0.6:
        return False
    own = radii.get(name, 0.04)
    for other, ob in bodies.items():
        if other == name:
            continue
        q = d.xpos[ob]
        if abs(q[2] - p[2]) <= 0.04 and math.hypot(q[0] - p[0], q[1] - p[1]) < own + radii.get(other, 0.04) + 0.01:
            return False
    inside = subtree(m, b)
    support = lambda g: (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or "") in ("floor",) or \
        (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or "").endswith("table_collision")
    for c in d.contact[:d.ncon]:
        g1, g2 = int(c.geom[0]), int(c.geom[1])
        if c.dist < -1e-3 and (inside(m.geom_bodyid[g1]) or inside(m.geom_bodyid[g2])) and not (support(g1) or support(g2)):
            return False
    return True


def shift_safely(env, name, delta, min_norm, radii):
    m, d = env.sim.model._model, env.sim.data._data
    obj = env.env.objects_dict[name]
    jnt = m.joint(obj.joints[-1]).id
    adr = m.jnt_qposadr[jnt]
    for c in candidates(delta, min_norm):
        d.qpos[adr] += c[0]
        d.qpos[adr + 1] += c[1]
        mujoco.mj_forward(m, d)
        if safe(env, name, radii, m, d):
            return list(c)
        d.qpos[adr] -= c[0]
        d.qpos[adr + 1] -= c[1]
    mujoco.mj_forward(m, d)
    return None


def object_radii(env) -> dict:
    return {n: float(o.horizontal_radius) for n, o in {**env.env.objects_dict, **env.env.fixtures_dict}.items()}


# --- the visual edits ---

def apply_visual(env, edits):
    m = env.sim.model._model
    if "lighting" in edits:
        lt = edits["lighting"]
        for i in range(m.nlight):
            m.light_active[i] = 1
            m.light_intensity[i] = 0.0
            m.light_ambient[i] = lt["ambient"]
            m.light_diffuse[i] = lt["diffuse"]
            m.light_specular[i] = lt["specular"]
    if "camera" in edits:
        cam = m.camera("agentview").id
        m.cam_pos[cam] = edits["camera"]["pos"]
        m.cam_quat[cam] = edits["camera"]["quat"]
    if "appearance" in edits:
        objects, rgba = edits["appearance"]
        e = env.env
        for name in objects:
            root = m.body({**e.objects_dict, **e.fixtures_dict}[name].root_body).id
            inside = subtree(m, root)
            for g in range(m.ngeom):
                gname = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
                if m.geom_group[g] != 1 or not (inside(m.geom_bodyid[g]) or gname.startswith(name)):
                    continue
                m.geom_rgba[g] = rgba
                mat = m.geom_matid[g]
                if mat >= 0:
                    m.mat_rgba[mat] = rgba
                    m.mat_texid[mat] = -1
    # cam_xpos/cam_xmat (what the renderer reads) follow cam_pos/cam_quat at the next forward pass,
    # which the policy's first observation (after a step) always has
    mujoco.mj_forward(m, env.sim.data._data)


def agentview(env):
    obs = env.env._get_observations(force_update=True)
    return np.asarray(obs["agentview_image"], dtype=np.uint8)


def run_case(out, name, suite, task_id, edits):
    b, task, bddl = L.task_of(suite, task_id)
    env = L.make_env(bddl, has_offscreen_renderer=True, use_camera_obs=True, camera_names=["agentview"],
                     camera_heights=SIZE, camera_widths=SIZE)
    env.seed(0)
    env.reset()
    env.set_init_state(L.task_init_states(suite, task_id)[0])
    d = os.path.join(out, name)
    os.makedirs(d, exist_ok=True)
    meta = {"suite": suite, "task_id": task_id, "edits": edits}
    radii = object_radii(env)
    if "initial_pose" in edits:
        obj, delta, min_norm, yaw = edits["initial_pose"]
        m, data = env.sim.model._model, env.sim.data._data
        adr = m.jnt_qposadr[m.joint(env.env.objects_dict[obj].joints[-1]).id]
        data.qpos[adr + 3:adr + 7] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        mujoco.mj_forward(m, data)
        meta["applied_delta"] = shift_safely(env, obj, delta, min_norm, radii)
        meta["state_after_edit"] = env.sim.get_state().flatten().tolist()
    apply_visual(env, edits)
    Image.fromarray(agentview(env)).save(os.path.join(d, "agentview.png"))
    if "dark_noise" in edits:
        brightness, sd = edits["dark_noise"]
        clean = agentview(env)
        noise = np.random.default_rng(142).normal(0.0, sd, clean.shape)
        noisy = np.clip(clean.astype(np.float32) * brightness + noise, 0, 255).astype(np.uint8)
        Image.fromarray(clean).save(os.path.join(d, "clean.png"))
        np.save(os.path.join(d, "noise.npy"), noise.reshape(-1, 3))  # (h*w, 3): 2-D for the Rust reader
        Image.fromarray(noisy).save(os.path.join(d, "noisy.png"))
    if "initial_pose" in edits or "runtime_move" in edits:
        acts = golden.actions(STEPS, 2000 + task_id)
        states, moved = [], None
        for t, a in enumerate(acts):
            if "runtime_move" in edits and moved is None:
                obj, delta, min_norm, trigger, fallback = edits["runtime_move"]
                data = env.sim.data._data
                eef = data.site_xpos[env.sim.model._model.site(env.env.robots[0].controller.eef_name).id]
                body = env.sim.model._model.body(env.env.objects_dict[obj].root_body).id
                if np.linalg.norm(eef - data.xpos[body]) <= trigger or t >= fallback:
                    moved = {"at_step": t, "delta": shift_safely(env, obj, delta, min_norm, radii)}
            env.step(a)
            states.append(env.sim.get_state().flatten())
        meta["runtime_move"] = moved
        np.save(os.path.join(d, "actions.npy"), acts)
        np.save(os.path.join(d, "states.npy"), np.array(states))
    with open(os.path.join(d, "case.json"), "w") as f:
        json.dump(meta, f, indent=1)
    env.close()


def main():
    what, out = sys.argv[1], sys.argv[2]
    if what == "radii":
        write_radii(out)
        return
    os.makedirs(out, exist_ok=True)
    only = set(sys.argv[3:])
    for case in CASES:
        if only and case[0] not in only:
            continue
        run_case(out, *case)
        print("recorded", case[0])


if __name__ == "__main__":
    main()
