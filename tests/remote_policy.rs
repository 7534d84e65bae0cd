//! A policy served over openpi's protocol, evaluated through the whole pipeline on the real scene:
//! `pipeline run --policy openpi:ws://...` against the toy openpi server
//! (`scripts/reference/openpi_toy_server.py`, the PyPI `openpi-client` codec). The server refuses
//! requests without both 224×224 images, as a real π0 would, so a finished episode proves the
//! rollout rendered the cameras and preprocessed them; the stored actions prove the chunking; a
//! dropped connection must become an error row while the run goes on.

use libero_e2e::{ok, pipeline, repo_root, sql_rows, test_dir};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn python() -> PathBuf {
    let venv =
        std::env::var_os("LIBERO_REMOTE_VENV").map(PathBuf::from).unwrap_or_else(|| repo_root().join(".remote-venv"));
    let py = venv.join("bin/python");
    assert!(py.exists(), "no remote-policy venv at {}: run ./setup.sh --tests", venv.display());
    py
}

pub(crate) struct ToyServer {
    child: Child,
    pub(crate) url: String,
}

impl ToyServer {
    pub(crate) fn start(args: &[&str]) -> ToyServer {
        let mut child = Command::new(python())
            .arg(repo_root().join("scripts/reference/openpi_toy_server.py"))
            .args(["--port", "0", "--require-images"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start the toy server");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
        let port =
            line.trim().strip_prefix("listening on ").unwrap_or_else(|| panic!("server said {line:?}")).to_string();
        ToyServer { child, url: format!("ws://127.0.0.1:{port}") }
    }
}

impl Drop for ToyServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn run_openpi(dir: &Path, url: &str, trials: &str) -> PathBuf {
    let specs = dir.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", trials, "-o", s]));
    let run = dir.join("run");
    let policy = format!("openpi:{url}");
    ok(pipeline(&["run", s, "--out", run.to_str().unwrap(), "--policy", &policy, "--max-steps", "12", "--jobs", "1"]));
    run
}

#[test]
fn an_openpi_served_policy_runs_through_the_pipeline_with_rendered_images_and_chunks() {
    let server = ToyServer::start(&[]);
    let d = test_dir("remote", "ok");
    let run = run_openpi(&d, &server.url, "1");
    let e = sql_rows(&run, "SELECT n_policy_steps, COALESCE(error, 'none') FROM episodes", &[]);
    assert_eq!(e, [["12", "none"]], "the server refuses requests without images: {e:?}");
    // The manifest records the server's metadata and the image preprocessing.
    let identity = sql_rows(&run, "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    assert!(identity.contains("toy") && identity.contains("pad224"), "{identity}");
    // Chunks of 10, 5 executed: within a chunk consecutive actions step by 0.01 in every
    // component (the toy formula); a new chunk starts at policy steps 5 and 10.
    let rows = sql_rows(
        &run,
        "SELECT policy_step, action[1], action[7] FROM steps WHERE policy_step IS NOT NULL ORDER BY policy_step",
        &[],
    );
    let a: Vec<(f64, f64)> = rows.iter().map(|r| (r[1].parse().unwrap(), r[2].parse().unwrap())).collect();
    for t in 1..12 {
        let step = a[t].0 - a[t - 1].0;
        let new_chunk = t % 5 == 0;
        assert_eq!(
            (step - 0.01).abs() < 1e-5,
            !new_chunk,
            "policy step {t}: action[0] moved by {step} ({})",
            if new_chunk { "a new chunk should restart" } else { "within a chunk" }
        );
    }
}

#[test]
fn a_dropped_connection_becomes_an_error_row_and_the_run_goes_on() {
    // Request 2 (the second chunk of the first episode) is dropped; the next episode reconnects.
    let server = ToyServer::start(&["--drop-at", "2"]);
    let d = test_dir("remote", "drop");
    let t0 = Instant::now();
    let run = run_openpi(&d, &server.url, "2");
    assert!(t0.elapsed() < Duration::from_secs(120), "the run took {:?}", t0.elapsed());
    let rows = sql_rows(
        &run,
        "SELECT init_state_id, n_policy_steps, COALESCE(error_kind, 'none') FROM episodes ORDER BY init_state_id",
        &[],
    );
    assert_eq!(rows, [["0", "5", "policy"], ["1", "12", "none"]]);
}
