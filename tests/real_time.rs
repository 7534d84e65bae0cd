//! Real-time runs (`pipeline run --latency-ms`, `udfs::real_time`) with policies of known latency:
//! a fixed latency gives the exact pattern of held steps and hold actions its rule says, and the
//! policy's own actions run in order on the steps after; a measured one holds, after each answer's
//! query, as many steps as the answer's stored `policy_ms` spans; ALOHA-sim repeats its last
//! absolute targets; the setting is in the manifest, a resume under another is refused, bad input
//! is refused before anything is written, and `pipeline compare` pairs the run with its
//! closed-loop twin.

use libero_e2e::{ok, pipeline, pipeline_with_env, repo_root, sql_rows, test_dir};
use std::path::{Path, PathBuf};

const STEPS: u32 = 20;

fn lerobot_python() -> PathBuf {
    let py = repo_root().join(".lerobot-venv/bin/python");
    assert!(py.exists(), "no venv at {}: run ./setup.sh --tests", py.display());
    py
}

fn libero_specs(d: &Path) -> PathBuf {
    let specs = d.join("specs.parquet");
    if !specs.exists() {
        let s = specs.to_str().unwrap();
        ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "1", "-o", s]));
    }
    specs
}

/// `pipeline run` of a `python:` fixture policy for `STEPS` policy steps with `extra` options.
fn run_python(d: &Path, name: &str, policy: &str, extra: &[&str]) -> (PathBuf, std::process::Output) {
    let specs = libero_specs(d);
    let run = d.join(name);
    let policy = format!(
        "{policy}{}python={}&batch=1",
        if policy.contains('?') { "&" } else { "?" },
        lerobot_python().display()
    );
    let fixtures = repo_root().join("tests/fixtures/python_policies");
    let steps = STEPS.to_string();
    let mut args = vec!["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", &policy];
    args.extend(["--max-steps", &steps, "--jobs", "1"]);
    args.extend(extra);
    let out = pipeline_with_env(&args, &[("PYTHONPATH", fixtures.to_str().unwrap())]);
    (run, out)
}

/// (held, action) of every policy step, in order.
fn held_and_actions(run: &Path) -> Vec<(bool, Vec<f32>)> {
    sql_rows(
        run,
        "SELECT held, array_to_string(action, ' ') FROM steps WHERE policy_step IS NOT NULL ORDER BY step",
        &[],
    )
    .into_iter()
    .map(|r| (r[0] == "true", r[1].split(' ').map(|v| v.parse().unwrap()).collect()))
    .collect()
}

/// `tests/fixtures/python_policies/chunks.py`'s action k of the chunk it answers at `policy_step`.
fn chunk_action(policy_step: u32, k: u32) -> Vec<f32> {
    (0..7).map(|j| (0.02 * (0.7 * policy_step as f64 + 0.3 * k as f64 + 1.1 * j as f64).sin()) as f32).collect()
}

fn close(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-6)
}

#[test]
fn a_fixed_latency_holds_exactly_the_steps_its_answers_are_late_for() {
    let d = test_dir("real_time", "fixed");
    // chunks of 4 answered after 120 ms at 20 Hz: the query's step and the next hold, the chunk's
    // 4 actions run on the 4 steps after (queued actions cost no time), then the next query
    let (run, out) = run_python(&d, "rt", "python:chunks:make?size=4", &["--latency-ms", "120"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let rows = held_and_actions(&run);
    assert_eq!(rows.len(), STEPS as usize);
    let mut gripper = -1.0; // open before the first answer, as in the wait steps
    for (p, (held, action)) in rows.iter().enumerate() {
        let (query, phase) = (p as u32 / 6 * 6, p as u32 % 6);
        if phase < 2 {
            assert!(held, "policy step {p} must hold: {rows:?}");
            // `stay`, LIBERO's default: no motion, the gripper's last command
            assert_eq!(action, &vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, gripper], "policy step {p}");
        } else {
            assert!(!held, "policy step {p} runs the answer");
            let expected = chunk_action(query, phase - 2);
            assert!(close(action, &expected), "policy step {p}: {action:?} vs the chunk's {expected:?}");
            gripper = action[6];
        }
    }
    // the summary query: 8 held of 20 (steps 0, 1, 6, 7, 12, 13, 18, 19), the first action at 2
    assert!(stdout.contains("is a real-time run: 20 Hz, latency 120 ms per model query, hold stay"), "{stdout}");
    // exported, the held steps stay marked: their actions are the hold, not the policy's
    let dataset = d.join("dataset");
    ok(pipeline(&["export", run.to_str().unwrap(), "--out", dataset.to_str().unwrap(), "--camera-size", "64"]));
    let out = std::process::Command::new(lerobot_python())
        .arg(repo_root().join("scripts/reference/lerobot_dataset_check.py"))
        .args([&dataset, &run])
        .env("HF_HUB_OFFLINE", "1")
        .env("HF_DATASETS_CACHE", d.join("hf-cache"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().last().unwrap()).unwrap();
    assert_eq!(
        (&v["len"], &v["held_frames"], &v["held_mismatches"]),
        (&serde_json::json!(20), &serde_json::json!(8), &serde_json::json!(0)),
        "{v}"
    );
    let row = stdout.lines().find(|l| l.starts_with("| libero_spatial") && l.contains("0.4")).unwrap_or_default();
    let cells: Vec<&str> = row.split('|').map(str::trim).filter(|c| !c.is_empty()).collect();
    assert_eq!(cells, ["libero_spatial", "1", "20", "8", "0.4", "2.0"], "{stdout}");
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["realtime"], serde_json::json!({"latency": {"fixed": {"ms": 120.0}}, "hold": "stay"}));
    let stored = sql_rows(&run, "SELECT realtime LIKE '%\"fixed\":{\"ms\":120.0}%' FROM manifest", &[]);
    assert_eq!(stored, [["true"]], "manifest.parquet's realtime");

    // a resume under another setting is refused, naming it; nothing is added
    for other in [&["--latency-ms", "100"][..], &["--latency-ms", "120", "--hold", "repeat"], &[]] {
        let (_, out) = run_python(&d, "rt", "python:chunks:make?size=4", other);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains("another configuration") && err.contains("realtime: stored"),
            "{other:?}: {err}"
        );
    }
    assert_eq!(held_and_actions(&run).len(), STEPS as usize);

    // a latency of 0: every answer in time, the closed loop's steps with the held column
    let (zero, out) = run_python(&d, "zero", "python:chunks:make?size=4", &["--latency-ms", "0"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    // the closed-loop twin: no held step; compare pairs the two runs' episodes
    let (closed, out) = run_python(&d, "closed", "python:chunks:make?size=4", &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let closed_rows = held_and_actions(&closed);
    assert!(closed_rows.iter().all(|(held, _)| !held));
    assert!(close(&closed_rows[5].1, &chunk_action(4, 1)), "closed loop: step 5 is chunk 4's second action");
    assert_eq!(held_and_actions(&zero), closed_rows, "--latency-ms 0 runs the closed loop's steps");
    let out_dir = d.join("compare");
    let compared =
        ok(pipeline(&["compare", closed.to_str().unwrap(), run.to_str().unwrap(), "--out", out_dir.to_str().unwrap()]));
    assert!(compared.contains("libero_spatial"), "{compared}");
}

#[test]
fn a_measured_latency_holds_as_many_steps_as_each_answer_took() {
    let d = test_dir("real_time", "measured");
    // every query sleeps 110 ms and answers 2 actions: at least 2 held steps before each answer
    let (run, out) = run_python(&d, "rt", "python:slow:make?ms=110&size=2", &["--latency-ms", "measured"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows = sql_rows(
        &run,
        "SELECT held, policy_ms, array_to_string(action, ' ') FROM steps WHERE policy_step IS NOT NULL ORDER BY step",
        &[],
    );
    let mut held_run = 0u32;
    let mut answers = 0;
    for (p, r) in rows.iter().enumerate() {
        let policy_ms: f32 = r[1].parse().unwrap();
        if r[0] == "true" {
            held_run += 1;
            assert_eq!(policy_ms, 0.0, "a held step carries no call's time");
            continue;
        }
        // an answer's step: the steps held just before it are floor(policy_ms / 50 ms), the
        // answer's own measured time; a queued action took (almost) none and held nothing
        let expected = (policy_ms as f64 * 20.0 / 1000.0).floor() as u32;
        assert_eq!(held_run, expected, "policy step {p}: {held_run} held before an answer of {policy_ms} ms: {rows:?}");
        if policy_ms >= 110.0 {
            answers += 1;
            assert!(held_run >= 2, "a 110 ms answer is late for 2 steps at 20 Hz");
        }
        held_run = 0;
    }
    // a loaded machine stretches the sleeps (and the held runs with them): at least two answers
    assert!(answers >= 2, "{rows:?}");
}

#[test]
fn aloha_sim_repeats_its_last_targets_while_an_answer_is_late() {
    let d = test_dir("real_time", "aloha");
    let specs = d.join("specs.parquet");
    ok(pipeline(&["specs", "--benchmark", "aloha_sim", "--trials", "1", "-o", specs.to_str().unwrap()]));
    let s = specs.to_str().unwrap();
    let run = |name: &str, extra: &[&str]| {
        let out = d.join(name);
        let mut args = vec!["run", s, "--out", out.to_str().unwrap(), "--policy", "expert", "--max-steps", "30"];
        args.extend(extra);
        ok(pipeline(&args));
        out
    };
    // the scripted control answers every step; 30 ms at 50 Hz (20 ms a step) is late by one step
    let rt = run("rt", &["--latency-ms", "30"]);
    let closed = run("closed", &[]);
    let rows = |run: &Path| -> Vec<(String, i32, bool, Vec<f32>)> {
        sql_rows(
            run,
            "SELECT episode_key, step, coalesce(held, false), array_to_string(action, ' ') FROM steps ORDER BY episode_key, step",
            &[],
        )
        .into_iter()
        .map(|r| (r[0].clone(), r[1].parse().unwrap(), r[2] == "true", r[3].split(' ').map(|v| v.parse().unwrap()).collect()))
        .collect()
    };
    let (rt_rows, closed_rows) = (rows(&rt), rows(&closed));
    assert_eq!(rt_rows.len(), 60);
    for (i, (key, step, held, action)) in rt_rows.iter().enumerate() {
        assert_eq!(*held, step % 2 == 0, "{key} step {step}");
        if *step == 0 {
            // before the first answer `repeat` holds the joints where the reset put them
            let start = [0.0, -0.96, 1.16, 0.0, -0.3, 0.0];
            assert!(close(&action[..6], &start) && close(&action[7..13], &start), "{key}: {action:?}");
        } else if *held {
            assert_eq!(action, &rt_rows[i - 1].3, "{key} step {step} repeats the last targets");
        } else {
            // the answer to the query of step - 1: the scripted control's targets of that step
            let twin = closed_rows.iter().find(|r| &r.0 == key && r.1 == step - 1).unwrap();
            assert_eq!(action, &twin.3, "{key} step {step}");
        }
    }
    assert!(
        ok(pipeline(&["results", "--run", rt.to_str().unwrap(), "--out", d.join("out").to_str().unwrap()]))
            .contains("latency 30 ms per model query, hold repeat")
    );
}

#[test]
fn bad_real_time_options_are_refused_before_anything_is_written() {
    let d = test_dir("real_time", "bad");
    let specs = libero_specs(&d);
    let out_dir = d.join("never");
    for (extra, needle) in [
        (&["--latency-ms", "-5"][..], "0 or more milliseconds"),
        (&["--latency-ms", "soon"], "neither a number of milliseconds nor `measured`"),
        (&["--hold", "stay"], "add --latency-ms"),
        (&["--latency-ms", "50", "--hold", "freeze"], "use repeat (the last action again) or stay"),
        // vla-eval's server keeps the chunks: a fixed latency cannot tell its queries apart
        (&["--latency-ms", "100", "--policy", "vla-eval:ws://127.0.0.1:9"], "Use --latency-ms measured"),
    ] {
        let policy = if extra.contains(&"--policy") { vec![] } else { vec!["--policy", "random"] };
        let mut args = vec!["run", specs.to_str().unwrap(), "--out", out_dir.to_str().unwrap()];
        args.extend(policy);
        args.extend(extra);
        let out = pipeline(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(needle), "{extra:?}: {err}");
        assert!(!out_dir.exists(), "{extra:?} wrote {}", out_dir.display());
    }
}
