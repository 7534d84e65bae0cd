//! `pipeline export --format lerobot` (`pipeline/src/export.rs`, `lerobot_dataset.rs`), read back by
//! lerobot 0.6.1's own `LeRobotDataset` (`scripts/reference/lerobot_dataset_check.py`, offline):
//! LIBERO frames equal, pixel for pixel (lossless video), to what a `python:` policy saw (its
//! host's record), rotated as lerobot's LIBERO processor rotates them; states to lerobot's own
//! state of those observations; actions to what the policy answered and the run stored. ALOHA-sim
//! frames carry the stored joints, actions and rewards. Bad input writes nothing.

use libero_e2e::{ok, pipeline, pipeline_with_env, repo_root, test_dir};
use std::path::{Path, PathBuf};
use std::process::Command;

fn lerobot_python() -> PathBuf {
    let py = repo_root().join(".lerobot-venv/bin/python");
    assert!(py.exists(), "no venv at {}: run ./setup.sh --tests", py.display());
    py
}

/// lerobot's reading of `dataset` against `run` (and the host's `record`), as JSON.
fn check(dataset: &Path, run: &Path, record: Option<&Path>, scratch: &Path) -> serde_json::Value {
    check_with(dataset, run, record, scratch, "pyav")
}

/// [`check`] with lerobot's `video_backend` (pyav: PyAV's own FFmpeg; torchcodec: the system's).
fn check_with(dataset: &Path, run: &Path, record: Option<&Path>, scratch: &Path, backend: &str) -> serde_json::Value {
    let mut cmd = Command::new(lerobot_python());
    cmd.env("VIDEO_BACKEND", backend);
    cmd.arg(repo_root().join("scripts/reference/lerobot_dataset_check.py")).arg(dataset).arg(run);
    if let Some(r) = record {
        cmd.arg(r);
    }
    // lerobot's Arrow cache of the frames, kept out of the user's ~/.cache
    let out = cmd.env("HF_HUB_OFFLINE", "1").env("HF_DATASETS_CACHE", scratch.join("hf-cache")).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().last().unwrap()).unwrap()
}

#[test]
fn libero_failures_export_as_a_dataset_lerobot_reads_back_as_the_policy_saw_them() {
    let d = test_dir("export", "libero");
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0,1", "--trials", "1", "-o", s]));
    let run = d.join("run");
    let record = d.join("record");
    let policy = format!("python:sees:make?python={}&batch=1&size=64", lerobot_python().display());
    let fixtures = repo_root().join("tests/fixtures/python_policies");
    let out = pipeline_with_env(
        &["run", s, "--out", run.to_str().unwrap(), "--policy", &policy, "--max-steps", "8", "--jobs", "1"],
        &[("PYTHONPATH", fixtures.to_str().unwrap()), ("LIBERO_EVAL_HOST_RECORD", record.to_str().unwrap())],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    // lossless: every frame as the policy saw it
    let exact = d.join("exact");
    let (r, x) = (run.to_str().unwrap(), exact.to_str().unwrap());
    let printed = ok(pipeline(&["export", r, "--out", x, "--video", "lossless", "--camera-size", "64"]));
    assert!(printed.contains("2 episodes, 16 frames at 20 fps"), "{printed}");
    let v = check(&exact, &run, Some(&record), &d);
    assert_eq!((v["len"].as_u64(), v["fps"].as_u64(), v["episodes"].as_u64()), (Some(16), Some(20), Some(2)), "{v}");
    assert_eq!(v["frames"], serde_json::json!([8, 8]), "{v}");
    assert_eq!(v["done"], 2, "one last frame per episode: {v}");
    assert_eq!(v["max_image_diff"], 0, "frames equal to what the policy saw: {v}");
    let torchcodec = check_with(&exact, &run, Some(&record), &d, "torchcodec");
    assert_eq!(
        (torchcodec["len"].as_u64(), &torchcodec["max_image_diff"]),
        (Some(16), &serde_json::json!(0)),
        "{torchcodec}"
    );
    assert_eq!(v["max_action_diff"].as_f64(), Some(0.0), "actions equal to the stored ones: {v}");
    assert_eq!(v["max_policy_action_diff"].as_f64(), Some(0.0), "and to what the policy answered: {v}");
    assert_eq!(v["success_mismatches"], 0, "{v}");
    // eef position and fingers are exact; lerobot computes the axis-angle in float32
    assert!(v["max_state_diff"].as_f64().unwrap() < 1e-5, "{v}");
    assert_eq!(v["image_shapes"]["observation.images.image"], serde_json::json!([3, 64, 64]), "{v}");
    for key in ["observation.state", "action", "observation.images.image", "observation.images.image2"] {
        assert!(v["stats_keys"].as_array().unwrap().iter().any(|k| k == key), "stats.json lacks {key}: {v}");
    }
    let tasks: Vec<&str> = v["tasks"].as_array().unwrap().iter().map(|t| t.as_str().unwrap()).collect();
    assert!(tasks.iter().all(|t| t.starts_with("pick up the black bowl")), "task strings, not indices: {tasks:?}");
    let provenance: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(exact.join("meta/libero_eval.json")).unwrap()).unwrap();
    assert_eq!(provenance["episodes"][0]["episode_key"], "libero_spatial/0/0/7");

    // --cap 5: the episodes as that scoring sees them, 5 frames each, the fifth the last
    let capped = d.join("capped");
    let c = capped.to_str().unwrap();
    ok(pipeline(&["export", r, "--out", c, "--video", "lossless", "--camera-size", "64", "--cap", "5"]));
    let v = check(&capped, &run, Some(&record), &d);
    assert_eq!(
        (&v["frames"], &v["done"], &v["max_image_diff"]),
        (&serde_json::json!([5, 5]), &serde_json::json!(2), &serde_json::json!(0)),
        "{v}"
    );

    // the default H.264: a predicate picks one episode; pixels within the codec's error
    let lossy = d.join("lossy");
    ok(pipeline(&["export", r, "--out", lossy.to_str().unwrap(), "--camera-size", "64", "--where", "task_id = 1"]));
    let v = check(&lossy, &run, Some(&record), &d);
    assert_eq!((v["len"].as_u64(), v["episodes"].as_u64()), (Some(8), Some(1)), "{v}");
    assert!(v["max_image_diff"].as_i64().unwrap() < 64, "{v}");

    // bad input: nothing matches, the folder exists, the predicate is not SQL; nothing is written
    let never = d.join("never");
    for (args, needle) in [
        (vec!["--where", "task_id = 9"], "matches no episode"),
        (vec!["--where", "no_such_column = 1"], "is not a predicate over the scored view"),
    ] {
        let mut all = vec!["export", r, "--out", never.to_str().unwrap()];
        all.extend(args);
        let out = pipeline(&all);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(needle), "{err}");
        assert!(!never.exists());
    }
    let out = pipeline(&["export", r, "--out", x]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("already exists"));
    let leftovers: Vec<_> = std::fs::read_dir(&d)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .filter(|n| n.contains(".partial-"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn an_aloha_sim_run_exports_its_joints_actions_and_rewards() {
    let d = test_dir("export", "aloha");
    let specs = d.join("specs.parquet");
    ok(pipeline(&["specs", "--benchmark", "aloha_sim", "--trials", "1", "-o", specs.to_str().unwrap()]));
    let run = d.join("run");
    let r = run.to_str().unwrap();
    ok(pipeline(&["run", specs.to_str().unwrap(), "--out", r, "--policy", "expert", "--max-steps", "20"]));
    let dataset = d.join("dataset");
    // the scripted control cannot finish in 20 steps: both episodes are failures
    ok(pipeline(&["export", r, "--out", dataset.to_str().unwrap()]));
    let v = check(&dataset, &run, None, &d);
    assert_eq!((v["len"].as_u64(), v["fps"].as_u64(), v["episodes"].as_u64()), (Some(40), Some(50), Some(2)), "{v}");
    assert_eq!(v["image_shapes"]["observation.images.top"], serde_json::json!([3, 480, 640]), "{v}");
    assert_eq!(v["max_action_diff"].as_f64(), Some(0.0), "{v}");
    assert_eq!(v["max_state_diff"].as_f64(), Some(0.0), "agent_pos before each step: {v}");
    assert_eq!(v["max_reward_diff"].as_f64(), Some(0.0), "{v}");
    assert_eq!(v["tasks"].as_array().unwrap().len(), 2, "{v}");
}

#[test]
fn an_episode_that_cannot_be_replayed_stops_the_export_and_writes_nothing() {
    let d = test_dir("export", "unreplayable");
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "2", "-o", s]));
    let run = |name: &str, policy: &str| {
        let out = d.join(name);
        ok(pipeline(&["run", s, "--out", out.to_str().unwrap(), "--policy", policy, "--max-steps", "6"]));
        out
    };
    let never = d.join("never");
    let refused = |run: &Path, extra: &[&str], needle: &str| {
        let mut args = vec!["export", run.to_str().unwrap(), "--out", never.to_str().unwrap(), "--camera-size", "64"];
        args.extend(extra);
        let out = pipeline(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(needle), "{extra:?}: {err}");
        assert!(!never.exists(), "{extra:?} wrote {}", never.display());
    };
    // NaN at the first policy step: every episode is an error row with no step to replay; the
    // default (failures with a policy step) matches none, and asking for them names the episode
    let nan = run("nan", "nan-at:0");
    refused(&nan, &[], "matches no episode");
    refused(&nan, &["--where", "true"], "has no policy step to replay");
    // NaN at policy step 3: the 3 steps before the error are the episode's frames
    let nan3 = run("nan3", "nan-at:3");
    let dataset = d.join("nan3-dataset");
    ok(pipeline(&["export", nan3.to_str().unwrap(), "--out", dataset.to_str().unwrap(), "--camera-size", "64"]));
    let v = check(&dataset, &nan3, None, &d);
    assert_eq!((&v["frames"], &v["max_action_diff"]), (&serde_json::json!([3, 3]), &serde_json::json!(0.0)), "{v}");
    // a stored action changed after the run: the replay leaves the stored trajectory
    let tampered = run("random", "random");
    let part = std::fs::read_dir(tampered.join("steps")).unwrap().next().unwrap().unwrap().path();
    let edit = "import sys, pyarrow as pa, pyarrow.parquet as pq\n\
                t = pq.read_table(sys.argv[1]); rows = t.to_pylist()\n\
                for r in rows:\n    if r['policy_step'] == 2: r['action'][0] += 0.5\n\
                pq.write_table(pa.Table.from_pylist(rows, schema=t.schema), sys.argv[1])\n";
    let out = Command::new(lerobot_python()).args(["-c", edit, part.to_str().unwrap()]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    refused(&tampered, &["--where", "true"], "the replay is not deterministic: at step 12");
    let leftovers = std::fs::read_dir(&d)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().contains(".partial-"));
    assert_eq!(leftovers.count(), 0);
}
