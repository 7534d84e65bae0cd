"""LIBERO-PRO's `view_occlusion` case: the occluder scenes as task bundles, and reference episodes
(set-up time, in the reference venv; perturbation-spec.md §C2 `object_placement`, §C3).

usage: pro_occlusion.py build BUNDLES --occlusion OUT [--tasks suite/id,...] [--jobs J]
       pro_occlusion.py golden GOLDEN --occlusion OUT

`view_occlusion` adds an object to each of the 40 tasks' scenes, so each needs a bundle of its own:
suite `<suite>_view_occlusion` (libero_schema `Perturbation::ViewOcclusion`), the same task ids.

- The BDDL (plain text edits of the clean task's, written to OUT/bddl_files/<suite>_view_occlusion/):
  the occluder `black_book_occluder_1 - black_book`, or `yellow_book_N - yellow_book` (N the next
  free index) when the scene already has a black book, added to `:objects`; a region
  `occluder_region` of 0.01 m starting at (-0.34, -0.30) on the workspace (the target of the
  scene's first region with ranges); `(On <occluder> <workspace>_occluder_region)` in `:init`.
  The instruction, goal and objects of interest are the clean task's. hf-libero compiles it.
- The init states (OUT/init_files/...): the clean task's 50, mapped onto the new model by joint
  name (§C3); the occluder's free joint gets the pose the new scene's first reset after
  `env.seed(0)` samples in its region (its "BDDL placement"), velocity 0, in every state. The
  placement edit below moves it anyway: only its height matters, and it is deterministic.
- `build`: the unchanged exporter (`build_bundles.py`, imported) on those, this module registering
  the suites with `libero_ref`'s task lookup (as plus_layout.py does). Resumable: a bundle whose
  stamp `BUNDLES/.complete-<suite>-<task_id>@<OUT name>` exists is skipped.
- `golden`: reference episodes of the tests' occlusion cases (CASES): the reference env (hf-libero)
  on the occlusion BDDL, `env.seed(0)`, `reset()`, `set_init_state(mapped state 0)`, then the
  placement edit (`apply_occlusion`, from the spec, independently of the Rust code), then 70 steps
  of golden.py's actions with the occluder pinned after every step (qpos rewritten, qvel not) and
  the data forwarded (the observation re-rendered after pinning, as a third-party harness does).
  Per case OUT/<case>/: case.json (parameters, the partner's move, the occluder's chosen offset,
  the state after the edit), agentview.png (256x256 after the edit, reference orientation),
  agentview_60.png (after 60 steps), actions.npy, states.npy.

The placement edit (§C2; where the spec is terse, our reading, the same in sim/src/env/occlusion.rs):
  1. the goal partner, when it is another object than the reference and its body is closer than
     `partner_threshold` (xy) to the reference's, is moved by `partner_delta` with
     `choose_safe_delta` (the candidates and checks of pro_robustness_oracle.py, minimum norm 0);
  2. the occluder is placed at reference xy + the first candidate offset (in the frame of
     front_direction (1, 0), +x toward the camera, and lateral +y) that passes the same safety
     checks, lies at least min_reference_distance (0.02 m) from the reference and at least
     `partner_clearance` (xy) from the partner's body; its height is its BDDL placement's plus
     z_offset (0); its orientation target_quat (1, 0, 0, 0). No candidate: it stays where it was;
  3. its 7 qpos are then pinned after every env step.
  `candidate_reference_offsets(o)`: o; then radii {max(n,.12), max(n+.04,.16), max(n+.08,.20)}
  (n = |o|) x angles {0, ±.16, ±.32, ±.48} rad about o's direction; then forward
  {.075,.095,.12,.16,.20,.24} x lateral {0, ±.065, ±.10}; deduplicated to 0.1 mm; at most 32.
  mesh_scale 1.6 is not applied: writing mjModel.mesh_scale after compilation changes nothing (§C2).
"""
import argparse
import json
import math
import os
import re
import sys
import time
from collections import namedtuple

import libero_ref as L
from libero_ref import np, mujoco

import golden
import pro_robustness_oracle as R

SUFFIX = "_view_occlusion"
SUITES = ["libero_spatial", "libero_object", "libero_goal", "libero_10"]
REGION = "occluder_region"
REGION_RANGE = (-0.34, -0.30, -0.33, -0.29)
STEPS = 70
SIZE = 256
Task = namedtuple("Task", "name language problem_folder bddl_file")

# The tests' cases: (case, suite, task id, occlusion parameters as the spec rows give them for that
# task by libero_pro_robustness.rs's rules). Keep the tasks equal to setup.sh PRO_OCCLUSION_TEST_TASKS.
CASES = [
    ("occlusion_goal_partner_moved", "libero_goal", 8,
     dict(reference="akita_black_bowl_1", offset=[0.08, 0.0], partner="plate_1", partner_threshold=0.24,
          partner_delta=[0.16, 0.0], partner_clearance=0.08)),
    ("occlusion_study_yellow_book", "libero_10", 5,
     dict(reference="black_book_1", offset=[0.08, 0.0], partner="desk_caddy_1", partner_threshold=0.24,
          partner_delta=[0.16, 0.0], partner_clearance=0.08)),
]


# --- the scene edit ---

def section(text, name):
    """(start, end) of the `(:name ...)` block's body (after the tag, before its closing paren)."""
    m = re.search(r"\(:" + name + r"\b", text)
    if not m:
        raise SystemExit(f"the BDDL has no (:{name} ...) block")
    depth, i = 1, m.end()
    while depth:
        depth += {"(": 1, ")": -1}.get(text[i], 0)
        i += 1
    return m.end(), i - 1


def occluder_name(text):
    """black_book_occluder_1, or the next yellow_book_N when the scene has a black book."""
    s, e = section(text, "objects")
    s2, e2 = section(text, "fixtures")
    declared = re.findall(r"(\S+)\s+-\s+(\S+)", text[s:e] + "\n" + text[s2:e2])
    if not any(t == "black_book" for _, t in declared):
        return "black_book_occluder_1", "black_book"
    used = [int(m.group(1)) for n, _ in declared for m in [re.fullmatch(r"yellow_book_(\d+)", n)] if m]
    return f"yellow_book_{max(used, default=0) + 1}", "yellow_book"


def occlusion_bddl(text):
    """The clean task's BDDL with the occluder added (see the module doc); (text, occluder name)."""
    name, cls = occluder_name(text)
    workspace = re.search(r"\(\S+\s*\(:target\s+(\S+)\)\s*\(:ranges", text)
    if not workspace:
        raise SystemExit("no region with ranges: cannot tell the workspace the occluder stands on")
    workspace = workspace.group(1)
    x0, y0, x1, y1 = REGION_RANGE
    region = (f"      ({REGION}\n          (:target {workspace})\n          (:ranges (\n"
              f"              ({x0} {y0} {x1} {y1})\n            )\n          )\n      )\n    ")
    _, e = section(text, "regions")
    text = text[:e].rstrip() + "\n" + region + text[e:]
    _, e = section(text, "objects")
    text = text[:e].rstrip() + f"\n    {name} - {cls}\n  " + text[e:]
    _, e = section(text, "init")
    text = text[:e].rstrip() + f"\n    (On {name} {workspace}_{REGION})\n  " + text[e:]
    return text, name


def joint_slices(m):
    """{joint name: (qpos slice, qvel slice)} of a model."""
    out = {}
    for j in range(m.njnt):
        nq = {0: 7, 1: 4, 2: 1, 3: 1}[int(m.jnt_type[j])]
        nv = {0: 6, 1: 3, 2: 1, 3: 1}[int(m.jnt_type[j])]
        q, v = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        out[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)] = (slice(q, q + nq), slice(v, v + nv))
    return out


def map_states(clean_states, clean_model, env):
    """The clean states on the new model, by joint name; joints the clean model lacks (the
    occluder's) keep the new env's current values, with zero velocity."""
    new = env.sim.model._model
    cur = np.asarray(env.get_sim_state(), dtype=np.float64)
    old_j, new_j = joint_slices(clean_model), joint_slices(new)
    missing = sorted(set(old_j) - set(new_j))
    if missing:
        raise SystemExit(f"the occlusion scene lost joints {missing}")
    onq, nnq = clean_model.nq, new.nq
    out = np.zeros((len(clean_states), 1 + new.nq + new.nv))
    for k, s in enumerate(clean_states):
        out[k, 0] = s[0]
        for name, (q, v) in new_j.items():
            if name in old_j:
                oq, ov = old_j[name]
                out[k, 1 + q.start:1 + q.stop] = s[1 + oq.start:1 + oq.stop]
                out[k, 1 + nnq + v.start:1 + nnq + v.stop] = s[1 + onq + ov.start:1 + onq + ov.stop]
            else:
                out[k, 1 + q.start:1 + q.stop] = cur[1 + q.start:1 + q.stop]
    return out


def prepare(out, suite, task_id):
    """The occlusion BDDL and mapped init states of one task, into OUT (skipped when there)."""
    b, task, bddl = L.task_of(suite, task_id)
    osuite = suite + SUFFIX
    path = os.path.join(out, "bddl_files", osuite, task.bddl_file)
    init = os.path.join(out, "init_files", osuite, f"{task.name}.npy")
    meta = os.path.join(out, "tasks", f"{osuite}-{task_id}.json")
    if os.path.exists(meta):
        return json.load(open(meta))
    text, name = occlusion_bddl(open(bddl).read())
    os.makedirs(os.path.dirname(path), exist_ok=True)
    open(path, "w").write(text)
    clean = L.make_env(bddl)
    clean_model = clean.sim.model._model
    env = L.make_env(path)
    env.seed(0)
    env.reset()
    states = map_states(L.task_init_states(suite, task_id), clean_model, env)
    q = joint_slices(env.sim.model._model)[env.env.objects_dict[name].joints[-1]][0]
    os.makedirs(os.path.dirname(init), exist_ok=True)
    np.save(init, states)
    row = dict(suite=osuite, task_id=task_id, name=task.name, language=task.language, occluder=name,
               occluder_qpos=states[0, 1 + q.start:1 + q.stop].tolist(), n_states=len(states))
    os.makedirs(os.path.dirname(meta), exist_ok=True)
    json.dump(row, open(meta + ".tmp", "w"), indent=1)
    os.replace(meta + ".tmp", meta)
    clean.close()
    env.close()
    return row


def register(out):
    """Let libero_ref (and so the exporter) look the `_view_occlusion` suites up in OUT."""
    task_of, task_init_states, suite_parts = L.task_of, L.task_init_states, L.suite_parts

    def occ_task_of(suite, task_id):
        if not suite.endswith(SUFFIX):
            return task_of(suite, task_id)
        row = prepare(out, suite[:-len(SUFFIX)], task_id)
        task = Task(row["name"], row["language"], suite, row["name"] + ".bddl")
        return None, task, os.path.join(out, "bddl_files", suite, task.bddl_file)

    def occ_init_states(suite, task_id):
        if not suite.endswith(SUFFIX):
            return task_init_states(suite, task_id)
        row = prepare(out, suite[:-len(SUFFIX)], task_id)
        return np.load(os.path.join(out, "init_files", suite, row["name"] + ".npy"))

    def occ_suite_parts(suite):
        if suite.endswith(SUFFIX) and suite[:-len(SUFFIX)] in SUITES:
            return suite[:-len(SUFFIX)], "view_occlusion"
        return suite_parts(suite)

    L.task_of, L.task_init_states, L.suite_parts = occ_task_of, occ_init_states, occ_suite_parts


def selected(tasks):
    out = []
    for item in tasks.split(","):
        suite, _, tid = item.partition("/")
        suite = suite if suite.endswith(SUFFIX) else suite + SUFFIX
        if suite[:-len(SUFFIX)] not in SUITES:
            raise SystemExit(f"unknown occlusion suite {suite}: <suite>{SUFFIX} of {', '.join(SUITES)}")
        out += [(suite, int(tid))] if tid else [(suite, i) for i in range(10)]
    return out


def stamp(bundles, occ, suite, task_id):
    return os.path.join(bundles, f".complete-{suite}-{task_id}@{os.path.basename(os.path.normpath(occ))}")


def build(args):
    register(args.occlusion)
    import build_bundles
    todo = [(s, t) for s, t in selected(args.tasks) if not os.path.exists(stamp(args.bundles, args.occlusion, s, t))]
    print(f"occlusion bundles: {len(todo)} to build", file=sys.stderr)
    t0 = time.time()
    for s, t in todo:  # the scene edits first, one process (each makes two envs)
        prepare(args.occlusion, s[:-len(SUFFIX)], t)
    for i in range(0, len(todo), args.chunk):
        chunk = todo[i:i + args.chunk]
        sys.argv = ["build_bundles.py", args.bundles, "--tasks", ",".join(f"{s}/{t}" for s, t in chunk),
                    "--jobs", str(args.jobs)]
        build_bundles.main()
        for s, t in chunk:
            open(stamp(args.bundles, args.occlusion, s, t), "w").close()
        print(f"occlusion bundles: {i + len(chunk)}/{len(todo)} in {time.time() - t0:.0f} s ({args.jobs} jobs)",
              file=sys.stderr, flush=True)


# --- the placement edit and pinning (reference) ---

def candidate_reference_offsets(o):
    n = math.hypot(*o)
    a = math.atan2(o[1], o[0]) if n > 0 else 0.0
    out = [tuple(o)]
    for r in (max(n, 0.12), max(n + 0.04, 0.16), max(n + 0.08, 0.20)):
        for da in (0.0, 0.16, -0.16, 0.32, -0.32, 0.48, -0.48):
            out.append((r * math.cos(a + da), r * math.sin(a + da)))
    for f in (0.075, 0.095, 0.12, 0.16, 0.20, 0.24):
        for lat in (0.0, 0.065, -0.065, 0.10, -0.10):
            out.append((f, lat))
    seen, unique = set(), []
    for c in out:
        k = (round(c[0] * 1e4), round(c[1] * 1e4))
        if k not in seen:
            seen.add(k)
            unique.append(c)
    return unique[:32]


def body_of(env, name):
    e = env.env
    return env.sim.model._model.body({**e.objects_dict, **e.fixtures_dict}[name].root_body).id


def shift_any(env, name, delta, radii):
    """choose_safe_delta on an object (free joint qpos) or a fixture (body_pos), minimum norm 0."""
    e = env.env
    if name in e.objects_dict:
        return R.shift_safely(env, name, delta, 0.0, radii)
    m, d = env.sim.model._model, env.sim.data._data
    b = body_of(env, name)
    for c in R.candidates(delta, 0.0):
        m.body_pos[b][:2] += c
        mujoco.mj_forward(m, d)
        if R.safe(env, name, radii, m, d):
            return list(c)
        m.body_pos[b][:2] -= c
    mujoco.mj_forward(m, d)
    return None


def apply_occlusion(env, occluder, p, radii):
    """Steps 1 and 2 of the module doc; returns (record, pinned qpos slice, pinned values)."""
    m, d = env.sim.model._model, env.sim.data._data
    ref_b = body_of(env, p["reference"])
    rec = dict(partner_distance=None, partner_delta=None, occluder_offset=None)
    partner = p.get("partner")
    if partner and partner != p["reference"]:
        pb = body_of(env, partner)
        dist = math.hypot(*(d.xpos[pb][:2] - d.xpos[ref_b][:2]))
        rec["partner_distance"] = dist
        if dist < p["partner_threshold"]:
            rec["partner_delta"] = shift_any(env, partner, p["partner_delta"], radii)
    adr = int(m.jnt_qposadr[m.joint(env.env.objects_dict[occluder].joints[-1]).id])
    q = slice(adr, adr + 7)
    before = d.qpos[q].copy()
    ref = d.xpos[ref_b][:2].copy()
    occ_b = body_of(env, occluder)
    for c in candidate_reference_offsets(p["offset"]):
        if math.hypot(*c) < 0.02:
            continue
        d.qpos[q] = [ref[0] + c[0], ref[1] + c[1], before[2] + 0.0, 1.0, 0.0, 0.0, 0.0]
        mujoco.mj_forward(m, d)
        clear = not (partner and partner != p["reference"]) or \
            math.hypot(*(d.xpos[occ_b][:2] - d.xpos[body_of(env, partner)][:2])) >= p["partner_clearance"]
        if clear and R.safe(env, occluder, radii, m, d):
            rec["occluder_offset"] = list(c)
            break
        d.qpos[q] = before
    mujoco.mj_forward(m, d)
    return rec, q, d.qpos[q].copy()


def run_case(out, occ, name, suite, task_id, p):
    osuite = suite + SUFFIX
    row = prepare(occ, suite, task_id)
    _, _, bddl = L.task_of(osuite, task_id)
    env = L.make_env(bddl, has_offscreen_renderer=True, use_camera_obs=True, camera_names=["agentview"],
                     camera_heights=SIZE, camera_widths=SIZE)
    env.seed(0)
    env.reset()
    env.set_init_state(L.task_init_states(osuite, task_id)[0])
    radii = R.object_radii(env)
    rec, q, pinned = apply_occlusion(env, row["occluder"], p, radii)
    d = os.path.join(out, name)
    os.makedirs(d, exist_ok=True)
    from PIL import Image
    Image.fromarray(R.agentview(env)).save(os.path.join(d, "agentview.png"))
    state_after = env.sim.get_state().flatten().tolist()
    acts = golden.actions(STEPS, 3000 + task_id)
    data, model = env.sim.data._data, env.sim.model._model
    states = []
    for t, a in enumerate(acts):
        env.step(a)
        data.qpos[q] = pinned
        mujoco.mj_forward(model, data)
        states.append(env.sim.get_state().flatten())
        if t + 1 == 60:
            Image.fromarray(R.agentview(env)).save(os.path.join(d, "agentview_60.png"))
    np.save(os.path.join(d, "actions.npy"), acts)
    np.save(os.path.join(d, "states.npy"), np.array(states))
    meta = dict(suite=osuite, clean_suite=suite, task_id=task_id, occluder=row["occluder"], occlusion=p,
                applied=rec, pinned_qpos=pinned.tolist(), state_after_edit=state_after)
    json.dump(meta, open(os.path.join(d, "case.json"), "w"), indent=1)
    env.close()
    print("recorded", name, json.dumps(rec))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build")
    b.add_argument("bundles")
    b.add_argument("--occlusion", required=True)
    b.add_argument("--tasks", default=",".join(SUITES))
    b.add_argument("--chunk", type=int, default=8)
    b.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    g = sub.add_parser("golden")
    g.add_argument("out")
    g.add_argument("--occlusion", required=True)
    args = ap.parse_args()
    if args.cmd == "build":
        build(args)
    else:
        register(args.occlusion)
        os.makedirs(args.out, exist_ok=True)
        for case in CASES:
            run_case(args.out, args.occlusion, *case)


if __name__ == "__main__":
    main()
