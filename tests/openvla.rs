//! `pipeline run --policy openvla:<dir>` on the real scene with a tiny random-weight checkpoint
//! of OpenVLA's architecture in the real format (built by `scripts/reference/openvla_tiny.py`
//! with transformers + timm; `policies/tests/openvla_parity.rs` proves the Rust model equals
//! the Python one): the camera is rendered and preprocessed, seven action tokens are decoded per
//! step, the action is un-normalised with the named statistics and the gripper mapped; a wrong
//! `unnorm` key stops the run before any episode, naming the keys the checkpoint has.

use libero_e2e::{ok, pipeline, repo_root, single_and_batched_steps, sql_rows, test_dir};
use std::path::PathBuf;
use std::process::Command;

pub(crate) fn tiny_checkpoint(dir: &std::path::Path) -> PathBuf {
    let venv =
        std::env::var_os("LIBERO_OPENVLA_VENV").map(PathBuf::from).unwrap_or_else(|| repo_root().join(".openvla-venv"));
    let py = venv.join("bin/python");
    assert!(py.exists(), "no OpenVLA reference venv at {}: run ./setup.sh --tests", venv.display());
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
    // the attention the model ran: eager on a CPU unless the spec says otherwise
    assert!(identity.contains("attention") && identity.contains("eager: softmax"), "{identity}");

    // `&attention=sdpa` (the GPU's default) runs on a CPU too, stores the actions eager stores
    // (f32, where the two agree to ~1e-6), and the manifest says which attention ran
    let sdpa = d.join("sdpa");
    let sdpa_policy = format!("{policy}&attention=sdpa");
    ok(pipeline(&["run", s, "--out", sdpa.to_str().unwrap(), "--policy", &sdpa_policy, "--max-steps", "3"]));
    let actions = |run: &std::path::Path| {
        sql_rows(run, "SELECT policy_step, action FROM steps WHERE policy_step IS NOT NULL ORDER BY policy_step", &[])
    };
    assert_eq!(actions(&sdpa), actions(&run));
    let identity = sql_rows(&sdpa, "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    assert!(identity.contains("sdpa: torch") && !identity.contains("eager: softmax"), "{identity}");
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

/// `&devices=cpu,cpu`: two replicas of the model, each with its own batcher. The 4 episodes spread
/// over both (the run reports each replica's forwards), and each episode's actions equal those of
/// one episode per forward. `&quant=int8` and `&quant=int4`: the weights quantised as they load,
/// the manifest says how, and `pipeline compare` against the unquantised run reports the first
/// actions' agreement (policy step 0 sees the same observation in both runs).
#[test]
fn replicas_serve_their_own_episodes_and_quantised_weights_run_through_the_pipeline() {
    let d = test_dir("openvla", "replicas");
    let ckpt = tiny_checkpoint(&d);
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0,1", "--trials", "2", "-o", s]));
    let policy = format!("openvla:{}?unnorm=libero_spatial_no_noops", ckpt.display());
    let extra = ["--max-steps", "3", "--jobs", "4"];
    let columns = "episode_key, policy_step, action";
    let (_, single) = libero_e2e::run_policy_steps(&specs, &d.join("single"), &policy, &extra, columns);
    let replicated = format!("{policy}&batch=2&wait_ms=2000&devices=cpu,cpu");
    let (stderr, on_replicas) = libero_e2e::run_policy_steps(&specs, &d.join("replicas"), &replicated, &extra, columns);
    for replica in ["[replica 1 of 2]", "[replica 2 of 2]"] {
        let line = stderr.lines().find(|l| l.contains(replica)).unwrap_or_else(|| panic!("no {replica}: {stderr}"));
        let forwards: usize = line.split(": ").last().unwrap().split(' ').next().unwrap().parse().unwrap();
        assert!(forwards > 0, "{replica} ran no forward: {line}");
    }
    assert_eq!(single, on_replicas, "an episode's actions depend on its replica");
    let identity = sql_rows(&d.join("replicas"), "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    assert!(
        identity.contains("(episodes in progress + 1) x recent forward ms") && identity.matches("Cpu").count() == 2,
        "{identity}"
    );

    for quant in ["int8", "int4"] {
        let run = d.join(quant);
        let (_, steps) =
            libero_e2e::run_policy_steps(&specs, &run, &format!("{policy}&quant={quant}"), &extra, columns);
        assert_eq!(steps.len(), single.len());
        let identity = sql_rows(&run, "SELECT policy_identity FROM manifest", &[]).concat().join(",");
        assert!(identity.contains(&format!("{quant} weight-only")), "{identity}");
        let out = d.join(format!("compare-{quant}"));
        let stdout = ok(pipeline(&[
            "compare",
            d.join("single").to_str().unwrap(),
            run.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]));
        let line = stdout.lines().find(|l| l.starts_with("first actions")).unwrap_or_else(|| panic!("{stdout}"));
        assert!(line.contains("of 4 episodes equal in every dimension") && line.contains("of 28 dimensions"), "{line}");
        eprintln!("{quant}: {line}");
    }
}
