//! ALOHA-sim through the same dataflow as LIBERO: `pipeline specs --benchmark aloha_sim` (lerobot's
//! seeds 1000 + i), `pipeline run` on the real gym-aloha scene (`data/aloha`), the episode rows
//! and the scores of the same queries, ALOHA's own steps table (14-D actions, `agent_pos`, the
//! 0–4 reward), re-scoring from the compact evidence equal to re-scoring from the steps, failure
//! modes from the reward stages, resume, and the bad inputs refused before any episode.
//!
//! Kept small for CI (2 episodes per task); the positive control's rate over lerobot's 50 seeds
//! per task is `sim/tests/aloha.rs`'s.

use arrow::array::{ArrayRef, Int32Array, Int64Array, RecordBatch, StringArray};
use arrow::datatypes::{Field, Schema};
use libero_e2e::{ok, pipeline, test_dir};
use std::path::{Path, PathBuf};
use std::sync::Arc;

fn tmp(name: &str) -> PathBuf {
    test_dir("aloha_run", name)
}

fn sql(run: &Path, query: &str) -> Vec<Vec<String>> {
    libero_e2e::sql_rows(run, query, &[])
}

fn aloha_specs(dir: &Path, trials: &str) -> PathBuf {
    let specs = dir.join("specs.parquet");
    ok(pipeline(&["specs", "--benchmark", "aloha_sim", "--trials", trials, "-o", specs.to_str().unwrap()]));
    specs
}

fn write_specs(path: &Path, columns: Vec<(&str, ArrayRef)>) {
    let schema =
        Schema::new(columns.iter().map(|(n, a)| Field::new(*n, a.data_type().clone(), true)).collect::<Vec<_>>());
    let batch = RecordBatch::try_new(Arc::new(schema), columns.into_iter().map(|(_, a)| a).collect()).unwrap();
    std::fs::write(path, libero_udfs::run_store::parquet_bytes(&batch, None).unwrap()).unwrap();
}

fn spec_columns(suite: &[&str], task: &[i32], seed: &[i64]) -> Vec<(&'static str, ArrayRef)> {
    vec![
        ("suite", Arc::new(StringArray::from(suite.to_vec())) as ArrayRef),
        ("task_id", Arc::new(Int32Array::from(task.to_vec()))),
        ("init_state_id", Arc::new(Int32Array::from((0..task.len() as i32).collect::<Vec<_>>()))),
        ("seed", Arc::new(Int64Array::from(seed.to_vec()))),
    ]
}

/// The scripted control solves every episode and the random baseline none, through `pipeline
/// run`; the episode rows say `aloha_sim` and the protocol; the steps are ALOHA's; `results`
/// scores them with Wilson intervals; a second run on the same `--out` runs nothing.
#[test]
fn aloha_sim_episodes_run_through_the_pipeline_and_score_like_libero() {
    let dir = tmp("control");
    let specs = aloha_specs(&dir, "2");
    let run = dir.join("expert");
    let (s, r) = (specs.to_str().unwrap(), run.to_str().unwrap());
    let out = ok(pipeline(&["run", s, "--out", r, "--policy", "expert"]));
    eprintln!("{out}");

    let episodes = sql(
        &run,
        "SELECT task_id, seed, env, success, first_success_step, n_policy_steps, max_steps, num_steps_wait, instruction, error_kind \
         FROM episodes ORDER BY task_id, seed",
    );
    assert_eq!(episodes.len(), 4, "{episodes:?}");
    for (e, (task, seed)) in episodes.iter().zip([(0, 1000), (0, 1001), (1, 1000), (1, 1001)]) {
        assert_eq!((e[0].as_str(), e[1].as_str()), (task.to_string().as_str(), seed.to_string().as_str()));
        assert_eq!(&e[2..4], ["aloha_sim", "true"], "{e:?}");
        // run to the cap (lerobot's 400), no wait steps; the scripted transfer succeeds at
        // ~202-212, the insertion at ~332-334 (sim/tests/aloha.rs over 50 seeds)
        let first: u32 = e[4].parse().unwrap();
        let window = if task == 0 { 195..=220 } else { 325..=340 };
        assert!(window.contains(&first), "first success {first}: {e:?}");
        assert_eq!(&e[5..8], ["400", "400", "0"], "{e:?}");
        assert_eq!(e[9], "", "{e:?}");
    }
    assert_eq!(episodes[0][8], "Transfer cube");

    // ALOHA's steps: 14-D actions, agent_pos, the reward, goal = reward 4, no wait steps
    let steps = sql(
        &run,
        "SELECT count(*), min(array_length(action, 1)), max(array_length(agent_pos, 1)), \
                sum(CAST(is_wait AS INT)), sum(CAST(goal <> (reward = 4) AS INT)), max(reward), min(step), max(step) \
         FROM steps",
    );
    assert_eq!(steps[0], ["1600", "14", "14", "0", "0", "4", "0", "399"], "{steps:?}");
    // the reward climbs through the stages of a transfer: the right gripper touches the cube
    // (1), lifts it (2), the left one holds it off the table (4; 3, the left touching while the
    // cube is on the table, is skipped by a handover in the air)
    let levels =
        sql(&run, "SELECT count(DISTINCT reward) FROM steps WHERE task_id = 0 AND seed = 1000 AND reward IN (1, 2, 4)");
    assert_eq!(levels[0][0], "3", "{levels:?}");

    // the same results query as LIBERO's: 4/4 with a Wilson interval
    let results = dir.join("results");
    let text = ok(pipeline(&["results", "--run", r, "--out", results.to_str().unwrap()]));
    let csv = std::fs::read_to_string(results.join("results.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let row: Vec<&str> = csv
        .lines()
        .find(|l| l.starts_with("aloha_sim,"))
        .unwrap_or_else(|| panic!("{csv}\n{text}"))
        .split(',')
        .collect();
    let col = |name: &str| row[header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name}: {csv}"))];
    assert_eq!((col("n_total"), col("n_success"), col("n_error")), ("4", "4", "0"), "{csv}");
    assert_eq!(col("success_rate").parse::<f64>().unwrap(), 1.0, "{csv}");
    let (lo, hi): (f64, f64) = (col("ci_lo").parse().unwrap(), col("ci_hi").parse().unwrap());
    // Wilson 95% of 4/4: [0.510, 1]
    assert!((lo - 0.5101).abs() < 1e-3 && hi == 1.0, "{lo} {hi}");

    // resume: nothing left to run
    let again = pipeline(&["run", s, "--out", r, "--policy", "expert"]);
    let stderr = String::from_utf8_lossy(&again.stderr).to_string();
    assert!(again.status.success() && stderr.contains("(4 already finished, 0 to run)"), "{stderr}");

    // re-scoring from the episodes' compact evidence equals re-scoring from the step rows, under
    // both success definitions and a shorter cap
    libero_e2e::assert_goal_evidence_matches_steps(&run, 300);

    // failure modes from the reward stages: at gym-aloha's 300-step cap the scripted insertion
    // (first success at ~332) fails with the peg lifted but not in, the transfer (~205) succeeds
    let modes = failure_modes(&run, &dir.join("failures-300"), &["--cap", "300"]);
    assert_eq!(modes.len(), 2, "{modes:?}");
    for (task, mode, max_reward) in &modes {
        assert_eq!(task, "1", "{modes:?}");
        assert!(
            ["not_aligned", "not_inserted"].contains(&mode.as_str()) && ["2", "3"].contains(&max_reward.as_str()),
            "{modes:?}"
        );
    }

    // the random baseline solves nothing, and its failures are early stages
    let random = dir.join("random");
    ok(pipeline(&["run", s, "--out", random.to_str().unwrap(), "--policy", "random"]));
    let rows = sql(&random, "SELECT sum(CAST(success AS INT)), count(*), count(error_kind) FROM episodes");
    assert_eq!(rows[0], ["0", "4", "0"], "{rows:?}");
    let modes = failure_modes(&random, &dir.join("failures-random"), &[]);
    assert_eq!(modes.len(), 4, "{modes:?}");
    for (task, mode, _) in &modes {
        let early: &[&str] =
            if task == "0" { &["never_touched", "not_lifted"] } else { &["not_grasped", "not_lifted"] };
        assert!(early.contains(&mode.as_str()), "{modes:?}");
    }
}

/// Per step of one episode (ordered): the action, `agent_pos` after the step, and the render time.
fn actions_and_state(run: &Path, task: u32) -> Vec<(Vec<f64>, Vec<f64>, f64)> {
    let parse = |s: &str| -> Vec<f64> { s.split(';').map(|x| x.parse().unwrap()).collect() };
    let query = format!(
        "SELECT array_to_string(action, ';'), array_to_string(agent_pos, ';'), render_ms FROM steps WHERE task_id = {task} ORDER BY step"
    );
    sql(run, &query).iter().map(|r| (parse(&r[0]), parse(&r[1]), r[2].parse().unwrap())).collect()
}

/// openpi's ALOHA-sim example through `pipeline run --policy openpi:ws://...` against the toy
/// openpi server in its ALOHA mode, which refuses any request but `{"state": f64 (14,),
/// "images": {"cam_high": u8 (3, 224, 224)}}` with the black bars of a padded 480 × 640 frame:
/// the `top` camera is rendered only when a chunk is due, the state sent is the `agent_pos`
/// observed before the step, and 10 of each 50-action chunk are executed.
#[test]
fn an_openpi_served_policy_runs_on_aloha_sim_as_openpis_example_runs_it() {
    let server = crate::remote_policy::ToyServer::start(&["--aloha", "--chunk", "50"]);
    let dir = tmp("openpi");
    let specs = aloha_specs(&dir, "1");
    let run = dir.join("run");
    let policy = format!("openpi:{}", server.url);
    let (s, r) = (specs.to_str().unwrap(), run.to_str().unwrap());
    ok(pipeline(&["run", s, "--out", r, "--policy", &policy, "--max-steps", "25", "--jobs", "1"]));
    let e = sql(&run, "SELECT task_id, n_policy_steps, COALESCE(error, 'none') FROM episodes ORDER BY task_id");
    assert_eq!(e, [["0", "25", "none"], ["1", "25", "none"]], "the server refuses anything but the example's dict");
    // (CSV doubles the JSON's quotes)
    let identity = sql(&run, "SELECT policy_identity FROM manifest").concat().join(",").replace("\"\"", "\"");
    for needle in ["cam_high", "\"executed\":10", "\"predicted\":50", "aloha_sim"] {
        assert!(identity.contains(needle), "{needle} not in {identity}");
    }
    for task in [0, 1] {
        let steps = actions_and_state(&run, task);
        assert_eq!(steps.len(), 25);
        for (t, (action, _, render_ms)) in steps.iter().enumerate() {
            // the top camera is rendered for a query only: steps 0, 10, 20
            assert_eq!(*render_ms > 0.0, t % 10 == 0, "step {t}: render_ms {render_ms}");
            if t % 10 != 0 {
                // within a chunk the toy's actions step by 0.01 in every joint
                let prev = &steps[t - 1].0;
                assert!(
                    action.iter().zip(prev).all(|(a, p)| (a - p - 0.01).abs() < 1e-5),
                    "step {t}: {action:?} {prev:?}"
                );
            } else if t > 0 {
                // a new chunk starts from the agent_pos after the previous step: the same offset
                // (0.01 plus the image's centre pixel term) in all 14 components
                let state = &steps[t - 1].1;
                let d: Vec<f64> = action.iter().zip(state).map(|(a, s)| a - s).collect();
                assert!(d.iter().all(|x| (x - d[0]).abs() < 1e-5), "step {t}: {d:?}");
                assert!((0.01 - 1e-5..=0.01 + 3.0 * 255.0 / 1e5 + 1e-5).contains(&d[0]), "step {t}: {d:?}");
            }
        }
    }
}

/// A TorchScript module made for ALOHA-sim (`model.json` says `"benchmark": "aloha_sim"`), traced
/// with libtorch, through `pipeline run`: it sees the 480 × 640 `top` frame and the 14-D state and
/// returns 14-D chunks; a LIBERO module is refused on ALOHA specs, and this one on LIBERO specs.
#[test]
fn a_torchscript_module_for_aloha_sim_runs_and_each_benchmark_refuses_the_others_module() {
    use tch::{CModule, Device, Kind, Tensor};
    let dir = tmp("torchscript");
    let file = dir.join("aloha.pt");
    let inputs =
        [Tensor::rand([1, 3, 480, 640], (Kind::Float, Device::Cpu)), Tensor::rand([1, 14], (Kind::Float, Device::Cpu))];
    // hold the observed joints, + 0.1 × the image's mean (in every joint) + 0.001 per chunk position
    CModule::create_by_tracing("ToyAloha", "forward", &inputs, &mut |x| {
        let mean = x[0].mean_dim([1i64, 2, 3].as_slice(), true, Kind::Float).reshape([1, 1, 1]);
        let steps = Tensor::arange(4, (Kind::Float, Device::Cpu)).reshape([1, 4, 1]) * 0.001;
        vec![x[1].unsqueeze(1) + mean * 0.1 + steps]
    })
    .unwrap()
    .save(&file)
    .unwrap();
    std::fs::write(
        dir.join("aloha.json"),
        r#"{"benchmark": "aloha_sim", "inputs": ["top", "state"], "preprocessing": "none", "chunk_size": 4, "replan_steps": 3}"#,
    )
    .unwrap();
    let specs = aloha_specs(&dir, "1");
    let run = dir.join("run");
    let policy = format!("torchscript:{}", file.display());
    let (s, r) = (specs.to_str().unwrap(), run.to_str().unwrap());
    ok(pipeline(&["run", s, "--out", r, "--policy", &policy, "--max-steps", "9"]));
    let e = sql(&run, "SELECT n_policy_steps, COALESCE(error, 'none') FROM episodes ORDER BY task_id");
    assert_eq!(e, [["9", "none"], ["9", "none"]]);
    let identity = sql(&run, "SELECT policy_identity FROM manifest").concat().join(",");
    assert!(identity.contains("aloha_sim") && identity.contains("480x640"), "{identity}");
    let steps = actions_and_state(&run, 0);
    for (t, (action, _, render_ms)) in steps.iter().enumerate() {
        assert_eq!(*render_ms > 0.0, t % 3 == 0, "step {t}: render_ms {render_ms}");
        if t % 3 != 0 {
            assert!(action.iter().zip(&steps[t - 1].0).all(|(a, p)| (a - p - 0.001).abs() < 1e-5), "step {t}");
        } else if t > 0 {
            // from the state before the step, + 0.1 × a rendered frame's mean (a real picture:
            // neither black nor white)
            let d: Vec<f64> = action.iter().zip(&steps[t - 1].1).map(|(a, s)| a - s).collect();
            assert!(d.iter().all(|x| (x - d[0]).abs() < 1e-5), "step {t}: {d:?}");
            assert!((0.005..0.095).contains(&d[0]), "step {t}: the image term {d:?}");
        }
    }

    // each benchmark refuses the other's module before any episode
    let refused = |specs: &Path, policy: &str, needle: &str| {
        let out_dir = dir.join(format!("refused-{}", needle.len()));
        let out = pipeline(&["run", specs.to_str().unwrap(), "--out", out_dir.to_str().unwrap(), "--policy", policy]);
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(!out.status.success() && stderr.contains(needle), "{stderr}");
        assert!(!out_dir.join("episodes").exists());
    };
    std::fs::create_dir_all(dir.join("libero")).unwrap();
    let libero_specs = libero_e2e::spatial_task0_specs(&dir.join("libero"), "1");
    refused(&libero_specs, &policy, "\"benchmark\": \"aloha_sim\"");
    let libero_module = dir.join("libero.pt");
    std::fs::copy(&file, &libero_module).unwrap();
    std::fs::write(
        dir.join("libero.json"),
        r#"{"inputs": ["agentview", "state"], "image_size": 32, "preprocessing": "rot180"}"#,
    )
    .unwrap();
    refused(&specs, &format!("torchscript:{}", libero_module.display()), "LIBERO module");
    refused(&specs, &format!("{policy}?batch=2"), "?batch= shares forwards between LIBERO episodes only");
}

/// `pipeline failures` on a run: (task_id, failure_mode, max_reward) per failed episode.
fn failure_modes(run: &Path, out: &Path, extra: &[&str]) -> Vec<(String, String, String)> {
    let mut args = vec!["failures", "--run", run.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    ok(pipeline(&args));
    let csv = std::fs::read_to_string(out.join("failure_modes.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let at = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name}: {csv}"));
    let (task, mode, reward) = (at("task_id"), at("failure_mode"), at("max_reward"));
    csv.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[task].to_string(), f[mode].to_string(), f[reward].to_string())
        })
        .collect()
}

/// A NaN action is an error row and the run goes on; the manifest records the benchmark and
/// ALOHA's control rate; the gym cap (300) is expressible and recorded.
#[test]
fn aloha_error_rows_and_the_gym_cap() {
    let dir = tmp("errors");
    let specs = aloha_specs(&dir, "1");
    let run = dir.join("run");
    let r = run.to_str().unwrap();
    ok(pipeline(&["run", specs.to_str().unwrap(), "--out", r, "--policy", "nan-at:5", "--max-steps", "300"]));
    let rows = sql(&run, "SELECT task_id, error_kind, n_policy_steps, max_steps FROM episodes ORDER BY task_id");
    assert_eq!(rows, [["0", "invalid_action", "5", "300"], ["1", "invalid_action", "5", "300"]]);
    let modes = failure_modes(&run, &dir.join("failures"), &[]);
    assert!(modes.len() == 2 && modes.iter().all(|(_, m, _)| m == "error"), "{modes:?}");
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["env"], "aloha_sim");
    assert_eq!(manifest["control_freq_hz"], 50);
    assert_eq!(manifest["substeps_per_step"], 10);
    assert_eq!(manifest["max_steps"]["aloha_sim"], 300);
}

/// Bad input fails before any episode, naming the problem and the fix: a LIBERO policy (7-D
/// actions) on ALOHA-sim, an unknown ALOHA task, a seed numpy cannot take, a LIBERO perturbation
/// column on ALOHA rows, LIBERO and ALOHA rows in one table.
#[test]
fn bad_aloha_specs_and_policies_fail_before_any_episode() {
    let dir = tmp("bad");
    let specs = aloha_specs(&dir, "1");
    let refused = |specs: &Path, policy: &str, needles: &[&str]| {
        let run = dir.join(format!("run-{}", specs.file_stem().unwrap().to_string_lossy()));
        let out = pipeline(&["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", policy]);
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(!out.status.success(), "accepted: {stderr}");
        for n in needles {
            assert!(stderr.contains(n), "{n:?} not in: {stderr}");
        }
        assert!(!run.join("episodes").exists(), "an episode ran: {stderr}");
    };
    refused(&specs, "lift", &["7-D", "14-D", "expert"]);

    let bad_task = dir.join("bad_task.parquet");
    write_specs(&bad_task, spec_columns(&["aloha_sim", "aloha_sim"], &[0, 2], &[1000, 1001]));
    refused(&bad_task, "expert", &["row 1", "no task_id 2", "0 transfer_cube and 1 insertion"]);

    let bad_seed = dir.join("bad_seed.parquet");
    write_specs(&bad_seed, spec_columns(&["aloha_sim"], &[0], &[1 << 33]));
    refused(&bad_seed, "expert", &["row 0", "4294967295"]);

    let libero_column = dir.join("libero_column.parquet");
    let mut columns = spec_columns(&["aloha_sim"], &[0], &[1000]);
    columns.push(("camera_pos", Arc::new(StringArray::from(vec!["[0, 0, 1]"])) as ArrayRef));
    write_specs(&libero_column, columns);
    refused(&libero_column, "expert", &["camera_pos", "LIBERO perturbation", "drop them"]);

    let mixed = dir.join("mixed.parquet");
    write_specs(&mixed, spec_columns(&["libero_spatial", "aloha_sim"], &[0, 0], &[7, 1000]));
    refused(&mixed, "expert", &["mixes benchmarks", "row 0 is libero", "row 1 is aloha_sim"]);
}
