//! `pipeline compare`, `pipeline sample-size` and the `published` table, through the binary, on
//! runs written with the library's own builders (real Parquet parts on disk, no simulation) whose
//! paired outcomes are known by construction.

use libero_e2e::{ok, pipeline, test_dir, write_constructed_manifest, write_episode_parts};
use libero_udfs::episode::{EpisodeContext, EpisodeProtocol, EpisodeSummary, episode_batch};
use libero_udfs::steps_batch::{EpisodeKey, StepRecord, StepsBatchBuilder};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

const MAX_STEPS: u32 = 20;
const WAIT: u32 = 2;

/// How an episode's goal evolves over its policy steps.
#[derive(Clone, Copy, PartialEq)]
enum Outcome {
    /// The goal never holds.
    Fail,
    /// The goal holds from policy step 10 to the end (a success under every definition).
    Success,
    /// The goal holds at policy steps 5..8 only (any-step success, last-step failure).
    Transient,
}

fn goal(outcome: Outcome, p: u32) -> bool {
    match outcome {
        Outcome::Fail => false,
        Outcome::Success => p >= 10,
        Outcome::Transient => (5..8).contains(&p),
    }
}

fn tmp(name: &str) -> PathBuf {
    test_dir("compare", name)
}

/// A run folder with one steps part and one episode part per (suite, task, init, seed, outcome).
fn write_run(dir: &Path, policy: &str, episodes: &[(&str, i32, i32, i64, Outcome)]) {
    std::fs::create_dir_all(dir.join("steps")).unwrap();
    std::fs::create_dir_all(dir.join("episodes")).unwrap();
    let protocol = EpisodeProtocol {
        max_steps: MAX_STEPS,
        num_steps_wait: WAIT,
        stop_on_success: false,
        instruction_source: Default::default(),
        realtime: None,
        protocol: Some(Default::default()),
    };
    for &(suite, task, init, seed, outcome) in episodes {
        let key = EpisodeKey::new(suite, task, init, seed);
        let mut b = StepsBatchBuilder::new(key.clone(), vec!["bowl".into()]);
        let mut first = None;
        for t in 0..WAIT + MAX_STEPS {
            let p = t.checked_sub(WAIT);
            let g = p.is_some_and(|p| goal(outcome, p));
            if g && first.is_none() {
                first = p;
            }
            b.push(&StepRecord {
                step: t as i32,
                policy_step: p.map(|x| x as i32),
                action: first_action_of_b(policy, suite, init, p),
                eef_pos: [0.0; 3],
                eef_quat: [1.0, 0.0, 0.0, 0.0],
                gripper_qpos: [0.0; 2],
                joint_pos: [0.0; 7],
                object_poses: &[([0.0; 3], [1.0, 0.0, 0.0, 0.0])],
                goal: g,
                goal_terms: &[g],
                gripper_contacts: &[],
                sim_ms: 1.0,
                policy_ms: 0.0,
                render_ms: 0.0,
                timing: None,
                held: false,
            });
        }
        let summary = EpisodeSummary {
            instruction: format!("task {task} of {suite}"),
            instruction_source: "bddl",
            // the same start for the same (task, init, seed) in any suite, but in `_swap`
            start_sha256: Some(format!("{task}/{init}/{seed}{}", if suite.ends_with("_swap") { "/moved" } else { "" })),
            n_policy_steps: MAX_STEPS,
            first_success_step: first,
            final_goal: goal(outcome, MAX_STEPS - 1),
            goal_changes: libero_udfs::goal_evidence::GoalChanges::from_goals((0..MAX_STEPS).map(|p| goal(outcome, p))),
            goal_terms: vec!["on bowl_1 plate_1".into()],
            objects_of_interest: vec!["bowl".into()],
            error: None,
            wall_s: 1.0,
            sim_s: 1.0,
            policy_s: 0.0,
            render_s: 0.0,
            started_at: None,
        };
        let ctx = EpisodeContext { policy, perturbation_params: None, run_config: policy, protocol: &protocol };
        let ep = episode_batch(&key, &summary, &ctx, None).unwrap();
        write_episode_parts(dir, &key, b, &ep);
    }
    write_constructed_manifest(dir, policy, WAIT);
}

/// Every action is 0 but B's first in libero_spatial's init state 9 (both tasks): two of its
/// dimensions differ from A's, by 0.25 and 1.
fn first_action_of_b(policy: &str, suite: &str, init: i32, policy_step: Option<u32>) -> [f32; 7] {
    match (policy, suite, init, policy_step) {
        ("policy-b", "libero_spatial", 9, Some(0)) => [0.25, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0],
        _ => [0.0; 7],
    }
}

/// The two runs. libero_spatial (tasks 0 and 1, inits 0..9, seed 7): per task, A/B outcomes
/// give 4 both, 1 A-only, 3 B-only (2 of task 0's and 1 of task 1's are transient in B), 2
/// neither. libero_object (task 0): inits 0..9 paired with 5 both and 5 neither; A alone has
/// inits 10, 11 and B alone 12, 13, 14.
/// Built once: tests run in parallel, and a second build would delete the folder under the first.
fn paired_runs() -> (PathBuf, PathBuf) {
    static RUNS: std::sync::OnceLock<(PathBuf, PathBuf)> = std::sync::OnceLock::new();
    RUNS.get_or_init(build_paired_runs).clone()
}

fn build_paired_runs() -> (PathBuf, PathBuf) {
    use Outcome::*;
    let d = tmp("runs");
    let (mut a, mut b) = (vec![], vec![]);
    for task in 0..2 {
        let transient_in_b = if task == 0 { 2 } else { 1 };
        for init in 0..10 {
            let (oa, ob) = match init {
                0..4 => (Success, Success),
                4 => (Success, Fail),
                5..8 => (Fail, if init - 5 < transient_in_b { Transient } else { Success }),
                _ => (Fail, Fail),
            };
            a.push(("libero_spatial", task, init, 7, oa));
            b.push(("libero_spatial", task, init, 7, ob));
        }
    }
    for init in 0..10 {
        let o = if init < 5 { Success } else { Fail };
        a.push(("libero_object", 0, init, 7, o));
        b.push(("libero_object", 0, init, 7, o));
    }
    a.extend([("libero_object", 0, 10, 7, Success), ("libero_object", 0, 11, 7, Fail)]);
    b.extend((12..15).map(|i| ("libero_object", 0, i, 7, Success)));
    write_run(&d.join("a"), "policy-a", &a);
    write_run(&d.join("b"), "policy-b", &b);
    (d.join("a"), d.join("b"))
}

/// A CSV written by the pipeline, as rows of column → value (no quoted commas in these tests).
fn read_csv(path: &Path) -> Vec<HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(str::to_string).collect();
    lines.map(|l| header.iter().cloned().zip(l.split(',').map(str::to_string)).collect()).collect()
}

fn row<'a>(rows: &'a [HashMap<String, String>], key: &str, value: &str) -> &'a HashMap<String, String> {
    rows.iter().find(|r| r[key] == value).unwrap_or_else(|| panic!("no row with {key} = {value}"))
}

fn f(r: &HashMap<String, String>, col: &str) -> f64 {
    r[col].parse().unwrap_or_else(|e| panic!("{col} = {:?}: {e}", r[col]))
}

/// The counts columns (n_paired, n_both, n_a_only, n_b_only, n_neither, n_only_in_a, n_only_in_b).
fn counts(r: &HashMap<String, String>) -> [String; 7] {
    ["n_paired", "n_both", "n_a_only", "n_b_only", "n_neither", "n_only_in_a", "n_only_in_b"].map(|c| r[c].clone())
}

fn strs<const N: usize>(v: [i64; N]) -> [String; N] {
    v.map(|x| x.to_string())
}

/// The statistics of a row against the library functions (themselves tested against
/// statsmodels in libero-udfs), called with B as the first run.
fn check_statistics(r: &HashMap<String, String>, [both, a_only, b_only, neither]: [u64; 4]) {
    let n = (both + a_only + b_only + neither) as f64;
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12;
    assert!(close(f(r, "success_rate_a"), (both + a_only) as f64 / n));
    assert!(close(f(r, "success_rate_b"), (both + b_only) as f64 / n));
    assert!(close(f(r, "diff_b_minus_a"), (b_only as f64 - a_only as f64) / n));
    let (lo, hi) = libero_udfs::newcombe::newcombe_paired_interval(both, b_only, a_only, neither, 0.95).unwrap();
    assert!(close(f(r, "diff_ci_lo"), lo) && close(f(r, "diff_ci_hi"), hi), "{r:?} vs ({lo}, {hi})");
    assert!(close(f(r, "mcnemar_p"), libero_udfs::mcnemar::mcnemar_exact_p(a_only, b_only)));
}

#[test]
fn compare_counts_the_discordant_pairs_and_the_unpaired_episodes() {
    let (a, b) = paired_runs();
    let out = a.parent().unwrap().join("outputs");
    let stdout = ok(pipeline(&["compare", a.to_str().unwrap(), b.to_str().unwrap(), "--out", out.to_str().unwrap()]));
    assert!(stdout.contains("any-step") && stdout.contains("libero_spatial"), "{stdout}");
    let suites = read_csv(&out.join("compare.csv"));
    assert_eq!(
        suites.iter().map(|r| r["suite"].as_str()).collect::<Vec<_>>(),
        ["libero_object", "libero_spatial", "all"]
    );

    let spatial = row(&suites, "suite", "libero_spatial");
    assert_eq!(counts(spatial), strs([20, 8, 2, 6, 4, 0, 0]));
    assert_eq!((spatial["policy_a"].as_str(), spatial["policy_b"].as_str()), ("policy-a", "policy-b"));
    assert_eq!((spatial["n_success_a"].as_str(), spatial["n_success_b"].as_str()), ("10", "14"));
    check_statistics(spatial, [8, 2, 6, 4]);
    // b = 2, c = 6: 2·P(X ≤ 2 | 8, ½) = 2·(1 + 8 + 28)/256
    assert!((f(spatial, "mcnemar_p") - 74.0 / 256.0).abs() < 1e-12);
    assert!(f(spatial, "diff_ci_lo") < 0.0 && f(spatial, "diff_ci_hi") > 0.2);

    let object = row(&suites, "suite", "libero_object");
    assert_eq!(counts(object), strs([10, 5, 0, 0, 5, 2, 3]));
    check_statistics(object, [5, 0, 0, 5]);
    assert_eq!(f(object, "mcnemar_p"), 1.0, "no discordant pair");

    let all = row(&suites, "suite", "all");
    assert_eq!(counts(all), strs([30, 13, 2, 6, 9, 2, 3]));
    check_statistics(all, [13, 2, 6, 9]);

    // the 30 paired episodes' first actions: all equal but init 9's two in libero_spatial
    assert!(stdout.contains("28 of 30 episodes equal in every dimension, 206 of 210 dimensions"), "{stdout}");
    let first = read_csv(&out.join("compare_first_actions.csv"));
    assert_eq!(first.len(), 1);
    assert_eq!(
        [&first[0]["n_episodes"], &first[0]["n_episodes_all_equal"], &first[0]["n_dims_equal"], &first[0]["n_dims"]],
        ["30", "28", "206", "210"]
    );
    assert_eq!(f(&first[0], "max_abs_diff"), 1.0);
    assert!((f(&first[0], "mean_abs_diff") - 2.5 / 210.0).abs() < 1e-12);

    let tasks = read_csv(&out.join("compare_by_task.csv"));
    assert_eq!(tasks.len(), 3);
    let t0 = tasks.iter().find(|r| r["suite"] == "libero_spatial" && r["task_id"] == "0").unwrap();
    assert_eq!(counts(t0), strs([10, 4, 1, 3, 2, 0, 0]));
    assert_eq!(t0["instruction"], "task 0 of libero_spatial");
    check_statistics(t0, [4, 1, 3, 2]);

    // last-step: B's transient successes (2 in task 0, 1 in task 1) become failures, in both runs alike
    ok(pipeline(&[
        "compare",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--success",
        "last-step",
        "--out",
        out.to_str().unwrap(),
    ]));
    let suites = read_csv(&out.join("compare.csv"));
    let spatial = row(&suites, "suite", "libero_spatial");
    assert_eq!(spatial["success_definition"], "last-step");
    assert_eq!(counts(spatial), strs([20, 8, 2, 3, 7, 0, 0]));
    check_statistics(spatial, [8, 2, 3, 7]);

    // a cap of 9 policy steps: every Success (goal from step 10) fails; the transients still count any-step
    ok(pipeline(&["compare", a.to_str().unwrap(), b.to_str().unwrap(), "--cap", "9", "--out", out.to_str().unwrap()]));
    let suites = read_csv(&out.join("compare.csv"));
    let spatial = row(&suites, "suite", "libero_spatial");
    assert_eq!((spatial["episode_length_cap_a"].as_str(), spatial["episode_length_cap_b"].as_str()), ("9", "9"));
    assert_eq!(counts(spatial), strs([20, 0, 0, 3, 17, 0, 0]));
}

#[test]
fn runs_without_a_common_episode_key_are_an_error_that_says_so() {
    let d = tmp("disjoint");
    write_run(&d.join("a"), "policy-a", &[("libero_goal", 0, 0, 7, Outcome::Success)]);
    write_run(&d.join("b"), "policy-b", &[("libero_goal", 0, 0, 0, Outcome::Success)]);
    let out = pipeline(&["compare", d.join("a").to_str().unwrap(), d.join("b").to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("share no episode key") && err.contains("same spec"), "{err}");
    let out = pipeline(&["compare", d.join("a").to_str().unwrap(), d.join("nothing").to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no run"), "a missing run is named");
}

#[test]
fn sample_size_prints_trials_per_task_and_per_suite() {
    // statsmodels: samplesize_proportions_2indep_onetail(0.1, 0.8, 0.8) = 198.96… → 199 per task,
    // and a suite of 10 tasks pools them: 20 per task.
    let stdout = ok(pipeline(&["sample-size", "--p0", "0.8", "--delta", "0.1"]));
    let line = |scope: &str| stdout.lines().find(|l| l.contains(scope)).unwrap_or_else(|| panic!("{stdout}"));
    let nums = |l: &str| l.split('|').map(str::trim).filter(|c| !c.is_empty()).map(str::to_string).collect::<Vec<_>>();
    let task = nums(line("one task"));
    assert_eq!(task[task.len() - 2..], ["199", "199"]);
    let suite = nums(line("suite of 10 tasks"));
    assert_eq!(suite[suite.len() - 2..], ["20", "200"]);
    let bad = pipeline(&["sample-size", "--p0", "0.95", "--delta", "0.1"]);
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("[0, 1]"));
}

#[test]
fn the_published_table_is_in_every_sql_session() {
    let (a, _) = paired_runs();
    let q = "SELECT count(DISTINCT model) FROM published WHERE benchmark = 'libero' AND suite = 'libero_spatial'";
    let stdout = ok(pipeline(&["sql", q, "--run", a.to_str().unwrap(), "--csv"]));
    let n: u32 = stdout.lines().nth(1).unwrap().parse().unwrap();
    assert!(n >= 7, "{stdout}");
    let q = "SELECT suite, success_rate FROM published WHERE model = 'pi0.5' AND reported_by = 'authors' \
             AND benchmark = 'libero' ORDER BY suite";
    let stdout = ok(pipeline(&["sql", q, "--run", a.to_str().unwrap(), "--csv"]));
    assert_eq!(stdout.lines().count(), 5, "{stdout}");
    assert!(stdout.contains("libero_10,0.924"), "{stdout}");
}

/// `queries/robustness.sql` pairs a perturbed episode with the base's when both start alike
/// (`start_sha256`), and only then: libero_goal_lan here starts as libero_goal does (as a
/// language-only variant would), libero_goal_swap does not. Paired: the drop is (n10 − n01)/n
/// with Newcombe's paired interval and McNemar's p; unpaired: base − perturbed with the
/// independent-samples interval around it.
#[test]
fn robustness_pairs_episodes_that_start_alike() {
    use Outcome::*;
    let d = tmp("robustness");
    let mut eps = vec![];
    // base vs lan over inits 0..10: 4 both, 3 base only, 1 lan only, 2 neither
    for init in 0..10 {
        let (base, lan) = match init {
            0..4 => (Success, Success),
            4..7 => (Success, Fail),
            7 => (Fail, Success),
            _ => (Fail, Fail),
        };
        eps.push(("libero_goal", 0, init, 7, base));
        eps.push(("libero_goal_lan", 0, init, 7, lan));
        eps.push(("libero_goal_swap", 0, init, 7, if init < 2 { Success } else { Fail }));
    }
    write_run(&d, "constructed", &eps);
    let rows = libero_e2e::sql_rows(
        &d,
        "SELECT perturbation, paired, n_pairs, drop_from_base, drop_ci_lo, drop_ci_hi, mcnemar_p, \
         newcombe_paired_lo(4, 3, 1, 2), newcombe_paired_hi(4, 3, 1, 2), base_rate, success_rate \
         FROM robustness ORDER BY perturbation",
        &[],
    );
    let f = |r: &Vec<String>, i: usize| r[i].parse::<f64>().unwrap();
    let lan = rows.iter().find(|r| r[0] == "lan").unwrap();
    assert_eq!((lan[1].as_str(), lan[2].as_str()), ("true", "10"), "{lan:?}");
    assert!((f(lan, 3) - 0.2).abs() < 1e-12, "{lan:?}");
    assert_eq!((f(lan, 4), f(lan, 5)), (f(lan, 7), f(lan, 8)), "Newcombe's paired interval: {lan:?}");
    assert!(f(lan, 6) > 0.0 && f(lan, 6) <= 1.0, "McNemar's p: {lan:?}");
    let swap = rows.iter().find(|r| r[0] == "swap").unwrap();
    assert_eq!((swap[1].as_str(), swap[2].as_str()), ("false", ""), "{swap:?}");
    assert!((f(swap, 3) - (0.7 - 0.2)).abs() < 1e-12 && (f(swap, 9) - 0.7).abs() < 1e-12, "{swap:?}");
    assert!(f(swap, 4) < f(swap, 3) && f(swap, 3) < f(swap, 5), "{swap:?}");
}
