//! `queries/generalisation.sql` and `generalisation_summary.sql` on a fixed, constructed run (real
//! episode Parquet parts written with the rollout's own builders, no simulation; as
//! `tests/failure_modes.rs` does): every number of every cell asserted, computed here from the
//! rows by hand: the rates and Wilson bounds, the paired branch (each variant's twin: the base row
//! of its task, init state, seed and instruction mode; Newcombe's paired interval, McNemar's p),
//! the fallback when some variant of a cell has no twin (the suite's base rows, the hybrid
//! interval), the difficulty rows (suites pooled), the error counts, and the summary's totals.

use libero_e2e::{ok, pipeline, test_dir, write_constructed_manifest, write_episode_parts};
use libero_udfs::episode::{EpisodeContext, EpisodeError, EpisodeProtocol, EpisodeSummary, episode_batch};
use libero_udfs::goal_evidence::GoalChanges;
use libero_udfs::steps_batch::{EpisodeKey, StepsBatchBuilder};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

const MAX_STEPS: u32 = 30;
const SEED: i64 = 7;

/// One constructed episode: `category` None is a base row.
struct Row {
    suite: &'static str,
    task: i32,
    init: i32,
    category: Option<&'static str>,
    difficulty: Option<i32>,
    success: bool,
    /// Ended in an error row at policy step 10 (a failure).
    error: bool,
}

const fn base(suite: &'static str, task: i32, init: i32, success: bool, error: bool) -> Row {
    Row { suite, task, init, category: None, difficulty: None, success, error }
}

const fn variant(
    suite: &'static str,
    task: i32,
    category: &'static str,
    difficulty: Option<i32>,
    success: bool,
) -> Row {
    Row { suite, task, init: 0, category: Some(category), difficulty, success, error: false }
}

/// The run. libero_spatial has base rows at init states 0 and 1 of tasks 0 and 1 (task 1's init 0
/// errored), so its Camera variants (init 0, tasks 0 and 1) all have twins; one of its Noise
/// variants is on task 2, which has no base row: that cell falls back to the suite's base rows.
/// libero_goal's base rows are at init states 1 and 2 only: no variant of it has a twin.
fn rows() -> Vec<Row> {
    let mut v4 = variant("libero_spatial", 1, "Camera", Some(2), false);
    v4.error = true;
    vec![
        base("libero_spatial", 0, 0, true, false),
        base("libero_spatial", 0, 1, true, false),
        base("libero_spatial", 1, 0, false, true),
        base("libero_spatial", 1, 1, true, false),
        variant("libero_spatial", 0, "Camera", Some(1), true), // twin succeeded: n11
        variant("libero_spatial", 0, "Camera", Some(1), false), // n10
        variant("libero_spatial", 1, "Camera", Some(2), true), // twin failed (errored): n01
        v4,                                                    // n00, itself an error
        variant("libero_spatial", 0, "Camera", None, false),   // n10
        variant("libero_spatial", 0, "Noise", Some(3), true),  // twin succeeded
        variant("libero_spatial", 2, "Noise", Some(3), false), // no twin
        base("libero_goal", 0, 1, true, false),
        base("libero_goal", 0, 2, false, false),
        variant("libero_goal", 0, "Camera", Some(1), true),
        variant("libero_goal", 0, "Camera", None, false),
    ]
}

fn write_run(dir: &Path) {
    let protocol = EpisodeProtocol {
        max_steps: MAX_STEPS,
        num_steps_wait: 10,
        stop_on_success: false,
        instruction_source: Default::default(),
        realtime: None,
        protocol: Some(Default::default()),
    };
    for (i, r) in rows().iter().enumerate() {
        let hash = format!("{i:012x}");
        let key = EpisodeKey::with_variant(r.suite, r.task, r.init, SEED, r.category.map(|_| hash.as_str()));
        let n_steps = if r.error { 10 } else { MAX_STEPS };
        let mut goal_changes = GoalChanges::default();
        for p in 0..n_steps {
            goal_changes.record(p, r.success && p >= 5);
        }
        let summary = EpisodeSummary {
            instruction: "constructed".into(),
            instruction_source: "bddl",
            start_sha256: None,
            n_policy_steps: n_steps,
            first_success_step: r.success.then_some(5),
            final_goal: r.success,
            goal_changes,
            goal_terms: vec!["on bowl_1 plate_1".into()],
            objects_of_interest: vec!["bowl_1".into()],
            error: r.error.then(|| EpisodeError { kind: "sim_unstable", message: "constructed crash".into() }),
            wall_s: 1.0,
            sim_s: 1.0,
            policy_s: 0.0,
            render_s: 0.0,
            started_at: None,
        };
        let params = r.category.map(|c| format!("{{\"constructed\":\"{c} {i}\"}}"));
        let ctx = EpisodeContext {
            policy: "constructed",
            perturbation_params: params.as_deref(),
            run_config: "constructed",
            protocol: &protocol,
        };
        use arrow::array::{ArrayRef, Int32Array, RecordBatch, StringArray};
        // the spec's columns, as `pipeline specs --benchmark libero-plus` types them
        let extras = RecordBatch::try_from_iter_with_nullable([
            ("benchmark", Arc::new(StringArray::from(vec!["libero_plus"])) as ArrayRef, true),
            ("category", Arc::new(StringArray::from(vec![r.category])), true),
            ("difficulty", Arc::new(Int32Array::from(vec![r.difficulty])), true),
            ("instruction_mode", Arc::new(StringArray::from(vec!["bddl"])), true),
        ])
        .unwrap();
        let steps = StepsBatchBuilder::new(key.clone(), vec!["bowl_1".into()]);
        write_episode_parts(dir, &key, steps, &episode_batch(&key, &summary, &ctx, Some(&extras)).unwrap());
    }
    // the spec table the run was made from: its extra columns are the episodes' extras
    use arrow::array::{ArrayRef, Int32Array, Int64Array, RecordBatch, StringArray};
    let rows = rows();
    let specs = RecordBatch::try_from_iter_with_nullable([
        ("suite", Arc::new(StringArray::from_iter_values(rows.iter().map(|r| r.suite))) as ArrayRef, false),
        ("task_id", Arc::new(Int32Array::from_iter_values(rows.iter().map(|r| r.task))), false),
        ("init_state_id", Arc::new(Int32Array::from_iter_values(rows.iter().map(|r| r.init))), false),
        ("seed", Arc::new(Int64Array::from_iter_values(rows.iter().map(|_| SEED))), false),
        ("benchmark", Arc::new(StringArray::from_iter_values(rows.iter().map(|_| "libero_plus"))), true),
        ("category", Arc::new(StringArray::from_iter(rows.iter().map(|r| r.category))), true),
        ("difficulty", Arc::new(Int32Array::from_iter(rows.iter().map(|r| r.difficulty))), true),
        ("instruction_mode", Arc::new(StringArray::from_iter_values(rows.iter().map(|_| "bddl"))), true),
    ])
    .unwrap();
    std::fs::write(dir.join("specs.parquet"), libero_udfs::run_store::parquet_bytes(&specs, None).unwrap()).unwrap();
    write_constructed_manifest(dir, "constructed", 10);
}

/// A CSV of the binary as rows of column -> value (no quoted commas in these tables but the
/// summary's note and published column, which the checks below do not read).
fn csv(path: &Path) -> Vec<BTreeMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(str::to_string).collect();
    lines.map(|l| header.iter().cloned().zip(l.split(',').map(str::to_string)).collect()).collect()
}

/// The Wilson 95% interval, written out here (z = Φ⁻¹(0.975)).
fn wilson(k: u64, n: u64) -> (f64, f64) {
    let z = 1.959_963_984_540_054_f64;
    let (k, n) = (k as f64, n as f64);
    let p = k / n;
    let d = 1.0 + z * z / n;
    let c = (p + z * z / (2.0 * n)) / d;
    let h = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / d;
    (if k == 0.0 { 0.0 } else { c - h }, if k == n { 1.0 } else { c + h })
}

/// What a cell must hold.
struct Expect {
    n: u64,
    k: u64,
    errors: u64,
    /// Some((n11, n10, n01, n00, twins that errored)) for a paired cell; None: the suite's base
    /// rows (k, n, errors) below.
    paired: Option<(u64, u64, u64, u64, u64)>,
    suite_base: (u64, u64, u64),
}

fn check(row: &BTreeMap<String, String>, e: &Expect) {
    let f = |c: &str| -> f64 { row[c].parse().unwrap_or_else(|_| panic!("{c} = '{}' in {row:?}", row[c])) };
    let close = |c: &str, want: f64| {
        let got = f(c);
        assert!((got - want).abs() < 1e-12, "{c}: {got} != {want} in {row:?}");
    };
    let int = |c: &str| row[c].parse::<u64>().unwrap_or_else(|_| panic!("{c} in {row:?}"));
    assert_eq!((int("n_total"), int("n_success"), int("n_errors")), (e.n, e.k, e.errors), "{row:?}");
    let p = e.k as f64 / e.n as f64;
    let (l, u) = wilson(e.k, e.n);
    close("success_rate", p);
    close("ci_lo", l);
    close("ci_hi", u);
    let (bk, bn, be) = e.suite_base;
    close("suite_base_rate", bk as f64 / bn as f64);
    assert_eq!((int("suite_base_n"), int("suite_base_n_errors")), (bn, be), "{row:?}");
    match e.paired {
        Some((n11, n10, n01, n00, twin_errors)) => {
            assert_eq!(row["paired"], "true", "{row:?}");
            let n = n11 + n10 + n01 + n00;
            assert_eq!(n, e.n, "every variant has its twin");
            assert_eq!((int("n11"), int("n10"), int("n01"), int("n00")), (n11, n10, n01, n00), "{row:?}");
            assert_eq!((int("base_n"), int("base_n_errors")), (n, twin_errors), "{row:?}");
            close("base_rate", (n11 + n10) as f64 / n as f64);
            close("drop_from_base", (n10 as f64 - n01 as f64) / n as f64);
            let (lo, hi) = libero_udfs::newcombe::newcombe_paired_interval(n11, n10, n01, n00, 0.95).unwrap();
            close("drop_lo", lo);
            close("drop_hi", hi);
            // McNemar's exact p for these discordant counts, by hand: min(1, 2·P(X ≤ min) of Bin(b + c, ½))
            let (b, c) = (n10.min(n01), n10 + n01);
            let tail: f64 = (0..=b).map(|i| binom(c, i)).sum::<f64>() / 2f64.powi(c as i32);
            close("mcnemar_p", (2.0 * tail).min(1.0));
        }
        None => {
            assert_eq!(row["paired"], "false", "{row:?}");
            let pb = bk as f64 / bn as f64;
            let (lb, ub) = wilson(bk, bn);
            assert_eq!((int("base_n"), int("base_n_errors")), (bn, be), "{row:?}");
            close("base_rate", pb);
            close("drop_from_base", pb - p);
            close("drop_lo", pb - p - ((pb - lb).powi(2) + (u - p).powi(2)).sqrt());
            close("drop_hi", pb - p + ((ub - pb).powi(2) + (p - l).powi(2)).sqrt());
            assert_eq!(row["mcnemar_p"], "", "no McNemar without pairs: {row:?}");
        }
    }
}

fn binom(n: u64, k: u64) -> f64 {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
}

#[test]
fn the_generalisation_tables_of_a_fixed_run_are_the_numbers_worked_by_hand() {
    let dir = test_dir("generalisation", "fixed");
    let run = dir.join("run");
    write_run(&run);
    let out = dir.join("out");
    let stdout = ok(pipeline(&["generalisation", "--run", run.to_str().unwrap(), "--out", out.to_str().unwrap()]));
    let cells = csv(&out.join("generalisation.csv"));
    let cell = |suite: &str, category: &str, difficulty: &str| {
        let found: Vec<_> = cells
            .iter()
            .filter(|r| r["base_suite"] == suite && r["category"] == category && r["difficulty"] == difficulty)
            .collect();
        assert_eq!(found.len(), 1, "{suite} {category} difficulty '{difficulty}':\n{stdout}");
        found[0]
    };
    let spatial_base = (3, 4, 1);
    let all_base = (4, 6, 1); // libero_spatial's 3/4 and libero_goal's 1/2
    // libero_spatial × Camera: every variant has its twin.
    check(
        cell("libero_spatial", "Camera", ""),
        &Expect { n: 5, k: 2, errors: 1, paired: Some((1, 2, 1, 1, 2)), suite_base: spatial_base },
    );
    // libero_spatial × Noise: the task-2 variant has no twin, so the whole cell falls back.
    check(
        cell("libero_spatial", "Noise", ""),
        &Expect { n: 2, k: 1, errors: 0, paired: None, suite_base: spatial_base },
    );
    // libero_goal × Camera: no twins at all.
    check(cell("libero_goal", "Camera", ""), &Expect { n: 2, k: 1, errors: 0, paired: None, suite_base: (1, 2, 0) });
    // Pooled over the suites: 5 of 7 Camera variants have twins, so the suites' base rows.
    check(cell("all", "Camera", ""), &Expect { n: 7, k: 3, errors: 1, paired: None, suite_base: all_base });
    check(cell("all", "Noise", ""), &Expect { n: 2, k: 1, errors: 0, paired: None, suite_base: all_base });
    // Difficulty rows, suites pooled; unlabelled variants are in none of them.
    check(cell("all", "Camera", "1"), &Expect { n: 3, k: 2, errors: 0, paired: None, suite_base: all_base });
    // difficulty 2: both libero_spatial task 1 variants, whose twin errored: paired, base rate 0
    check(
        cell("all", "Camera", "2"),
        &Expect { n: 2, k: 1, errors: 1, paired: Some((0, 0, 1, 1, 2)), suite_base: all_base },
    );
    check(cell("all", "Noise", "3"), &Expect { n: 2, k: 1, errors: 0, paired: None, suite_base: all_base });
    assert_eq!(cells.len(), 8, "{stdout}");

    // The summary: this run's categories (suites pooled) and its totals.
    let summary = csv(&out.join("generalisation_summary.csv"));
    let ours = summary.iter().find(|r| r["model"] == "this run").unwrap();
    let f = |c: &str| ours[c].parse::<f64>().unwrap();
    let r4 = |x: f64| (x * 1e4).round() / 1e4;
    let (camera, noise) = (3.0 / 7.0, 1.0 / 2.0);
    assert_eq!(f("camera"), r4(camera));
    assert_eq!(f("noise"), r4(noise));
    assert_eq!(f("total_weighted"), r4(4.0 / 9.0));
    assert_eq!(f("mean_categories"), r4((camera + noise) / 2.0));
    assert_eq!(f("robust_avg"), r4((camera + noise) / 2.0));
    assert_eq!(f("base_rate"), r4(4.0 / 6.0));
    assert_eq!(
        (ours["n_variants"].as_str(), ours["n_errors"].as_str(), ours["n_categories"].as_str()),
        ("9", "1", "2")
    );
    for c in ["robot", "language", "light", "background", "layout"] {
        assert_eq!(ours[c], "", "{c} was not run");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
