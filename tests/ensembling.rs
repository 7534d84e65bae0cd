//! Action-chunk ensembling (`ensemble=`, `policies::ensembling`) through the whole pipeline: a
//! `python:` policy whose chunks are a fixed function of the policy step
//! (`tests/fixtures/python_policies/chunks.py`) runs one LIBERO episode under each rule, and the
//! stored actions are compared with what the rule's reference code executes of the chunks the host
//! recorded (`scripts/reference/ensembling_oracle.py`): vla-eval 0.8.0's `ActionChunkBuffer`,
//! lerobot 0.6.1's `ACTTemporalEnsembler`, vla-eval's packaging of starVLA's `AdaptiveEnsembler`.

use libero_e2e::{ok, pipeline, pipeline_with_env, repo_root, sql_rows, test_dir};
use std::path::{Path, PathBuf};
use std::process::Command;

const STEPS: usize = 12;

fn venv_python(link: &str) -> PathBuf {
    let py = repo_root().join(link).join("bin/python");
    assert!(py.exists(), "no venv at {}: run ./setup.sh --tests", py.display());
    py
}

/// One episode of `python:chunks:make?size=SIZE&ensemble=RULE` for 12 policy steps, the host's
/// calls recorded; returns the run's directory and stderr.
fn run(d: &Path, name: &str, size: usize, rule: &str) -> (PathBuf, String) {
    let specs = d.join("specs.parquet");
    if !specs.exists() {
        let s = specs.to_str().unwrap();
        ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "1", "-o", s]));
    }
    let run = d.join(name);
    let policy = format!(
        "python:chunks:make?python={}&batch=1&size={size}&ensemble={rule}",
        venv_python(".lerobot-venv").display()
    );
    let record = d.join(format!("{name}-record"));
    let fixtures = repo_root().join("tests/fixtures/python_policies");
    let steps = STEPS.to_string();
    let out = pipeline_with_env(
        &["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", &policy]
            .into_iter()
            .chain(["--max-steps", &steps, "--jobs", "1"])
            .collect::<Vec<_>>(),
        &[("PYTHONPATH", fixtures.to_str().unwrap()), ("LIBERO_EVAL_HOST_RECORD", record.to_str().unwrap())],
    );
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{rule}: {stderr}");
    (run, stderr)
}

fn stored_actions(run: &Path) -> Vec<Vec<f32>> {
    sql_rows(run, "SELECT array_to_string(action, ' ') FROM steps WHERE policy_step IS NOT NULL ORDER BY step", &[])
        .into_iter()
        .map(|r| r[0].split(' ').map(|v| v.parse::<f32>().unwrap()).collect())
        .collect()
}

/// The reference's executed actions and query steps for the chunks recorded under `run`.
fn oracle(venv: &str, rule: &str, record: &Path) -> (Vec<Vec<f32>>, Vec<u64>, Vec<u64>) {
    let out = Command::new(venv_python(venv))
        .arg(repo_root().join("scripts/reference/ensembling_oracle.py"))
        .args([rule, record.to_str().unwrap(), &STEPS.to_string()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{rule}: {}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_str(String::from_utf8_lossy(&out.stdout).trim()).unwrap();
    let actions = v["actions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a.as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect())
        .collect();
    let steps = |k: &str| v[k].as_array().unwrap().iter().map(|x| x.as_u64().unwrap()).collect();
    (actions, steps("query_steps"), steps("recorded_query_steps"))
}

#[test]
fn ensembled_chunks_execute_what_the_reference_rules_make_of_them() {
    let d = test_dir("ensembling", "rules");
    // (rule, chunk size, the venv with its reference, the largest difference allowed in float32 ulps)
    let cases = [
        ("newest:3", 4, ".vla-eval-venv", 0),
        ("average:2", 4, ".vla-eval-venv", 0),
        ("ema:0.3:3", 4, ".vla-eval-venv", 0),
        ("temporal:0.01", 4, ".lerobot-venv", 0),
        // ACT's own chunk length (the 12 steps use the first 12 of its 100 weights exp(-0.01 i),
        // libm's expf against torch's)
        ("temporal:0.01", 100, ".lerobot-venv", 0),
        // float64 in both, in a different order of operations, and equal once rounded to float32
        ("adaptive:3:0.1", 4, ".vla-eval-venv", 0),
    ];
    for (rule, size, venv, ulps) in cases {
        let name = format!("{}-{size}", rule.replace([':', '.'], "-"));
        let (run, stderr) = run(&d, &name, size, rule);
        let stored = stored_actions(&run);
        assert_eq!(stored.len(), STEPS, "{rule}: {stderr}");
        let (expected, queries, recorded) = oracle(venv, rule, &d.join(format!("{name}-record")));
        // The queries came when the rule needs them: the pipeline's calls are the reference's.
        assert_eq!(recorded[..queries.len()], queries[..], "{rule}: asked at other steps");
        let mut worst = 0u32;
        for (step, (ours, theirs)) in stored.iter().zip(&expected).enumerate() {
            for (a, b) in ours.iter().zip(theirs) {
                let apart = (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs() as u32;
                worst = worst.max(apart);
                assert!(apart <= ulps, "{rule}: step {step}: ours {ours:?} reference {theirs:?}");
            }
        }
        eprintln!("{rule}: {STEPS} actions, queries at {queries:?}, at most {worst} ulp from the reference");
        let manifest: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run.join("manifest.json")).unwrap()).unwrap();
        assert_eq!(manifest["policy_identity"]["ensemble"]["rule"], rule, "{manifest}");
    }

    // Another rule is another identity: the resume is refused before any episode.
    let specs = d.join("specs.parquet");
    let first = d.join("newest-3-4");
    let policy = format!(
        "python:chunks:make?python={}&batch=1&size=4&ensemble=newest:2",
        venv_python(".lerobot-venv").display()
    );
    let fixtures = repo_root().join("tests/fixtures/python_policies");
    let out = pipeline_with_env(
        &["run", specs.to_str().unwrap(), "--out", first.to_str().unwrap(), "--policy", &policy],
        &[("PYTHONPATH", fixtures.to_str().unwrap())],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a resume under another ensembling rule ran:\n{stderr}");
    assert!(stderr.contains("another configuration") && stderr.contains("ensemble"), "{stderr}");
}

#[test]
fn chunks_too_short_to_ensemble_cost_their_episodes_with_the_fix_named() {
    let d = test_dir("ensembling", "short");
    let (run, stderr) = run(&d, "short", 2, "average:2");
    assert_eq!(sql_rows(&run, "SELECT n_policy_steps, error_kind FROM episodes", &[]), [["0", "policy"]], "{stderr}");
    let errors = ok(pipeline(&["sql", "SELECT error FROM episodes", "--run", run.to_str().unwrap(), "--csv"]));
    assert!(errors.contains("ensemble=average:2") && errors.contains("choose N below 2"), "{errors}");
}
