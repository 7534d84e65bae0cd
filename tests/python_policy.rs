//! Python policies through the whole pipeline (`policies::python_host`): a lerobot 0.6.1
//! checkpoint built by lerobot's own classes (a tiny random-weight SmolVLA, `scripts/reference/
//! lerobot_tiny.py`) run by `lerobot:` on the real scene, checked against lerobot's own
//! `select_action` path on the observations the host received; and `python:` policies that crash,
//! hang, raise or answer nonsense, which must cost their episodes and not the run.

use libero_e2e::{ok, pipeline, pipeline_with_env, repo_root, sql_rows, test_dir};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The lerobot venv `./setup.sh --tests` makes.
fn lerobot_python() -> PathBuf {
    let py = repo_root().join(".lerobot-venv/bin/python");
    assert!(py.exists(), "no lerobot venv at {}: run ./setup.sh --tests", py.display());
    py
}

/// `scripts/reference/lerobot_tiny.py ARGS` in the lerobot venv; its stdout.
fn lerobot_tiny(args: &[&str]) -> String {
    let out = Command::new(lerobot_python())
        .arg(repo_root().join("scripts/reference/lerobot_tiny.py"))
        .args(args)
        .output()
        .expect("run lerobot_tiny.py");
    assert!(out.status.success(), "lerobot_tiny.py {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn specs(d: &Path, tasks: &str, trials: &str) -> PathBuf {
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", tasks, "--trials", trials, "-o", s]));
    specs
}

fn sha256_file(path: &Path) -> String {
    let out = Command::new("sha256sum").arg(path).output().unwrap();
    String::from_utf8_lossy(&out.stdout).split_whitespace().next().unwrap().to_string()
}

/// Each episode's stored actions as one sequence of rows of f32 values (episodes sorted by their
/// first action, so two runs' or a run's and a record's sets compare as multisets).
fn sequences(rows: impl IntoIterator<Item = (String, Vec<f32>)>) -> Vec<Vec<Vec<f32>>> {
    let mut by: BTreeMap<String, Vec<Vec<f32>>> = BTreeMap::new();
    for (episode, action) in rows {
        by.entry(episode).or_default().push(action);
    }
    let mut out: Vec<Vec<Vec<f32>>> = by.into_values().collect();
    out.sort_by(|a, b| a.partial_cmp(b).unwrap());
    out
}

#[test]
fn a_lerobot_checkpoint_runs_as_lerobot_eval_feeds_it_and_its_actions_are_lerobots_own() {
    let d = test_dir("python-policy", "lerobot");
    let tiny = lerobot_tiny(&["smolvla", d.join("tiny").to_str().unwrap()]);
    let ckpt = d.join("tiny/ckpt");
    assert!(tiny.contains("\"parameters\""), "{tiny}");
    let specs = specs(&d, "0,1", "2");
    let run = d.join("run");
    let record = d.join("record");
    let py = lerobot_python();
    // 4 episodes on 4 workers sharing calls of up to 4 (waiting up to 2 s for each other: a loaded
    // 2-core box drifts the episodes apart otherwise); 12 policy steps = 3 chunks of 5 executed.
    let policy = format!("lerobot:{}?python={}&batch=4&wait_ms=2000", ckpt.display(), py.display());
    let out = pipeline_with_env(
        &["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", &policy]
            .into_iter()
            .chain(["--max-steps", "12", "--jobs", "4"])
            .collect::<Vec<_>>(),
        &[("LIBERO_EVAL_HOST_RECORD", record.to_str().unwrap())],
    );
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    assert_eq!(
        sql_rows(&run, "SELECT count(*) FROM episodes WHERE error_kind IS NULL AND n_policy_steps = 12", &[]),
        [["4"]],
        "{stderr}"
    );
    let line = stderr.lines().find(|l| l.starts_with("batched policy lerobot:")).unwrap_or_else(|| panic!("{stderr}"));
    let most: usize = line.rsplit("at most ").next().unwrap().split(';').next().unwrap().trim().parse().unwrap();
    assert!(most > 1, "no call held more than one episode: {line}");

    // The manifest: what ran, in which versions, on which files, fed how.
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("manifest.json")).unwrap()).unwrap();
    let id = &manifest["policy_identity"];
    assert_eq!(id["kind"], "lerobot", "{id}");
    assert_eq!(id["policy_type"], "smolvla");
    assert_eq!(id["versions"]["lerobot"], "0.6.1");
    assert_eq!(id["versions"]["torch"], "2.11.0");
    assert_eq!(id["checkpoint_sha256"]["model.safetensors"], sha256_file(&ckpt.join("model.safetensors")));
    assert_eq!(id["executed_steps"], 5);
    assert_eq!(id["chunk_size"], 10);
    assert_eq!(id["observation"]["camera_size"], 360, "lerobot's LIBERO env renders 360 x 360");
    assert_eq!(id["env_preprocessor"], serde_json::json!(["LiberoProcessorStep"]));
    assert!(id["preprocessor"].as_array().unwrap().iter().any(|s| s == "TokenizerProcessorStep"), "{id}");
    assert_eq!(id["numerics"]["cuda_matmul_allow_tf32"], true);
    assert_eq!(id["batch"]["max_episodes_per_forward"], 4);

    // What the host received is lerobot's LIBERO observation: both cameras at 360 x 360, the state.
    let oracle = lerobot_tiny(&["oracle", ckpt.to_str().unwrap(), record.to_str().unwrap()]);
    let oracle: serde_json::Value = serde_json::from_str(oracle.lines().last().unwrap()).unwrap();
    // 4 episodes x 3 calls x the 5 executed actions of each chunk (the last call's 5 cover steps
    // 10-14 of a 12-step episode), each compared with lerobot's select_action on its own (B = 1):
    // the batched forward may round differently from a forward of one, within 1e-5.
    assert_eq!(oracle["actions_compared"], 60, "{oracle}");
    let diff = oracle["max_abs_diff"].as_f64().unwrap();
    assert!(diff <= 1e-5, "the host's batched actions differ from lerobot's select_action by {diff}");
    eprintln!("lerobot: {line}; host vs lerobot's select_action (B = 1) on the same observations: max |diff| {diff:e}");

    // The stored actions are exactly what the host answered.
    let recorded = lerobot_tiny(&["dump", record.to_str().unwrap()]);
    // (the last chunk's actions past the 12-step cap were answered, never executed)
    let recorded = sequences(recorded.lines().filter_map(|l| {
        let mut f = l.split_whitespace();
        let seed = f.next().unwrap().to_string();
        let step: u32 = f.next().unwrap().parse().unwrap();
        (step < 12).then(|| (seed, f.map(|v| v.parse::<f64>().unwrap() as f32).collect()))
    }));
    let stored = sql_rows(
        &run,
        "SELECT episode_key, array_to_string(action, ' ') FROM steps WHERE policy_step IS NOT NULL ORDER BY episode_key, step",
        &[],
    );
    let stored = sequences(
        stored.into_iter().map(|r| (r[0].clone(), r[1].split(' ').map(|v| v.parse::<f32>().unwrap()).collect())),
    );
    assert_eq!(stored.len(), 4);
    assert_eq!(stored, recorded, "the stored actions are not the host's");

    // A checkpoint file that changed since (one byte of config.json) is another identity: the
    // resume is refused before any episode, naming the hashes.
    let config = ckpt.join("config.json");
    let mut text = std::fs::read_to_string(&config).unwrap();
    text.push(' ');
    std::fs::write(&config, text).unwrap();
    let out = pipeline(&["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", &policy]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a resume under a changed checkpoint ran:\n{stderr}");
    assert!(stderr.contains("another configuration") && stderr.contains("checkpoint_sha256"), "{stderr}");

    // Under ensemble=, the host answers whole chunks (the checkpoint's chunk_size 10, not its 5
    // executed) and temporal ensembling asks every step: 3 policy steps are 3 calls.
    std::fs::create_dir_all(d.join("one")).unwrap();
    let one = self::specs(&d.join("one"), "0", "1");
    let (run, record) = (d.join("run-ensembled"), d.join("record-ensembled"));
    let policy = format!("lerobot:{}?python={}&batch=1&ensemble=temporal:0.01", ckpt.display(), py.display());
    let out = pipeline_with_env(
        &["run", one.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", &policy]
            .into_iter()
            .chain(["--max-steps", "3", "--jobs", "1"])
            .collect::<Vec<_>>(),
        &[("LIBERO_EVAL_HOST_RECORD", record.to_str().unwrap())],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert_eq!(sql_rows(&run, "SELECT n_policy_steps, coalesce(error_kind, '-') FROM episodes", &[]), [["3", "-"]]);
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("manifest.json")).unwrap()).unwrap();
    let id = &manifest["policy_identity"];
    assert_eq!((&id["executed_steps"], &id["chunk_size"]), (&serde_json::json!(10), &serde_json::json!(10)), "{id}");
    assert_eq!(id["ensemble"]["rule"], "temporal:0.01");
    assert_eq!(std::fs::read_dir(&record).unwrap().count(), 3, "one call per step");
}

/// `python:misbehaving:make?mode=..&task=between the plate&at=3` on libero_spatial tasks 0 and 1
/// (only task 0's instruction says "between the plate"), one worker, one episode per call: task
/// 0's episode meets the misbehaviour at policy step 3, task 1's runs after it. Returns the run's
/// stderr, its episodes' `task_id, n_policy_steps, error_kind` and the error texts.
fn misbehaving_run(d: &Path, mode: &str, extra: &str) -> (String, Vec<Vec<String>>, String) {
    let specs = specs(d, "0,1", "1");
    let run = d.join(format!("run-{mode}"));
    let policy = format!(
        "python:misbehaving:make?python={}&batch=1&mode={mode}&task=between the plate&at=3{extra}",
        lerobot_python().display()
    );
    let args = ["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", &policy];
    let fixtures = repo_root().join("tests/fixtures/python_policies");
    let out = pipeline_with_env(
        &args.into_iter().chain(["--max-steps", "8", "--jobs", "1"]).collect::<Vec<_>>(),
        &[("PYTHONPATH", fixtures.to_str().unwrap())],
    );
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "a misbehaving policy stopped the run:\n{stderr}");
    let rows =
        sql_rows(&run, "SELECT task_id, n_policy_steps, coalesce(error_kind, '-') FROM episodes ORDER BY task_id", &[]);
    let errors = ok(pipeline(&[
        "sql",
        "SELECT error FROM episodes WHERE error IS NOT NULL",
        "--run",
        run.to_str().unwrap(),
        "--csv",
    ]));
    (stderr, rows, errors)
}

#[test]
fn a_host_that_crashes_hangs_or_answers_nonsense_costs_its_episodes_not_the_run() {
    let d = test_dir("python-policy", "misbehaving");
    // Task 0's episode is an error row at policy step 3; task 1's, in a host started again, runs
    // its 8 steps.
    let cases = [
        ("crash", "", "ended with exit status: 3"),
        ("hang", "&timeout_s=3", "no answer within 3 s"),
        ("malformed", "", "malformed actions: actions of shape (1, 1, 6), expected (1, steps >= 1, 7)"),
        ("raise", "", "ValueError: refusing policy step 3 on purpose"),
    ];
    for (mode, extra, says) in cases {
        let (stderr, rows, errors) = misbehaving_run(&d, mode, extra);
        assert_eq!(rows, [["0", "3", "policy"], ["1", "8", "-"]], "{mode}: {rows:?}\n{errors}\n{stderr}");
        assert!(errors.contains(says), "{mode}: the error row does not say {says:?}:\n{errors}");
        if mode != "raise" {
            assert!(errors.contains("the host is started again"), "{mode}: {errors}");
        }
    }
}

#[test]
fn python_policies_that_cannot_run_are_refused_before_any_episode() {
    let d = test_dir("python-policy", "refused");
    let specs = specs(&d, "0", "1");
    let tiny = d.join("act");
    lerobot_tiny(&["act", tiny.to_str().unwrap()]);
    let act = tiny.join("ckpt");
    let py = lerobot_python();
    let reference_python = repo_root().join(".venv/bin/python");
    // (policy, environment, what the refusal says)
    type Case<'a> = (String, Vec<(&'a str, &'a str)>, String);
    let cases: Vec<Case> = vec![
        // no interpreter named
        (format!("lerobot:{}", act.display()), vec![], "add ?python=/path/to/venv/bin/python to the policy, or set LIBERO_EVAL_PYTHON".into()),
        (format!("lerobot:{}?python=/nonexistent/bin/python", act.display()), vec![], "/nonexistent/bin/python does not exist".into()),
        // an interpreter without lerobot (the reference venv)
        (
            format!("lerobot:{}?python={}", act.display(), reference_python.display()),
            vec![],
            "the interpreter has no lerobot (it lacks the module \"torch\"): install lerobot 0.6.1 there".into(),
        ),
        // ALOHA-sim's ACT on LIBERO: its camera and widths do not fit
        (
            format!("lerobot:{}?python={}", act.display(), py.display()),
            vec![],
            "does not fit libero: it reads the camera observation.images.top, and libero gives ['observation.images.image', 'observation.images.image2']".into(),
        ),
        (format!("lerobot:{}?python={}", d.join("nothing").display(), py.display()), vec![], "has no config.json".into()),
        (format!("lerobot:{}?python={}&stpes=5", act.display(), py.display()), vec![], "unknown option \"stpes=5\"".into()),
    ];
    for (i, (policy, env, says)) in cases.into_iter().enumerate() {
        let run = d.join(format!("run-{i}"));
        let mut env = env;
        env.push(("LIBERO_EVAL_PYTHON", ""));
        let out = pipeline_with_env(
            &["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", &policy],
            &env,
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{policy} ran:\n{stderr}");
        assert!(stderr.contains(&says), "{policy}: the error does not say {says:?}:\n{stderr}");
        assert!(!run.join("episodes").exists(), "{policy}: episodes were written before the refusal");
    }
}
