//! `pipeline run --policy oft:<dir>` on the real scene with a tiny random-weight OpenVLA-OFT in the
//! released checkpoint layout (built by `scripts/reference/oft_tiny.py`; `policies/tests/oft_parity.rs`
//! proves the Rust model equals the Python one): both cameras are rendered and preprocessed, the
//! state is sent, an 8-action chunk is predicted per query and executed open loop (cameras rendered
//! only when the chunk is spent), the gripper mapped; a wrong `unnorm` key, a missing head file or a
//! directory that is no checkpoint stops the run before any episode.

use libero_e2e::{ok, pipeline, repo_root, single_and_batched_steps, sql_rows, test_dir};
use std::path::{Path, PathBuf};
use std::process::Command;

fn tiny_checkpoint(dir: &Path) -> PathBuf {
    let venv =
        std::env::var_os("LIBERO_OPENVLA_VENV").map(PathBuf::from).unwrap_or_else(|| repo_root().join(".openvla-venv"));
    let py = venv.join("bin/python");
    assert!(py.exists(), "no OpenVLA reference venv at {}: run ./setup.sh --tests", venv.display());
    let ckpt = dir.join("oft-tiny");
    let out = Command::new(py).arg(repo_root().join("scripts/reference/oft_tiny.py")).arg(&ckpt).output().unwrap();
    assert!(out.status.success(), "oft_tiny.py: {}", String::from_utf8_lossy(&out.stderr));
    ckpt
}

/// A run that must fail before any episode, saying `says`.
fn refused(d: &Path, specs: &str, name: &str, policy: &str, says: &[&str]) {
    let out = pipeline(&["run", specs, "--out", d.join(name).to_str().unwrap(), "--policy", policy]);
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && says.iter().all(|s| text.contains(s)), "{policy}: {text}");
    assert!(!d.join(name).join("episodes").exists(), "{policy}: an episode started");
}

#[test]
fn an_oft_checkpoint_runs_through_the_pipeline() {
    let d = test_dir("oft", "run");
    let ckpt = tiny_checkpoint(&d);
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "1", "-o", s]));

    refused(&d, s, "bad-key", &format!("oft:{}?unnorm=nope", ckpt.display()), &["nope", "libero_spatial_no_noops"]);
    let headless = d.join("headless");
    std::fs::create_dir_all(&headless).unwrap();
    for f in std::fs::read_dir(&ckpt).unwrap() {
        let p = f.unwrap().path();
        if p.is_file() && !p.file_name().unwrap().to_str().unwrap().starts_with("action_head--") {
            std::fs::copy(&p, headless.join(p.file_name().unwrap())).unwrap();
        }
    }
    refused(&d, s, "no-head", &format!("oft:{}", headless.display()), &["action_head--", "oft"]);
    refused(&d, s, "no-dir", &format!("oft:{}", d.join("nowhere").display()), &["nowhere"]);

    let run = d.join("run");
    let policy = format!("oft:{}?unnorm=libero_spatial_no_noops", ckpt.display());
    ok(pipeline(&["run", s, "--out", run.to_str().unwrap(), "--policy", &policy, "--max-steps", "10"]));
    assert_eq!(sql_rows(&run, "SELECT n_policy_steps, COALESCE(error, 'none') FROM episodes", &[]), [["10", "none"]]);
    // open loop: the cameras are rendered (and the model asked) at steps 0 and 8 only
    // (a step without cameras takes microseconds; rendering two 256² cameras, milliseconds)
    let rendered = sql_rows(&run, "SELECT policy_step FROM steps WHERE render_ms > 1 ORDER BY policy_step", &[]);
    assert_eq!(rendered, [["0"], ["8"]]);
    let grippers = sql_rows(&run, "SELECT action[7] FROM steps WHERE policy_step IS NOT NULL", &[]);
    assert!(grippers.iter().all(|g| ["-1.0", "1.0"].contains(&g[0].as_str())), "{grippers:?}");
    let arm = sql_rows(&run, "SELECT count(DISTINCT action[1]) FROM steps WHERE policy_step IS NOT NULL", &[]);
    assert!(arm[0][0].parse::<usize>().unwrap() > 2, "the chunk's actions differ: {arm:?}");
    let identity = sql_rows(&run, "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    for needle in ["openvla-oft", "action_head--150000_checkpoint.pt", "jpeg95", "libero_spatial_no_noops", "wrist"] {
        assert!(identity.contains(needle), "{needle}: {identity}");
    }
}

/// `&batch=4` with 4 workers: the episodes' queries share forwards (prompts of different lengths,
/// left-padded), and each episode's actions are those of one episode per forward: the first chunk's
/// arm within 1e-4 (continuous outputs: a batch changes the GEMM kernels and the order of sums), the
/// gripper equal. Which episodes share a forward depends on when each asks (`wait_ms`), and so does
/// the difference: measured 1.5e-6 for most pairings, 2.4e-5 and 2.9e-5 for others (on two
/// machines); a wrong row's readout or a padding key attended to moves the arm by ~1e-1. The
/// second chunk is asked from states that already differ by the first chunk's differences, which
/// the JPEG round trip and the random weights amplify (measured up to 9.3e-4): it must stay within
/// 1e-2, far below what a wrong row's readout or padding would give.
#[test]
fn batched_oft_forwards_give_each_episode_its_unbatched_actions() {
    let d = test_dir("oft", "batch");
    let ckpt = tiny_checkpoint(&d);
    let policy = format!("oft:{}?unnorm=libero_spatial_no_noops", ckpt.display());
    let (single, batched) = single_and_batched_steps(&d, &policy, 9);
    assert_eq!(single.len(), 4 * 9);
    let numbers = |row: &[String]| -> Vec<f64> {
        row[2..].iter().map(|v| v.trim_matches(|c| "\"[] ".contains(c)).parse::<f64>().unwrap()).collect()
    };
    let (mut first, mut later) = (0.0f64, 0.0f64);
    for (a, b) in single.iter().zip(&batched) {
        assert_eq!(a[..2], b[..2], "the same episode and step");
        let (x, y) = (numbers(a), numbers(b));
        assert_eq!(x.len(), 7, "{a:?}");
        assert_eq!(x[6], y[6], "gripper of {a:?} vs {b:?}");
        let d = x.iter().zip(&y).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
        let chunk = if a[1].parse::<u32>().unwrap() < 8 { &mut first } else { &mut later };
        *chunk = chunk.max(d);
    }
    eprintln!("batched vs one episode per forward: max |Δ action| first chunk {first:.2e}, second {later:.2e}");
    assert!(first <= 1e-4, "batched actions of the first chunk differ by {first}");
    assert!(later <= 1e-2, "batched actions of the second chunk differ by {later}");
}

/// Workers rendering through one shared GL thread (`LIBERO_GL_THREADS=shared`, the default on
/// GPUs: `libero_sim::gl_thread`) store the steps of workers with a GL thread each: 4 episodes of
/// two tasks, every action equal (the frames are equal bit for bit and the model is deterministic
/// here). The shared run has one worker, which keeps its renderer for a task's second episode and
/// makes a new one for the next task; the other has 4 workers, a renderer per episode. An unknown
/// value stops the run before any episode, naming the values.
#[test]
fn workers_sharing_one_gl_thread_store_the_steps_of_a_thread_each() {
    let d = test_dir("oft", "gl-threads");
    let ckpt = tiny_checkpoint(&d);
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0,1", "--trials", "2", "-o", s]));
    let policy = format!("oft:{}?unnorm=libero_spatial_no_noops", ckpt.display());
    let bogus = d.join("bogus");
    let args = ["run", s, "--out", bogus.to_str().unwrap(), "--policy", &policy];
    let refused = libero_e2e::pipeline_with_env(&args, &[("LIBERO_GL_THREADS", "one")]);
    let text = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && text.contains("LIBERO_GL_THREADS") && text.contains("shared"), "{text}");
    assert!(!bogus.join("episodes").exists(), "an episode started");
    let steps = |name: &str, threads: &str, jobs: &str| {
        let extra = ["--max-steps", "9", "--jobs", jobs];
        let env = [("LIBERO_GL_THREADS", threads)];
        libero_e2e::run_policy_steps_with_env(
            &specs,
            &d.join(name),
            &policy,
            &extra,
            "episode_key, policy_step, action",
            &env,
        )
        .1
    };
    let (own, shared) = (steps("per-worker", "per-worker", "4"), steps("shared", "shared", "1"));
    assert_eq!(own.len(), 4 * 9);
    assert_eq!(own, shared, "a shared GL thread changed what the policy saw");
}
