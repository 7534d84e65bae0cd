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
