"""Record golden data from the reference env for the Rust parity tests (set-up time).

usage: golden.py OUT_DIR [--suites ...] [--tasks all|0,3|suite/NN,...] [--inits 0,1,2] [--steps 80] [--jobs J]

Per task and init state, `OUT/<suite>__<NN>__init<k>/`:
  actions.npy  (T, 7)          10 wait steps [0,0,0,0,0,0,-1], then smooth seeded random motion with
                               gripper toggles and some exact-zero rotations
  states.npy   (T, 1+nq+nv)    the sim state after every step
  eef.npy      (T, 12)         grip-site position (3) and rotation matrix (9, row-major) after every step
  goal.npy     (T, 1+n_terms)  check_success() and each goal term after every step (0/1)
Per task, `OUT/<suite>__<NN>__goal_states/`: states where the goal *is* satisfied (objects placed
into their goal configuration by editing qpos and letting them settle, articulated joints set),
  states.npy   (S, 1+nq+nv)    sim states; goal.npy (S, 1+n_terms): the reference predicates
                               evaluated after set_init_state(state) (i.e. on a forwarded state)
  fixtures.json                the fixture root-body poses of that episode (the Rust env's reset(k, 0) must
                               put the fixtures exactly there)
Every episode is recorded on the published loop itself: a freshly constructed env, env.seed(0),
then one hard reset() per episode index up to the last recorded one (episode k is the (k+1)-th).
"""
import argparse
import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import libero_ref as L
from libero_ref import np

WAIT = np.array([0, 0, 0, 0, 0, 0, -1.0])
SEED = 0


def actions(n_steps, seed):
    rng = np.random.RandomState(seed)
    acts, a = [], np.zeros(7)
    for t in range(n_steps):
        if t < 10:
            acts.append(WAIT.copy())
            continue
        u = rng.uniform(-1, 1, 7) * np.array([1.0, 1.0, 1.0, 0.6, 0.6, 0.6, 1.0])
        a = 0.7 * a + 0.3 * u
        b = a.copy()
        b[6] = -1.0 if ((t - 10) // 15) % 2 == 0 else 1.0
        if t % 7 == 3:
            b[3:6] = 0.0  # exact-zero rotation: the controller keeps its goal orientation
        if t % 11 == 5:
            b[0] = 1.7  # out of range: clipped to 1
        acts.append(b)
    return np.array(acts)


def terms(env):
    e = env.env
    goal = e.parsed_problem["goal_state"]
    return [bool(e._eval_predicate(g)) for g in goal]


def eef(env):
    ctl_site = env.env.robots[0].controller.eef_name
    d = env.sim.data
    sid = env.sim.model.site_name2id(ctl_site)
    return np.concatenate([d.site_xpos[sid], d.site_xmat[sid].reshape(9)])


def episode(env, init_state, n_steps, seed):
    """One canonical episode on an env the published loop has just reset: set_init_state, then the
    actions."""
    env.set_init_state(init_state)
    acts = actions(n_steps, seed)
    states, eefs, goals = [], [], []
    for a in acts:
        _, _, done, _ = env.step(a)
        states.append(env.get_sim_state().copy())
        eefs.append(eef(env))
        goals.append([float(done)] + [float(x) for x in terms(env)])
    return acts, np.array(states), np.array(eefs), np.array(goals)


def free_qpos_adr(env, obj_name):
    e = env.env
    j = e.get_object(obj_name).joints[-1]
    return e.sim.model.get_joint_qpos_addr(j)[0]


def place_for_goal(env):
    """Edit qpos so that each goal term can hold; returns False if a term type is not handled."""
    e = env.env
    d, m = e.sim.data, e.sim.model
    for g in e.parsed_problem["goal_state"]:
        op = g[0]
        if op in ("on", "in"):
            a, b = g[1], g[2]
            adr = free_qpos_adr(env, a)
            if b in e.object_sites_dict:
                target = np.array(d.get_site_xpos(b))
            else:
                target = np.array(d.body_xpos[e.obj_body_id[b]])
            lift = 0.06 if op == "on" else 0.03
            d.qpos[adr:adr + 3] = target + np.array([0.0, 0.0, lift])
            d.qpos[adr + 3:adr + 7] = [1, 0, 0, 0]
        elif op in ("open", "close", "turnon", "turnoff"):
            x = g[1]
            if x in e.object_sites_dict:
                site = e.object_sites_dict[x]
                obj, joints = e.get_object(site.parent_name), site.joints
            else:
                obj = e.get_object(x)
                joints = obj.joints
            art = obj.object_properties["articulation"]
            rng = {"open": "default_open_ranges", "close": "default_close_ranges",
                   "turnon": "default_turnon_ranges", "turnoff": "default_turnoff_ranges"}[op]
            value = float(np.mean(art[rng]))
            for j in joints:
                d.qpos[m.get_joint_qpos_addr(j)] = value
        elif op == "up":
            adr = free_qpos_adr(env, g[1])
            d.qpos[adr + 2] = 1.1
        else:
            return False
    d.qvel[:] = 0
    e.sim.forward()
    return True


def goal_states(env, init_state, n_settle=40):
    """Place objects into their goal configuration, settle with wait actions, and keep every state;
    then evaluate the reference predicates on each (re-forwarded) state."""
    env.reset()
    env.set_init_state(init_state)
    if not place_for_goal(env):
        return None
    states = []
    for _ in range(n_settle):
        env.step(WAIT)
        states.append(env.get_sim_state().copy())
    goals = []
    for s in states:
        env.set_init_state(s)
        goals.append([float(env.check_success())] + [float(x) for x in terms(env)])
    return np.array(states), np.array(goals)


def record_task(job):
    suite, task_id, inits, n_steps, out = job
    b, task, bddl = L.task_of(suite, task_id)
    init_states = L.task_init_states(suite, task_id)
    summary = []
    # The published loop: a fresh env, env.seed(SEED), one hard reset per episode (episode k's
    # fixture poses depend on every reset before it, see libero_ref.published_property_samplers).
    env = L.make_env(bddl)
    assert env.env.hard_reset
    env.seed(SEED)
    for k in range(max(inits) + 1):
        env.reset()
        if k not in inits:
            continue
        poses = L.fixture_poses(env)
        acts, states, eefs, goals = episode(env, init_states[k], n_steps, seed=1000 * task_id + k)
        d = os.path.join(out, f"{suite}__{task_id:02d}__init{k}")
        os.makedirs(d, exist_ok=True)
        for name, arr in [("actions", acts), ("states", states), ("eef", eefs), ("goal", goals)]:
            np.save(os.path.join(d, f"{name}.npy"), np.asarray(arr, dtype=np.float64))
        json.dump(poses, open(os.path.join(d, "fixtures.json"), "w"))
        json.dump(dict(suite=suite, task_id=task_id, init_state_id=k, seed=SEED,
                       terms=[" ".join(g) for g in env.env.parsed_problem["goal_state"]]),
                  open(os.path.join(d, "meta.json"), "w"))
        summary.append(dict(init=k, any_success=bool(goals[:, 0].any())))
    env.close()
    # goal-satisfying states from init state 0, in the scene of episode 0 (a fresh env's first reset)
    env = L.make_env(bddl)
    env.seed(SEED)
    gs = goal_states(env, init_states[0])
    if gs is not None:
        d = os.path.join(out, f"{suite}__{task_id:02d}__goal_states")
        os.makedirs(d, exist_ok=True)
        np.save(os.path.join(d, "states.npy"), gs[0])
        np.save(os.path.join(d, "goal.npy"), gs[1])
        json.dump(dict(suite=suite, task_id=task_id, init_state_id=0, seed=SEED,
                       terms=[" ".join(g) for g in env.env.parsed_problem["goal_state"]]),
                  open(os.path.join(d, "meta.json"), "w"))
        summary.append(dict(goal_states=len(gs[0]), satisfied=int(gs[1][:, 0].sum())))
    env.close()
    print(json.dumps(dict(suite=suite, task_id=task_id, summary=summary)), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--suites", default="libero_spatial,libero_object,libero_goal,libero_10")
    ap.add_argument("--tasks", default="all", help="all, task indices (0,3), or suites and bundle paths (libero_goal_swap,libero_10_task/02)")
    ap.add_argument("--inits", default="0,1,2")
    ap.add_argument("--steps", type=int, default=80)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    inits = [int(x) for x in args.inits.split(",")]
    jobs = [(s, i, inits, args.steps, args.out) for s, i in L.selected_tasks(args.suites, args.tasks)]
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        list(ex.map(record_task, jobs))
    print(f"golden data for {len(jobs)} tasks -> {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
