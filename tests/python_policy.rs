//! Python policies through the whole pipeline (`policies::python_host`): lerobot 0.6.1
//! checkpoints built by lerobot's own classes (tiny random-weight SmolVLA for LIBERO and ACT for
//! ALOHA-sim, `scripts/reference/lerobot_tiny.py`) run by `lerobot:` on the real scenes, checked
//! against lerobot's own `select_action` path on the observations the host received; and
//! `python:` policies that crash, hang, raise or answer nonsense, which must cost their episodes
//! and not the run.

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
    lerobot_tiny_with_env(args, &[])
}

fn lerobot_tiny_with_env(args: &[&str], env: &[(&str, &str)]) -> String {
    let out = Command::new(lerobot_python())
        .arg(repo_root().join("scripts/reference/lerobot_tiny.py"))
        .args(args)
        .envs(env.iter().copied())
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

/// `pipeline run SPECS --policy POLICY --max-steps CAP --jobs JOBS` with the host recording
/// every call into `d/record-NAME`: the run's folder, the record's, the run's stderr and its
/// batcher line (`batched policy ...: N forwards, ..., at most M; ...`), checked that every
/// episode ran its CAP steps without error and that some call held more than one episode.
fn recorded_run(
    d: &Path,
    name: &str,
    specs: &Path,
    policy: &str,
    cap: u32,
    jobs: u32,
    env: &[(&str, &str)],
) -> (PathBuf, PathBuf, String) {
    let (run, record) = (d.join(format!("run-{name}")), d.join(format!("record-{name}")));
    let (cap_text, jobs_text) = (cap.to_string(), jobs.to_string());
    let mut env = env.to_vec();
    env.push(("LIBERO_EVAL_HOST_RECORD", record.to_str().unwrap()));
    let out = pipeline_with_env(
        &[
            "run",
            specs.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--policy",
            policy,
            "--max-steps",
            &cap_text,
            "--jobs",
            &jobs_text,
        ],
        &env,
    );
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    let episodes = sql_rows(&run, "SELECT count(*) FROM episodes", &[]);
    assert_eq!(
        sql_rows(
            &run,
            &format!("SELECT count(*) FROM episodes WHERE error_kind IS NULL AND n_policy_steps = {cap}"),
            &[]
        ),
        episodes,
        "{stderr}"
    );
    let line = stderr.lines().find(|l| l.starts_with("batched policy ")).unwrap_or_else(|| panic!("{stderr}"));
    let most: usize = line.rsplit("at most ").next().unwrap().split(';').next().unwrap().trim().parse().unwrap();
    assert!(most > 1, "no call held more than one episode: {line}");
    (run, record, line.to_string())
}

/// `lerobot_tiny.py oracle`: lerobot's own select_action (B = 1) on every observation the host
/// recorded; the largest difference from the host's actions, checked to cover `compared` actions.
fn lerobot_oracle(ckpt: &Path, record: &Path, tokenizer: Option<&Path>, env: &[(&str, &str)], compared: u64) -> f64 {
    let mut args = vec!["oracle", ckpt.to_str().unwrap(), record.to_str().unwrap()];
    args.extend(tokenizer.map(|t| t.to_str().unwrap()));
    let oracle = lerobot_tiny_with_env(&args, env);
    let oracle: serde_json::Value = serde_json::from_str(oracle.lines().last().unwrap()).unwrap();
    assert_eq!(oracle["actions_compared"], compared, "{oracle}");
    oracle["max_abs_diff"].as_f64().unwrap()
}

/// The run's stored policy actions equal, bit for bit, what the host answered (the record's
/// actions before the cap; a last chunk's actions past it were answered, never executed).
fn assert_stored_actions_are_the_hosts(run: &Path, record: &Path, cap: u32) {
    let recorded = lerobot_tiny(&["dump", record.to_str().unwrap()]);
    let recorded = sequences(recorded.lines().filter_map(|l| {
        let mut f = l.split_whitespace();
        let seed = f.next().unwrap().to_string();
        let step: u32 = f.next().unwrap().parse().unwrap();
        (step < cap).then(|| (seed, f.map(|v| v.parse::<f64>().unwrap() as f32).collect()))
    }));
    let stored = sql_rows(
        run,
        "SELECT episode_key, array_to_string(action, ' ') FROM steps WHERE policy_step IS NOT NULL ORDER BY episode_key, step",
        &[],
    );
    let stored = sequences(
        stored.into_iter().map(|r| (r[0].clone(), r[1].split(' ').map(|v| v.parse::<f32>().unwrap()).collect())),
    );
    assert_eq!(stored.len(), sql_rows(run, "SELECT count(*) FROM episodes", &[])[0][0].parse::<usize>().unwrap());
    assert_eq!(stored, recorded, "the stored actions are not the host's");
}

fn policy_identity(run: &Path) -> serde_json::Value {
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("manifest.json")).unwrap()).unwrap();
    manifest["policy_identity"].clone()
}

#[test]
fn a_lerobot_checkpoint_runs_as_lerobot_eval_feeds_it_and_its_actions_are_lerobots_own() {
    let d = test_dir("python-policy", "lerobot");
    let tiny = lerobot_tiny(&["smolvla", d.join("tiny").to_str().unwrap()]);
    let ckpt = d.join("tiny/ckpt");
    assert!(tiny.contains("\"parameters\""), "{tiny}");
    let specs = specs(&d, "0,1", "2");
    let py = lerobot_python();
    // 4 episodes on 4 workers sharing calls of up to 4 (waiting up to 10 s for each other: a loaded
    // 2-core box drifts the episodes apart otherwise); 12 policy steps = 3 chunks of 5 executed.
    let policy = format!("lerobot:{}?python={}&batch=4&wait_ms=10000", ckpt.display(), py.display());
    let (run, record, line) = recorded_run(&d, "smolvla", &specs, &policy, 12, 4, &[]);

    // The manifest: what ran, in which versions, on which files, fed how.
    let id = policy_identity(&run);
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
    // 4 episodes x 3 calls x the 5 executed actions of each chunk (the last call's 5 cover steps
    // 10-14 of a 12-step episode), each compared with lerobot's select_action on its own (B = 1):
    // the batched forward may round differently from a forward of one, within 1e-5.
    let diff = lerobot_oracle(&ckpt, &record, None, &[], 60);
    assert!(diff <= 1e-5, "the host's batched actions differ from lerobot's select_action by {diff}");
    eprintln!("lerobot: {line}; host vs lerobot's select_action (B = 1) on the same observations: max |diff| {diff:e}");
    assert_stored_actions_are_the_hosts(&run, &record, 12);

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

#[test]
fn a_tiny_pi05_runs_with_its_quantile_state_prompt_and_the_episodes_own_noise() {
    let d = test_dir("python-policy", "pi05");
    // lerobot's PI05 classes at a tiny size (the fixture's sitecustomize), in every process:
    // the builder, the pipeline's host and the oracle
    let tiny_size = repo_root().join("tests/fixtures/python_policies/tiny_pi05");
    let env = [("PYTHONPATH", tiny_size.to_str().unwrap())];
    let built = lerobot_tiny_with_env(&["pi05", d.join("tiny").to_str().unwrap()], &env);
    assert!(built.contains("\"parameters\""), "{built}");
    let (ckpt, tokenizer) = (d.join("tiny/ckpt"), d.join("tiny/tokenizer"));
    let specs = specs(&d, "0", "2");
    // 2 episodes of one task (their workers start together: one task's scene is compiled once)
    // sharing calls; 8 policy steps = 2 chunks of 5 executed; the checkpoint names
    // PaliGemma's gated tokenizer, and tokenizer= gives the local stand-in
    let policy = format!(
        "lerobot:{}?python={}&batch=2&wait_ms=10000&tokenizer={}",
        ckpt.display(),
        lerobot_python().display(),
        tokenizer.display()
    );
    let (run, record, line) = recorded_run(&d, "pi05", &specs, &policy, 8, 2, &env);
    let id = policy_identity(&run);
    assert_eq!(id["policy_type"], "pi05", "{id}");
    let pre: Vec<&str> = id["preprocessor"].as_array().unwrap().iter().map(|s| s.as_str().unwrap()).collect();
    // the state goes into the prompt, quantile-normalised, before the tokenizer
    assert!(
        pre.windows(3)
            .any(|w| w
                == ["NormalizerProcessorStep", "Pi05PrepareStateTokenizerProcessorStep", "TokenizerProcessorStep"]),
        "{pre:?}"
    );
    assert!(id["noise"].as_str().unwrap().contains("seed * 1000003 + policy_step"), "{id}");
    // 2 episodes x 2 calls x 5 executed actions, against PI05Policy's own chunk with the same noise
    let diff = lerobot_oracle(&ckpt, &record, Some(&tokenizer), &env, 20);
    assert!(diff <= 1e-5, "the host's batched π0.5 actions differ from lerobot's by {diff}");
    eprintln!("π0.5: {line}; host vs lerobot's PI05Policy (B = 1) on the same observations: max |diff| {diff:e}");
    assert_stored_actions_are_the_hosts(&run, &record, 8);
}

#[test]
fn lerobots_act_runs_on_aloha_sim_as_lerobot_eval_feeds_it() {
    let d = test_dir("python-policy", "act-aloha");
    lerobot_tiny(&["act", d.join("act").to_str().unwrap()]);
    let ckpt = d.join("act/ckpt");
    let py = lerobot_python();
    let specs = d.join("specs.parquet");
    ok(pipeline(&[
        "specs",
        "--benchmark",
        "aloha_sim",
        "--tasks",
        "0,1",
        "--trials",
        "2",
        "-o",
        specs.to_str().unwrap(),
    ]));
    // 4 episodes (2 tasks x seeds 1000, 1001) on 4 workers sharing calls of up to 4; 15 policy
    // steps = 2 chunks of the checkpoint's 10 executed actions.
    let policy = format!("lerobot:{}?python={}&batch=4&wait_ms=10000", ckpt.display(), py.display());
    let (run, record, line) = recorded_run(&d, "act", &specs, &policy, 15, 4, &[]);
    let id = policy_identity(&run);
    assert_eq!(
        (&id["policy_type"], &id["benchmark"]),
        (&serde_json::json!("act"), &serde_json::json!("aloha_sim")),
        "{id}"
    );
    assert_eq!(id["observation"]["cameras"], serde_json::json!(["top"]));
    assert_eq!((&id["executed_steps"], &id["chunk_size"]), (&serde_json::json!(10), &serde_json::json!(10)));

    // What the host received is gym-aloha's observation (top 480 x 640 upright, agent_pos, the
    // task's gym-aloha name), and lerobot's select_action (B = 1) on it gives the host's actions:
    // 4 episodes x 2 calls x 10 actions.
    let diff = lerobot_oracle(&ckpt, &record, None, &[], 80);
    assert!(diff <= 1e-5, "the host's batched ACT actions differ from lerobot's select_action by {diff}");
    eprintln!("ACT on ALOHA-sim: {line}; host vs lerobot's select_action (B = 1): max |diff| {diff:e}");
    let first_call = std::fs::read_dir(&record).unwrap().next().unwrap().unwrap().path();
    let shapes = Command::new(&py)
        .args(["-c", "import sys, json, numpy as np; r = np.load(sys.argv[1]); print(json.dumps([list(r['top'].shape), list(r['agent_pos'].shape), json.loads(str(r['task_json']))]))"])
        .arg(&first_call)
        .output()
        .unwrap();
    let shapes: serde_json::Value = serde_json::from_slice(&shapes.stdout).unwrap();
    assert_eq!(shapes[0].as_array().unwrap()[1..], [480, 640, 3], "{shapes}");
    assert_eq!(shapes[1].as_array().unwrap()[1], 14, "{shapes}");
    assert!(shapes[2].as_array().unwrap().iter().all(|t| t == "transfer_cube" || t == "insertion"), "{shapes}");
    assert_stored_actions_are_the_hosts(&run, &record, 15);

    // The same checkpoint does not fit LIBERO (its camera, state and action): refused before any
    // episode, naming the mismatch.
    let libero = d.join("libero-specs.parquet");
    ok(pipeline(&[
        "specs",
        "--suites",
        "libero_spatial",
        "--tasks",
        "0",
        "--trials",
        "1",
        "-o",
        libero.to_str().unwrap(),
    ]));
    let refused = d.join("run-libero");
    let out = pipeline(&["run", libero.to_str().unwrap(), "--out", refused.to_str().unwrap(), "--policy", &policy]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "ACT for ALOHA-sim ran on LIBERO:\n{stderr}");
    let says = "does not fit libero: it reads the camera observation.images.top, and libero gives ['observation.images.image', 'observation.images.image2']";
    assert!(stderr.contains(says), "{stderr}");
    assert!(!refused.join("episodes").exists(), "episodes were written before the refusal");
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
    // (the interpreter is refused before the checkpoint is read: any directory stands for one;
    // a checkpoint that does not fit is refused in lerobots_act_runs_on_aloha_sim_...)
    let act = d.join("ckpt");
    std::fs::create_dir_all(&act).unwrap();
    let py = lerobot_python();
    let reference_python = repo_root().join(".venv/bin/python");
    // (policy, environment, what the refusal says)
    type Case<'a> = (String, Vec<(&'a str, &'a str)>, String);
    let cases: Vec<Case> = vec![
        // no interpreter named
        (
            format!("lerobot:{}", act.display()),
            vec![],
            "add ?python=/path/to/venv/bin/python to the policy, or set LIBERO_EVAL_PYTHON".into(),
        ),
        (
            format!("lerobot:{}?python=/nonexistent/bin/python", act.display()),
            vec![],
            "/nonexistent/bin/python does not exist".into(),
        ),
        // an interpreter without lerobot (the reference venv)
        (
            format!("lerobot:{}?python={}", act.display(), reference_python.display()),
            vec![],
            "the interpreter has no lerobot (it lacks the module \"torch\"): install lerobot 0.6.1 there".into(),
        ),
        (
            format!("lerobot:{}?python={}", d.join("nothing").display(), py.display()),
            vec![],
            "has no config.json".into(),
        ),
        (
            format!("lerobot:{}?python={}&stpes=5", act.display(), py.display()),
            vec![],
            "unknown option \"stpes=5\"".into(),
        ),
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
