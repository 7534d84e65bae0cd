//! `pipeline run --policy openvla:<dir>` on the real scene with a tiny random-weight checkpoint
//! of OpenVLA's architecture in the real format (built by `scripts/reference/openvla_tiny.py`
//! with transformers + timm; `policies/tests/openvla_parity.rs` proves the Rust model equals
//! the Python one): the camera is rendered and preprocessed, seven action tokens are decoded per
//! step, the action is un-normalised with the named statistics and the gripper mapped; a wrong
//! `unnorm` key stops the run before any episode, naming the keys the checkpoint has.

use libero_e2e::{ok, pipeline, repo_root, single_and_batched_steps, sql_rows, test_dir};
use std::path::PathBuf;
use std::process::Command;

fn tiny_checkpoint(dir: &std::path::Path) -> PathBuf {
    let venv =
        std::env::var_os("LIBERO_OPENVLA_VENV").map(PathBuf::from).unwrap_or_else(|| repo_root().join(".openvla-venv"));
    let py = venv.join("bin/python");
    assert!(py.exists(), "no OpenVLA reference venv at {}: run ./setup.sh", venv.display());
    let ckpt = dir.join("openvla-tiny");
    let out = Command::new(py).arg(repo_root().join("scripts/reference/openvla_tiny.py")).arg(&ckpt).output().unwrap();
    assert!(out.status.success(), "openvla_tiny.py: {}", String::from_utf8_lossy(&out.stderr));
    ckpt
}

#[test]
fn an_openvla_checkpoint_runs_through_the_pipeline() {
    let d = test_dir("openvla", "run");
    let ckpt = tiny_checkpoint(&d);
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "1", "-o", s]));

    let bad = pipeline(&[
        "run",
        s,
        "--out",
        d.join("bad").to_str().unwrap(),
        "--policy",
        &format!("openvla:{}?unnorm=nope", ckpt.display()),
    ]);
    let text = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && text.contains("nope") && text.contains("libero_spatial_no_noops"), "{text}");
    assert!(!d.join("bad/episodes").exists(), "an episode started with a wrong unnorm key");

    let run = d.join("run");
    let policy = format!("openvla:{}?unnorm=libero_spatial_no_noops", ckpt.display());
    ok(pipeline(&["run", s, "--out", run.to_str().unwrap(), "--policy", &policy, "--max-steps", "3"]));
    assert_eq!(sql_rows(&run, "SELECT n_policy_steps, COALESCE(error, 'none') FROM episodes", &[]), [["3", "none"]]);
    let grippers = sql_rows(&run, "SELECT action[7] FROM steps WHERE policy_step IS NOT NULL", &[]);
    assert!(grippers.iter().all(|g| ["-1.0", "0.0", "1.0"].contains(&g[0].as_str())), "{grippers:?}");
    let identity = sql_rows(&run, "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    assert!(identity.contains("jpeg95") && identity.contains("libero_spatial_no_noops"), "{identity}");
}

/// `&batch=4` with 4 workers: the episodes' queries share forwards (prompts of different lengths,
/// left-padded), and each episode's actions equal those of one episode per forward
/// ([`single_and_batched_steps`]). (On a CPU, as in CI: f32. In bf16 on a GPU a near tie between
/// two action tokens could decode differently.)
#[test]
fn batched_openvla_forwards_give_each_episode_its_unbatched_actions() {
    let d = test_dir("openvla", "batch");
    let ckpt = tiny_checkpoint(&d);
    let policy = format!("openvla:{}?unnorm=libero_spatial_no_noops", ckpt.display());
    let (single, batched) = single_and_batched_steps(&d, &policy, 3);
    assert_eq!(single.len(), 4 * 3);
    // `pipeline sql --csv` writes the list column as its text
    assert!(single[0].join(",").contains("\"[") && single[0].len() == 2 + 7, "{:?}", single[0]);
    // decoded bins, un-normalised the same way: equal, not merely close
    assert_eq!(single, batched);
}
