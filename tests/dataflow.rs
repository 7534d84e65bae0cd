//! The episode dataflow end to end, through the `pipeline` binary on the real environment:
//! specs → run (rollout UDF, per-episode Parquet parts) → SQL results; resume after SIGKILL;
//! bad spec files; error rows; re-scoring from stored steps; notebook access without Rust.

use arrow::array::{ArrayRef, Int32Array, Int64Array, RecordBatch, StringArray};
use arrow::datatypes::{Field, Schema};
use libero_e2e::{ok, pipeline, pipeline_bin, reference_python, repo_root, test_dir};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

fn tmp(name: &str) -> PathBuf {
    test_dir("dataflow", name)
}

fn sql(run: &Path, query: &str, extra: &[&str]) -> Vec<Vec<String>> {
    libero_e2e::sql_rows(run, query, extra)
}

fn sql_one(run: &Path, query: &str) -> String {
    sql(run, query, &[]).remove(0).remove(0)
}

fn write_parquet(path: &Path, columns: Vec<(&str, ArrayRef)>) {
    let schema =
        Schema::new(columns.iter().map(|(n, a)| Field::new(*n, a.data_type().clone(), true)).collect::<Vec<_>>());
    let batch = RecordBatch::try_new(Arc::new(schema), columns.into_iter().map(|(_, a)| a).collect()).unwrap();
    std::fs::write(path, libero_udfs::run_store::parquet_bytes(&batch, None).unwrap()).unwrap();
}

fn spec_columns(suite: &[&str], task: &[i32], init: &[i32], seed: &[i64]) -> Vec<(&'static str, ArrayRef)> {
    vec![
        ("suite", Arc::new(StringArray::from(suite.to_vec())) as ArrayRef),
        ("task_id", Arc::new(Int32Array::from(task.to_vec()))),
        ("init_state_id", Arc::new(Int32Array::from(init.to_vec()))),
        ("seed", Arc::new(Int64Array::from(seed.to_vec()))),
    ]
}

/// The README's baseline runs, CI-sized: random and lift on libero_spatial and libero_object,
/// 2 trials per task (80 episodes, each to its cap; with 10 trials, 400 episodes, this module's
/// tests took 224 s on 2 cores beside the others, with 2 trials 102 s alone). Shared by the tests
/// that read a real run.
const BASELINE_TRIALS: usize = 2;
/// Episodes of one suite in one baseline run.
const BASELINE_PER_SUITE: usize = 10 * BASELINE_TRIALS;
struct Baselines {
    dir: PathBuf,
}

fn baselines() -> &'static Baselines {
    static B: OnceLock<Baselines> = OnceLock::new();
    B.get_or_init(|| {
        let dir = tmp("baselines");
        let specs = dir.join("specs.parquet");
        ok(pipeline(&[
            "specs",
            "--suites",
            "libero_spatial,libero_object",
            "--trials",
            &BASELINE_TRIALS.to_string(),
            "-o",
            specs.to_str().unwrap(),
        ]));
        for policy in ["random", "lift"] {
            let t0 = Instant::now();
            ok(pipeline(&[
                "run",
                specs.to_str().unwrap(),
                "--out",
                dir.join(policy).to_str().unwrap(),
                "--policy",
                policy,
            ]));
            eprintln!("baseline {policy}: {} episodes in {:.0} s", 2 * BASELINE_PER_SUITE, t0.elapsed().as_secs_f64());
        }
        Baselines { dir }
    })
}

#[test]
fn specs_command_writes_the_canonical_protocol_table() {
    let d = tmp("specs");
    let out = d.join("s.parquet");
    ok(pipeline(&["specs", "--suites", "libero_goal,libero_10", "--trials", "50", "-o", out.to_str().unwrap()]));
    let file = std::fs::File::open(&out).unwrap();
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file).unwrap().build().unwrap();
    let batches: Vec<RecordBatch> = reader.map(Result::unwrap).collect();
    let rows: usize = batches.iter().map(|b| b.num_rows()).sum();
    assert_eq!(rows, 2 * 10 * 50);
    let b = &batches[0];
    let schema = b.schema();
    let names: Vec<&str> = schema.fields().iter().map(|f| f.name().as_str()).collect();
    assert_eq!(names, ["suite", "task_id", "init_state_id", "seed"]);
    let seed = b.column(3).as_any().downcast_ref::<Int64Array>().unwrap();
    assert!(seed.values().iter().all(|&s| s == 7), "canonical seed is 7");
    let init = b.column(2).as_any().downcast_ref::<Int32Array>().unwrap();
    assert_eq!(init.values().iter().max(), Some(&49), "init_state_id = trial index");
}

#[test]
fn bad_spec_files_are_rejected_before_any_episode_starts_with_the_rows_named() {
    let d = tmp("badspecs");
    // (name, spec columns, fragments the error must contain)
    type Case = (&'static str, Vec<(&'static str, ArrayRef)>, Vec<&'static str>);
    let cases: Vec<Case> = vec![
        (
            "missing",
            spec_columns(&["libero_spatial"], &[0], &[0], &[7]).into_iter().filter(|(n, _)| *n != "seed").collect(),
            vec!["lacks the column(s) seed"],
        ),
        (
            "unknown",
            spec_columns(&["libero_spatial", "libero_99", "libero_goal"], &[0, 0, 12], &[0, 0, 0], &[7, 7, 7]),
            vec!["row 1", "unknown suite \"libero_99\"", "row 2", "unknown task 12"],
        ),
        (
            "range",
            spec_columns(&["libero_object", "libero_object"], &[1, 1], &[49, 50], &[7, 3]),
            vec!["row 1", "init_state_id out of range", "seeds [0, 7] only"],
        ),
        (
            "duplicate",
            spec_columns(&["libero_10", "libero_10", "libero_10"], &[4, 5, 4], &[3, 3, 3], &[7, 7, 7]),
            vec!["row 2", "duplicate episode key libero_10/4/3/7 (first at row 0)"],
        ),
    ];
    for (name, columns, expect) in cases {
        let spec = d.join(format!("{name}.parquet"));
        write_parquet(&spec, columns);
        let run = d.join(format!("run-{name}"));
        let out = pipeline(&["run", spec.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", "lift"]);
        assert!(!out.status.success(), "{name}: accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        for e in expect {
            assert!(err.contains(e), "{name}: error lacks {e:?}:\n{err}");
        }
        assert!(!run.join("episodes").exists() && !run.join("manifest.json").exists(), "{name}: something ran");
    }
}

#[test]
fn baselines_score_at_most_five_percent_and_results_are_written_with_wilson_intervals() {
    let b = baselines();
    for policy in ["random", "lift"] {
        let run = b.dir.join(policy);
        let outputs = b.dir.join(format!("{policy}-outputs"));
        let out = pipeline(&["results", "--run", run.to_str().unwrap(), "--out", outputs.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        ok(out);
        assert!(!stderr.contains("WARNING"), "{policy}: {stderr}");
        let csv = std::fs::read_to_string(outputs.join("results.csv")).unwrap();
        let mut lines = csv.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        for col in [
            "suite",
            "n_total",
            "n_success",
            "success_rate",
            "ci_lo",
            "ci_hi",
            "episode_length_cap",
            "n_rollouts_per_task",
            "success_definition",
        ] {
            assert!(header.contains(&col), "{col} missing from {header:?}");
        }
        let col = |row: &[&str], name: &str| row[header.iter().position(|h| *h == name).unwrap()].to_string();
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        assert_eq!(rows.len(), 2);
        for row in &rows {
            let suite = col(row, "suite");
            assert_eq!(col(row, "n_total"), BASELINE_PER_SUITE.to_string(), "{suite}");
            assert_eq!(col(row, "n_rollouts_per_task"), BASELINE_TRIALS.to_string());
            assert_eq!(col(row, "success_definition"), "any-step");
            let cap = if suite == "libero_spatial" { "220" } else { "280" };
            assert_eq!(col(row, "episode_length_cap"), cap);
            let rate: f64 = col(row, "success_rate").parse().unwrap();
            assert!(rate <= 0.05, "{policy} scored {rate} on {suite}");
            let (lo, hi): (f64, f64) = (col(row, "ci_lo").parse().unwrap(), col(row, "ci_hi").parse().unwrap());
            // the Wilson score interval at 95%, worked here from its formula
            let (n, k, z) = (BASELINE_PER_SUITE as f64, col(row, "n_success").parse::<f64>().unwrap(), 1.959963984540054);
            let centre = (k + z * z / 2.0) / (n + z * z);
            let half = z / (n + z * z) * (k * (n - k) / n + z * z / 4.0).sqrt();
            assert!((lo - (centre - half).max(0.0)).abs() < 1e-9 && (hi - (centre + half)).abs() < 1e-9, "{lo} {rate} {hi}");
            assert!(lo <= rate && rate <= hi, "{lo} {rate} {hi}");
        }
        assert!(std::fs::read_to_string(outputs.join("results_by_task.csv")).unwrap().lines().count() == 21);
    }
}

#[test]
fn several_runs_side_by_side_in_one_results_table() {
    let b = baselines();
    let outputs = b.dir.join("side-by-side");
    let (random, lift) = (b.dir.join("random"), b.dir.join("lift"));
    let o = outputs.to_str().unwrap();
    ok(pipeline(&["results", "--run", random.to_str().unwrap(), "--run", lift.to_str().unwrap(), "--out", o]));
    let csv = std::fs::read_to_string(outputs.join("results.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let (suite, policy) =
        (header.iter().position(|h| *h == "suite").unwrap(), header.iter().position(|h| *h == "policy").unwrap());
    let mut rows: Vec<(String, String)> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<_>>())
        .map(|r| (r[policy].to_string(), r[suite].to_string()))
        .collect();
    rows.sort();
    let expect: Vec<(String, String)> = [
        ("lift", "libero_object"),
        ("lift", "libero_spatial"),
        ("random", "libero_object"),
        ("random", "libero_spatial"),
    ]
    .iter()
    .map(|(p, s)| (p.to_string(), s.to_string()))
    .collect();
    assert_eq!(rows, expect);
    // 2 runs × 20 tasks, each row saying whose it is
    let by_task = std::fs::read_to_string(outputs.join("results_by_task.csv")).unwrap();
    assert_eq!(by_task.lines().count(), 41);
    assert!(by_task.lines().nth(1).unwrap().contains(",random,") && by_task.lines().last().unwrap().contains(",lift,"));
}

#[test]
fn stored_steps_are_complete_and_the_users_query_works() {
    let run = baselines().dir.join("lift");
    // every episode ran to its cap: wait steps + max_steps rows, each step once
    let rows = sql(
        &run,
        "SELECT count(*) AS n, count(DISTINCT episode_key || '/' || CAST(step AS VARCHAR)) AS distinct_steps, \
         sum(CASE WHEN is_wait THEN 1 ELSE 0 END) AS waits FROM steps",
        &[],
    );
    let expect = BASELINE_PER_SUITE * (220 + 10) + BASELINE_PER_SUITE * (280 + 10);
    assert_eq!(rows[0], vec![expect.to_string(), expect.to_string(), (2 * BASELINE_PER_SUITE * 10).to_string()]);
    // the query from the docs
    let rows = sql(
        &run,
        "SELECT suite, wilson(success)['n'] AS n, wilson(success)['k'] AS k FROM episodes GROUP BY suite ORDER BY suite",
        &[],
    );
    let n = BASELINE_PER_SUITE.to_string();
    assert_eq!(rows, vec![vec!["libero_object", n.as_str(), "0"], vec!["libero_spatial", n.as_str(), "0"]]);
    // lift moves up 2.5 mm per step and never grasps: the eef rises; the gripper touches nothing
    let rise = sql_one(
        &run,
        "SELECT min(last.eef_pos[3] - first.eef_pos[3]) FROM \
         (SELECT episode_key, eef_pos FROM steps WHERE policy_step = 0) first \
         JOIN (SELECT episode_key, eef_pos FROM steps WHERE policy_step = 99) last USING (episode_key)",
    );
    // (the OSC covers only part of each 2.5 mm goal offset per step; measured ≈ 6 cm in 100 steps)
    assert!(rise.parse::<f64>().unwrap() > 0.03, "eef rose only {rise} m in 100 steps");
    let manifest = sql(&run, "SELECT policy, num_steps_wait, mujoco_version, stop_on_success FROM manifest", &[]);
    assert_eq!(manifest[0], vec!["lift", "10", "3.3.7", "false"]);
}

#[test]
fn a_killed_run_resumes_without_rerunning_or_duplicating_episodes() {
    let d = tmp("resume");
    let spec = d.join("specs.parquet");
    ok(pipeline(&[
        "specs",
        "--suites",
        "libero_object",
        "--tasks",
        "0,1,2",
        "--trials",
        "8",
        "-o",
        spec.to_str().unwrap(),
    ]));
    let run = d.join("run");
    let args = ["run", spec.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", "random"];
    let mut child = Command::new(pipeline_bin()).args(args).current_dir(repo_root()).spawn().unwrap();
    let t0 = Instant::now();
    let parts = |dir: &str| std::fs::read_dir(run.join(dir)).map(|r| r.count()).unwrap_or(0);
    while parts("episodes") < 4 {
        assert!(t0.elapsed() < Duration::from_secs(300), "no progress");
        assert!(child.try_wait().unwrap().is_none(), "finished before it could be killed");
        std::thread::sleep(Duration::from_millis(100));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let before = parts("episodes");
    assert!(before < 24, "all finished before the kill");
    let first_parts: Vec<(String, std::time::SystemTime)> = std::fs::read_dir(run.join("episodes"))
        .unwrap()
        .map(|e| e.unwrap())
        .map(|e| (e.file_name().to_string_lossy().into_owned(), e.metadata().unwrap().modified().unwrap()))
        .collect();
    let out = ok(pipeline(&args));
    assert!(out.contains("libero_object"), "{out}");
    // finished episodes were not re-run: their parts are untouched
    for (name, mtime) in first_parts {
        let now = std::fs::metadata(run.join("episodes").join(&name)).unwrap().modified().unwrap();
        assert_eq!(now, mtime, "{name} was rewritten");
    }
    assert_eq!(parts("episodes"), 24);
    let counts = sql(&run, "SELECT count(*), count(DISTINCT episode_key) FROM episodes", &[]);
    assert_eq!(counts[0], vec!["24", "24"]);
    let steps = sql(&run, "SELECT count(*), count(DISTINCT episode_key) FROM steps", &[]);
    assert_eq!(steps[0], vec![(24 * 290).to_string(), "24".into()]);
    // the same output with another configuration is refused
    let other = pipeline(&["run", spec.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", "lift"]);
    assert!(!other.status.success());
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(err.contains("another configuration") && err.contains("policy"), "{err}");
}

#[test]
fn a_run_made_on_older_bundles_is_refused_on_resume_with_the_reason() {
    let d = tmp("old-bundles");
    let spec = d.join("specs.parquet");
    write_parquet(&spec, spec_columns(&["libero_spatial"], &[4], &[1], &[7]));
    let run = d.join("run");
    let args = ["run", spec.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", "lift", "--max-steps", "3"];
    ok(pipeline(&args));
    // The same run as a format-1 build wrote it.
    let path = run.join("manifest.json");
    let mut manifest: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    manifest["bundle_format_version"] = 1.into();
    std::fs::write(&path, serde_json::to_vec(&manifest).unwrap()).unwrap();
    let out = pipeline(&args);
    assert!(!out.status.success(), "a format-1 run was resumed");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("task bundles of format 1") && err.contains("published loop") && err.contains("new --out"),
        "{err}"
    );
}

#[test]
fn an_erroring_episode_becomes_an_error_row_and_the_run_goes_on() {
    let d = tmp("errors");
    let spec = d.join("specs.parquet");
    let mut cols = spec_columns(&["libero_goal", "libero_goal"], &[2, 3], &[0, 1], &[7, 0]);
    cols.push(("operator_note", Arc::new(StringArray::from(vec!["first", "second"])) as ArrayRef));
    write_parquet(&spec, cols);
    let run = d.join("run");
    ok(pipeline(&["run", spec.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", "nan-at:3"]));
    let rows = sql(
        &run,
        "SELECT episode_key, error_kind, n_policy_steps, success, operator_note FROM episodes ORDER BY episode_key",
        &[],
    );
    assert_eq!(rows[0], vec!["libero_goal/2/0/7", "invalid_action", "3", "false", "first"]);
    assert_eq!(rows[1], vec!["libero_goal/3/1/0", "invalid_action", "3", "false", "second"]);
    let steps = sql(&run, "SELECT count(*) FROM steps", &[]);
    assert_eq!(steps[0][0], (2 * (10 + 3)).to_string(), "the steps before the error are kept");
    let scored =
        sql(&run, "SELECT count(*), sum(CAST(errored AS INT)), sum(CAST(scored_success AS INT)) FROM scored", &[]);
    assert_eq!(scored[0], vec!["2", "2", "0"]);
    libero_e2e::assert_goal_evidence_matches_steps(&run, 2);
}

/// A run written directly with the library's builders, where the success definitions disagree:
/// A: goal at policy steps 5..9 only; B: goal only at the last step; C: never;
/// D: goal from step 50 on. Caps: 100 policy steps, 10 wait steps.
fn synthetic_run() -> PathBuf {
    use libero_udfs::episode::{EpisodeContext, EpisodeProtocol, EpisodeSummary, episode_batch};
    use libero_udfs::steps_batch::{EpisodeKey, StepRecord, StepsBatchBuilder};
    let d = tmp("synthetic");
    std::fs::create_dir_all(d.join("steps")).unwrap();
    std::fs::create_dir_all(d.join("episodes")).unwrap();
    let protocol = EpisodeProtocol {
        max_steps: 100,
        num_steps_wait: 10,
        stop_on_success: false,
        instruction_source: Default::default(),
        realtime: None,
        protocol: Some(Default::default()),
    };
    let goal_at: [fn(u32) -> bool; 4] = [|p| (5..10).contains(&p), |p| p == 99, |_| false, |p| p >= 50];
    for (i, goal) in goal_at.iter().enumerate() {
        let key = EpisodeKey::new("libero_goal", 0, i as i32, 7);
        let mut b = StepsBatchBuilder::new(key.clone(), vec!["bowl".into()]);
        let mut first = None;
        for t in 0..110u32 {
            let p = t.checked_sub(10);
            let g = p.is_some_and(goal);
            if g && first.is_none() {
                first = p;
            }
            b.push(&StepRecord {
                step: t as i32,
                policy_step: p.map(|x| x as i32),
                action: [0.0; 7],
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
            instruction: "put the bowl somewhere".into(),
            instruction_source: "bddl",
            start_sha256: None,
            n_policy_steps: 100,
            first_success_step: first,
            final_goal: goal(99),
            goal_changes: libero_udfs::goal_evidence::GoalChanges::from_goals((0..100).map(goal)),
            goal_terms: vec!["on bowl_1 plate_1".into()],
            objects_of_interest: vec!["bowl".into()],
            error: None,
            wall_s: 1.0,
            sim_s: 1.0,
            policy_s: 0.0,
            render_s: 0.0,
            started_at: None,
        };
        let ctx =
            EpisodeContext { policy: "synthetic", perturbation_params: None, run_config: "test", protocol: &protocol };
        let ep = episode_batch(&key, &summary, &ctx, None).unwrap();
        let write = |dir: &str, batch: &RecordBatch| {
            let bytes = libero_udfs::run_store::parquet_bytes(batch, None).unwrap();
            std::fs::write(d.join(dir).join(key.part_name()), bytes).unwrap();
        };
        write("steps", &b.finish().unwrap());
        write("episodes", &ep);
    }
    let manifest = libero_schema::RunManifest {
        tables_version: libero_schema::tables::TABLES_VERSION,
        run_config: "test".into(),
        created_at: "2026-01-01T00:00:00Z".into(),
        git_revision: "test".into(),
        pipeline_version: "0".into(),
        mujoco_version: "3.3.7".into(),
        bundle_format_version: libero_schema::bundle_format::BUNDLE_FORMAT_VERSION,
        bundles_hash: "none".into(),
        policy: "synthetic".into(),
        policy_identity: serde_json::json!({}),
        num_steps_wait: 10,
        max_steps: Default::default(),
        instruction_source: Default::default(),
        stop_on_success: false,
        substeps_per_step: 25,
        control_freq_hz: 20,
        env: libero_schema::Benchmark::Libero,
        realtime: None,
        protocol: Default::default(),
    };
    std::fs::write(d.join("manifest.json"), serde_json::to_vec(&manifest).unwrap()).unwrap();
    d
}

#[test]
fn rescoring_the_same_steps_by_last_step_any_step_and_a_shorter_cap() {
    let run = synthetic_run();
    let score = |extra: &[&str]| -> Vec<Vec<String>> {
        sql(
            &run,
            "SELECT init_state_id, scored_success, success_definition, episode_length_cap FROM scored ORDER BY init_state_id",
            extra,
        )
    };
    let col = |rows: &[Vec<String>], c: usize| rows.iter().map(|r| r[c].clone()).collect::<Vec<_>>().join(" ");
    let any = score(&[]);
    assert_eq!(col(&any, 1), "true true false true");
    assert_eq!(col(&any, 2), "any-step any-step any-step any-step");
    let last = score(&["--success", "last-step"]);
    assert_eq!(col(&last, 1), "false true false true");
    let capped = score(&["--cap", "40"]);
    assert_eq!(col(&capped, 1), "true false false false");
    assert_eq!(col(&capped, 3), "40 40 40 40");
    let capped_last = score(&["--cap", "40", "--success", "last-step"]);
    assert_eq!(col(&capped_last, 1), "false false false false");
    // the stored default equals the any-step query
    assert_eq!(col(&sql(&run, "SELECT success FROM episodes ORDER BY init_state_id", &[]), 0), "true true false true");
    // results tables say which definition they used
    let outputs = run.join("outputs");
    for (def, expect) in [("any-step", "3"), ("last-step", "2")] {
        ok(pipeline(&[
            "results",
            "--run",
            run.to_str().unwrap(),
            "--success",
            def,
            "--out",
            outputs.to_str().unwrap(),
        ]));
        let csv = std::fs::read_to_string(outputs.join("results.csv")).unwrap();
        let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
        let row: Vec<&str> = csv.lines().nth(1).unwrap().split(',').collect();
        let get = |n: &str| row[header.iter().position(|h| *h == n).unwrap()];
        assert_eq!((get("success_definition"), get("n_success"), get("n_total")), (def, expect, "4"));
    }
}

#[test]
fn runs_read_in_pyarrow_polars_and_duckdb_without_rust() {
    let run = baselines().dir.join("random");
    let script = r#"
import sys, pyarrow.dataset as ds, polars as pl, duckdb
run = sys.argv[1]
steps = ds.dataset(run + "/steps", format="parquet").to_table()
episodes = ds.dataset(run + "/episodes", format="parquet").to_table()
doc = steps.schema.field("policy_step").metadata[b"doc"].decode()
assert "wait" in doc, doc
pl_eps = pl.read_parquet(run + "/episodes/*.parquet")
pl_steps = pl.scan_parquet(run + "/steps/*.parquet").filter(pl.col("policy_step") == 0).select(pl.col("eef_pos").arr.get(2)).collect()
con = duckdb.connect()
n_duck, k_duck = con.execute(f"SELECT count(*), sum(success::INT) FROM read_parquet('{run}/episodes/*.parquet')").fetchone()
poses = con.execute(f"SELECT len(object_poses) FROM read_parquet('{run}/steps/*.parquet') LIMIT 1").fetchone()[0]
print(steps.num_rows, episodes.num_rows, pl_eps.height, n_duck, k_duck, pl_steps.height, poses)
"#;
    let out = Command::new(reference_python()).args(["-c", script, run.to_str().unwrap()]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: Vec<u64> = String::from_utf8_lossy(&out.stdout).split_whitespace().map(|x| x.parse().unwrap()).collect();
    let steps_rust: u64 = sql_one(&run, "SELECT count(*) FROM steps").parse().unwrap();
    let k_rust: u64 = sql_one(&run, "SELECT sum(CAST(success AS INT)) FROM episodes").parse().unwrap();
    assert_eq!(v[0], steps_rust);
    let episodes = 2 * BASELINE_PER_SUITE as u64;
    assert_eq!((v[1], v[2], v[3]), (episodes, episodes, episodes));
    assert_eq!(v[4], k_rust);
    assert_eq!(v[5], episodes);
    assert!(v[6] >= 3, "object poses per step: {}", v[6]);
}

/// A bundle file damaged after the set-up (here a cut-short scene.xml) stops the run before any
/// episode, naming the file and the command that rebuilds its suite.
#[test]
fn a_damaged_bundle_file_is_refused_before_any_episode() {
    let d = tmp("damaged-bundle");
    let real = libero_e2e::bundles().root().to_path_buf();
    let copy = d.join("bundles");
    std::fs::create_dir_all(copy.join("libero_object")).unwrap();
    std::fs::copy(real.join("index.json"), copy.join("index.json")).unwrap();
    std::os::unix::fs::symlink(real.join("assets").canonicalize().unwrap(), copy.join("assets")).unwrap();
    let task = copy.join("libero_object/00");
    std::fs::create_dir_all(&task).unwrap();
    for f in std::fs::read_dir(real.join("libero_object/00")).unwrap() {
        let f = f.unwrap();
        std::fs::copy(f.path(), task.join(f.file_name())).unwrap();
    }
    let scene = std::fs::read(task.join("scene.xml")).unwrap();
    std::fs::write(task.join("scene.xml"), &scene[..scene.len() / 2]).unwrap();
    let spec = d.join("specs.parquet");
    write_parquet(&spec, spec_columns(&["libero_object"], &[0], &[0], &[7]));
    let run = d.join("run");
    let out = pipeline(&[
        "run",
        spec.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--policy",
        "lift",
        "--bundles",
        copy.to_str().unwrap(),
    ]);
    assert!(!out.status.success(), "a run on a damaged bundle started");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("scene.xml") && err.contains("./setup.sh --suites libero_object"), "{err}");
    assert!(!run.join("episodes").exists(), "episodes were run");
}

/// A part cut short after the run (a full disk, an interrupted copy): queries name it and leave
/// its episode out; the resume sets both parts of that episode aside (nothing deleted) and runs it
/// again, after which the run is whole.
#[test]
fn a_damaged_part_is_named_skipped_by_queries_and_rerun_by_the_resume() {
    let d = tmp("damaged-part");
    let spec = d.join("specs.parquet");
    write_parquet(&spec, spec_columns(&["libero_object"; 3], &[0, 0, 0], &[0, 1, 2], &[7, 7, 7]));
    let run = d.join("run");
    let args = ["run", spec.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", "lift", "--max-steps", "5"];
    ok(pipeline(&args));
    let part = "libero_object-t00-i001-s7.parquet";
    let path = run.join("steps").join(part);
    assert!(path.exists(), "expected part {}", path.display());
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 100]).unwrap();

    let out = pipeline(&["sql", "SELECT count(*) FROM episodes", "--run", run.to_str().unwrap(), "--csv"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains(&format!("steps/{part}")) && err.contains("damaged"), "{err}");
    assert_eq!(String::from_utf8_lossy(&out.stdout).lines().nth(1), Some("2"), "the damaged episode is left out");

    let out = pipeline(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("set aside") && err.contains(part), "{err}");
    assert!(run.join("damaged/steps").join(part).exists() && run.join("damaged/episodes").join(part).exists());
    let rows = sql(&run, "SELECT count(*), count(DISTINCT episode_key) FROM episodes", &[]);
    assert_eq!(rows[0], ["3", "3"]);
    let steps = sql(&run, "SELECT count(*) FROM steps", &[]);
    assert_eq!(steps[0][0], (3 * 15).to_string());
}
