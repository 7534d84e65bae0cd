//! `pipeline run --policy torchscript:<file>` on the real scene: a small module traced with
//! libtorch and saved as TorchScript, with its `model.json`, evaluated through the whole dataflow
//! (cameras rendered for it, chunks executed, identity with the file's hash in the manifest).

use libero_e2e::{ok, pipeline, run_policy_steps, sql_rows, test_dir};
use tch::{CModule, Device, Kind, Tensor};

/// A file's sha256 by the system's `sha256sum` (a tool independent of the policy's hashing).
fn hex_sha256(path: &std::path::Path) -> String {
    let out = std::process::Command::new("sha256sum").arg(path).output().unwrap();
    String::from_utf8_lossy(&out.stdout).split_whitespace().next().unwrap().to_string()
}

#[test]
fn a_torchscript_policy_runs_through_the_pipeline_on_rendered_cameras() {
    let d = test_dir("torchscript", "run");
    let file = d.join("model.pt");
    let size = 64;
    let inputs = [
        Tensor::rand([1, 3, size, size], (Kind::Float, Device::Cpu)),
        Tensor::rand([1, 3, size, size], (Kind::Float, Device::Cpu)),
        Tensor::rand([1, 8], (Kind::Float, Device::Cpu)),
    ];
    // Small motions from what it sees: 0.1·(mean(agentview) − mean(wrist)) per component, then
    // + 0.01 per chunk position, so chunks are visible in the stored actions.
    CModule::create_by_tracing("Toy", "forward", &inputs, &mut |x| {
        // per sample (a batch of episodes must not mix): means over channels and pixels only
        let mean = |t: &Tensor| t.mean_dim([1i64, 2, 3].as_slice(), false, Kind::Float).unsqueeze(1);
        let base = (mean(&x[0]) - mean(&x[1])) * 0.1 + x[2].narrow(1, 0, 7) * 0.0;
        let steps = Tensor::arange(4, (Kind::Float, Device::Cpu)).reshape([1, 4, 1]) * 0.01;
        vec![base.unsqueeze(1) + steps]
    })
    .unwrap()
    .save(&file)
    .unwrap();
    std::fs::write(
        d.join("model.json"),
        format!(r#"{{"inputs": ["agentview", "wrist", "state"], "image_size": {size}, "preprocessing": "rot180", "chunk_size": 4, "replan_steps": 4}}"#),
    )
    .unwrap();

    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "1", "-o", s]));
    let run = d.join("run");
    let policy = format!("torchscript:{}", file.display());
    ok(pipeline(&["run", s, "--out", run.to_str().unwrap(), "--policy", &policy, "--max-steps", "8"]));
    let e = sql_rows(&run, "SELECT n_policy_steps, COALESCE(error, 'none') FROM episodes", &[]);
    assert_eq!(e, [["8", "none"]]);
    let identity = sql_rows(&run, "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    assert!(identity.contains(&hex_sha256(&file)), "the manifest lacks the file's hash: {identity}");
    let a: Vec<f64> = sql_rows(&run, "SELECT action[1] FROM steps WHERE policy_step IS NOT NULL ORDER BY step", &[])
        .iter()
        .map(|r| r[0].parse().unwrap())
        .collect();
    for t in [1, 2, 3, 5, 6, 7] {
        assert!((a[t] - a[t - 1] - 0.01).abs() < 1e-5, "within a chunk, step {t}: {a:?}");
    }
    // The second chunk saw other images (the arm moved), so it starts elsewhere.
    assert!((a[4] - a[3] - 0.01).abs() > 1e-7, "{a:?}");
    assert!(a.iter().all(|x| x.abs() < 0.2), "{a:?}");
}

/// The same module with `?batch=4` and 4 workers: the workers' queries share forwards, each
/// episode gets its own answers, and the actions equal those of one episode per forward.
#[test]
fn batched_forwards_give_each_episode_the_actions_of_an_unbatched_run() {
    let d = test_dir("torchscript", "batch");
    let file = d.join("model.pt");
    let inputs = [
        Tensor::rand([1, 3, 32, 32], (Kind::Float, Device::Cpu)),
        Tensor::rand([1, 3, 32, 32], (Kind::Float, Device::Cpu)),
        Tensor::rand([1, 8], (Kind::Float, Device::Cpu)),
    ];
    CModule::create_by_tracing("Toy", "forward", &inputs, &mut |x| {
        let mean = |t: &Tensor| t.mean_dim([1i64, 2, 3].as_slice(), false, Kind::Float).unsqueeze(1);
        let base = (mean(&x[0]) - mean(&x[1])) * 0.1 + x[2].narrow(1, 0, 7) * 0.5;
        let steps = Tensor::arange(2, (Kind::Float, Device::Cpu)).reshape([1, 2, 1]) * 0.01;
        vec![(base.unsqueeze(1) + steps).clamp(-0.3, 0.3)]
    })
    .unwrap()
    .save(&file)
    .unwrap();
    std::fs::write(
        d.join("model.json"),
        r#"{"inputs": ["agentview", "wrist", "state"], "image_size": 32, "preprocessing": "rot180", "chunk_size": 2, "replan_steps": 2}"#,
    )
    .unwrap();
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0,1", "--trials", "2", "-o", s]));
    let actions = |name: &str, policy: String| -> Vec<Vec<String>> {
        let extra = ["--max-steps", "6", "--jobs", "4"];
        run_policy_steps(
            &specs,
            &d.join(name),
            &policy,
            &extra,
            "episode_key, policy_step, action[1], action[3], action[4]",
        )
        .1
    };
    let single = actions("single", format!("torchscript:{}", file.display()));
    let batched = actions("batched", format!("torchscript:{}?batch=4", file.display()));
    assert_eq!(single.len(), 4 * 6);
    for (a, b) in single.iter().zip(&batched) {
        assert_eq!(a[..2], b[..2]);
        for k in 2..5 {
            let (x, y): (f64, f64) = (a[k].parse().unwrap(), b[k].parse().unwrap());
            assert!((x - y).abs() < 1e-5, "{a:?} vs {b:?}");
        }
    }
    let identity = sql_rows(&d.join("batched"), "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    assert!(identity.contains("max_episodes_per_forward"), "{identity}");
}
