//! Failure modes (`queries/failure_modes.sql`) through the binary, on a run of episodes
//! constructed to show each mode (real Parquet parts written with the rollout's own builders, no
//! simulation), so every mode's definition is pinned by an episode that has exactly its evidence.
//! The real-episode checks (a forced early release of the scripted expert is `dropped`) are in
//! `tests/expert.rs`.

use libero_e2e::{ok, pipeline, pipeline_bin, repo_root, test_dir, write_constructed_manifest, write_episode_parts};
use libero_udfs::episode::{EpisodeContext, EpisodeError, EpisodeProtocol, EpisodeSummary, episode_batch};
use libero_udfs::steps_batch::{EpisodeKey, StepRecord, StepsBatchBuilder};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

const WAIT: u32 = 10;
const MAX_STEPS: u32 = 30;
const OBJECTS: [&str; 3] = ["bowl_1", "plate_1", "mug_1"];
const BOWL: usize = 0;
const MUG: usize = 2;
const TABLE_Z: f64 = 0.9;

/// What happens in a constructed episode; its task id is its index in [`ALL`].
#[derive(Clone, Copy, Debug, PartialEq)]
enum Scene {
    /// Nothing moves, nothing is touched.
    Idle,
    /// The distractor mug is grasped and lifted 10 cm.
    LiftsTheMug,
    /// The bowl is grasped, lifted 10 cm, let go, and falls back to the table.
    DropsTheBowl,
    /// The bowl is grasped, lifted, lowered to 2 cm above the table and let go: a placement that
    /// missed its target (no goal), not a drop (the fall is under the 3 cm threshold).
    PlacesTheBowlAstray,
    /// The bowl is let go 10 cm above the plate and lands on it (its own term holds), while the
    /// other goal term never does: a fall into the goal is not a drop.
    PlacesTheBowlFromHigh,
    /// The goal holds at policy steps 5..8 only.
    Transient,
    /// Every policy action has three arm components at the clip bounds.
    Saturated,
    /// During the wait steps the bowl slides 5 cm sideways (a bad init state).
    SlidesInTheWait,
    /// During the wait steps the bowl settles 5 cm straight down (every LIBERO init state does).
    SettlesInTheWait,
    /// The sim fails at policy step 10: an error row.
    Crashes,
    /// One of the two goal terms comes true at policy step 10, without any grasp.
    HalfTheGoal,
    /// The goal holds from policy step 20 on.
    Succeeds,
}

use Scene::*;
const ALL: [Scene; 12] = [
    Idle,
    LiftsTheMug,
    DropsTheBowl,
    PlacesTheBowlAstray,
    PlacesTheBowlFromHigh,
    Transient,
    Saturated,
    SlidesInTheWait,
    SettlesInTheWait,
    Crashes,
    HalfTheGoal,
    Succeeds,
];

struct StepState {
    poses: Vec<([f64; 3], [f64; 4])>,
    contacts: Vec<usize>,
    action: [f32; 7],
    terms: [bool; 2],
}

fn state(scene: Scene, t: u32) -> StepState {
    let p = t.checked_sub(WAIT);
    let at = |range: std::ops::Range<u32>| p.is_some_and(|p| range.contains(&p));
    let mut pos = [[0.0, 0.0, TABLE_Z], [0.2, 0.0, TABLE_Z], [-0.2, 0.0, TABLE_Z]];
    let mut contacts = vec![];
    let mut action = [0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0];
    let mut terms = [false, false];
    match scene {
        Idle | Crashes => {}
        LiftsTheMug if at(5..15) => {
            contacts.push(MUG);
            pos[MUG][2] = TABLE_Z + 0.1;
            action[6] = 1.0;
        }
        DropsTheBowl if at(5..12) => {
            contacts.push(BOWL);
            pos[BOWL][2] = TABLE_Z + 0.1;
            action[6] = 1.0;
        }
        PlacesTheBowlAstray if at(5..13) => {
            contacts.push(BOWL);
            pos[BOWL][2] = TABLE_Z + if at(12..13) { 0.02 } else { 0.1 };
            action[6] = 1.0;
        }
        PlacesTheBowlFromHigh if at(5..12) => {
            contacts.push(BOWL);
            pos[BOWL][2] = TABLE_Z + 0.1;
            action[6] = 1.0;
        }
        PlacesTheBowlFromHigh if at(12..MAX_STEPS) => terms = [true, false],
        Transient if at(5..8) => terms = [true, true],
        Saturated if p.is_some() => action = [1.0, -1.0, 1.0, 0.0, 0.0, 0.0, -1.0],
        SlidesInTheWait if t == 0 => pos[BOWL][0] = -0.05,
        SettlesInTheWait if t == 0 => pos[BOWL][2] = TABLE_Z + 0.05,
        HalfTheGoal if at(10..MAX_STEPS) => terms = [true, false],
        Succeeds if at(20..MAX_STEPS) => terms = [true, true],
        _ => {}
    }
    StepState { poses: pos.iter().map(|p| (*p, [1.0, 0.0, 0.0, 0.0])).collect(), contacts, action, terms }
}

fn key(scene: Scene) -> EpisodeKey {
    EpisodeKey::new("libero_goal", ALL.iter().position(|s| *s == scene).unwrap() as i32, 0, 7)
}

/// The constructed run, built once (tests run in parallel).
fn run() -> PathBuf {
    static RUN: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    RUN.get_or_init(|| {
        let dir = test_dir("failure-modes", "run");
        let protocol = EpisodeProtocol {
            max_steps: MAX_STEPS,
            num_steps_wait: WAIT,
            stop_on_success: false,
            instruction_source: Default::default(),
            realtime: None,
            protocol: Some(Default::default()),
        };
        for scene in ALL {
            let key = key(scene);
            let mut steps = StepsBatchBuilder::new(key.clone(), OBJECTS.iter().map(|s| s.to_string()).collect());
            let last = if scene == Crashes { WAIT + 10 } else { WAIT + MAX_STEPS };
            let (mut first, mut final_goal) = (None, false);
            let mut goal_changes = libero_udfs::goal_evidence::GoalChanges::default();
            for t in 0..last {
                let s = state(scene, t);
                let goal = s.terms.iter().all(|&x| x);
                let p = t.checked_sub(WAIT);
                if let Some(p) = p {
                    final_goal = goal;
                    goal_changes.record(p, goal);
                    if goal && first.is_none() {
                        first = Some(p);
                    }
                }
                steps.push(&StepRecord {
                    step: t as i32,
                    policy_step: p.map(|x| x as i32),
                    action: s.action,
                    eef_pos: [0.0, 0.0, 1.0],
                    eef_quat: [1.0, 0.0, 0.0, 0.0],
                    gripper_qpos: [0.04, -0.04],
                    joint_pos: [0.0; 7],
                    object_poses: &s.poses,
                    goal,
                    goal_terms: &s.terms,
                    gripper_contacts: &s.contacts,
                    sim_ms: 1.0,
                    policy_ms: 0.0,
                    render_ms: 0.0,
                    timing: None,
                    held: false,
                });
            }
            let summary = EpisodeSummary {
                instruction: format!("{scene:?}"),
                instruction_source: "bddl",
                start_sha256: None,
                n_policy_steps: last - WAIT,
                first_success_step: first,
                final_goal,
                goal_changes,
                goal_terms: vec!["on bowl_1 plate_1".into(), "open drawer_1".into()],
                objects_of_interest: vec!["bowl_1".into(), "plate_1".into()],
                error: (scene == Crashes)
                    .then(|| EpisodeError { kind: "sim_unstable", message: "constructed crash".into() }),
                wall_s: 1.0,
                sim_s: 1.0,
                policy_s: 0.0,
                render_s: 0.0,
                started_at: None,
            };
            let ctx = EpisodeContext {
                policy: "constructed",
                perturbation_params: None,
                run_config: "constructed",
                protocol: &protocol,
            };
            write_episode_parts(&dir, &key, steps, &episode_batch(&key, &summary, &ctx, None).unwrap());
        }
        write_constructed_manifest(&dir, "constructed", WAIT);
        dir
    })
    .clone()
}

/// `failure_modes.csv` of `pipeline failures` as episode key -> (mode, row by column name).
fn modes(out: &Path) -> BTreeMap<String, (String, BTreeMap<String, String>)> {
    let text = std::fs::read_to_string(out.join("failure_modes.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    lines
        .map(|l| {
            let row: BTreeMap<String, String> =
                header.iter().zip(l.split(',')).map(|(h, v)| (h.to_string(), v.to_string())).collect();
            (row["episode_key"].clone(), (row["failure_mode"].clone(), row))
        })
        .collect()
}

fn failures(run: &Path, out: &Path, extra: &[&str]) -> BTreeMap<String, (String, BTreeMap<String, String>)> {
    let mut args = vec!["failures", "--run", run.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    ok(pipeline(&args));
    modes(out)
}

fn mode_of(m: &BTreeMap<String, (String, BTreeMap<String, String>)>, scene: Scene) -> Option<&str> {
    m.get(&key(scene).episode_key).map(|(mode, _)| mode.as_str())
}

#[test]
fn each_constructed_episode_gets_the_mode_its_evidence_shows() {
    let run = run();
    let out = test_dir("failure-modes", "any-step");
    let m = failures(&run, &out, &[]);
    let expected = [
        (Idle, "timeout"),
        (LiftsTheMug, "wrong_object"),
        (DropsTheBowl, "dropped"),
        (PlacesTheBowlAstray, "incomplete"),
        (PlacesTheBowlFromHigh, "incomplete"),
        (Saturated, "saturated_actions"),
        (SlidesInTheWait, "init_drift"),
        (SettlesInTheWait, "timeout"),
        (Crashes, "error"),
        (HalfTheGoal, "incomplete"),
    ];
    for (scene, mode) in expected {
        assert_eq!(mode_of(&m, scene), Some(mode), "{scene:?}: {:?}", m.get(&key(scene).episode_key));
    }
    // Any-step successes are not failures.
    assert_eq!(mode_of(&m, Transient), None);
    assert_eq!(mode_of(&m, Succeeds), None);
    assert_eq!(m.len(), expected.len());

    // The evidence behind the modes is in the row.
    let dropped = &m[&key(DropsTheBowl).episode_key].1;
    assert_eq!(dropped["fallen_object"], "bowl_1");
    assert!((dropped["interest_fall_m"].parse::<f64>().unwrap() - 0.1).abs() < 1e-9, "{dropped:?}");
    let astray = &m[&key(PlacesTheBowlAstray).episode_key].1;
    assert!((astray["interest_fall_m"].parse::<f64>().unwrap() - 0.02).abs() < 1e-9, "{astray:?}");
    assert_eq!(m[&key(LiftsTheMug).episode_key].1["moved_object"], "mug_1");
    assert_eq!(m[&key(SlidesInTheWait).episode_key].1["drifted_object"], "bowl_1");
    assert_eq!(m[&key(Crashes).episode_key].1["error_kind"], "sim_unstable");
    assert_eq!(m[&key(HalfTheGoal).episode_key].1["goal_progress"], "true");
    assert_eq!(m[&key(Idle).episode_key].1["goal_progress"], "false");

    // The summary counts the same rows and flags the harness faults.
    let summary = std::fs::read_to_string(out.join("failure_summary.csv")).unwrap();
    let rows: Vec<Vec<&str>> = summary.lines().skip(1).map(|l| l.split(',').collect()).collect();
    let n: usize = rows.iter().map(|r| r[4].parse::<usize>().unwrap()).sum();
    assert_eq!(n, expected.len());
    for r in &rows {
        let harness = matches!(r[2], "error" | "init_drift" | "saturated_actions");
        assert_eq!(r[3], harness.to_string(), "{r:?}");
        assert_eq!(r[5], expected.len().to_string(), "n_failed: {r:?}");
    }
}

#[test]
fn last_step_scoring_names_the_goal_that_did_not_last_transient_success() {
    let run = run();
    let out = test_dir("failure-modes", "last-step");
    let m = failures(&run, &out, &["--success", "last-step"]);
    assert_eq!(mode_of(&m, Transient), Some("transient_success"));
    assert_eq!(mode_of(&m, Succeeds), None);
    assert_eq!(m[&key(Transient).episode_key].1["success_definition"], "last-step");
    // A shorter cap turns the late success into a failure: both its terms come true together at
    // policy step 20, past a cap of 15, so within the cap there is no progress and no grasp.
    let capped = failures(&run, &test_dir("failure-modes", "cap"), &["--cap", "15"]);
    assert_eq!(mode_of(&capped, Succeeds), Some("timeout"));
}

#[test]
fn thresholds_edited_in_one_place_change_the_modes_of_a_stored_run() {
    let run = run();
    let queries = test_dir("failure-modes", "queries");
    for entry in std::fs::read_dir(repo_root().join("queries")).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, queries.join(path.file_name().unwrap())).unwrap();
    }
    let file = queries.join("failure_modes.sql");
    let text = std::fs::read_to_string(&file).unwrap();
    let edited = text.replace("0.03  AS fall_m", "0.5   AS fall_m");
    assert_ne!(text, edited, "the fall_m threshold line is no longer where the test expects it");
    std::fs::write(&file, edited).unwrap();

    let out = test_dir("failure-modes", "edited");
    let status = Command::new(pipeline_bin())
        .args(["failures", "--run", run.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .env("LIBERO_QUERIES", &queries)
        .current_dir(repo_root())
        .output()
        .unwrap();
    let m = modes(&out);
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    // A 10 cm fall is no longer a drop under a 50 cm threshold: the grasp makes it incomplete.
    assert_eq!(mode_of(&m, DropsTheBowl), Some("incomplete"));
    assert_eq!(mode_of(&m, LiftsTheMug), Some("wrong_object"));
}
