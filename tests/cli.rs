//! The `pipeline` binary as users run it.

use libero_e2e::{pipeline_bin, repo_root};
use std::process::Command;

fn pipeline(args: &[&str]) -> std::process::Output {
    Command::new(pipeline_bin()).args(args).current_dir(repo_root()).output().expect("run pipeline")
}

#[test]
fn help_lists_the_subcommands_that_exist() {
    let out = pipeline(&["--help"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for cmd in [
        "tasks",
        "specs",
        "run",
        "results",
        "failures",
        "sql",
        "compare",
        "sample-size",
        "smoke",
        "video",
        "videos",
        "bench",
    ] {
        assert!(text.contains(cmd), "{cmd} missing from --help:\n{text}");
    }
}

#[test]
fn tasks_lists_the_forty_canonical_tasks_with_their_instructions() {
    let out = pipeline(&["tasks", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: Vec<serde_json::Value> =
        String::from_utf8_lossy(&out.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    for suite in ["libero_spatial", "libero_object", "libero_goal", "libero_10"] {
        assert_eq!(rows.iter().filter(|r| r["suite"] == suite).count(), 10, "{suite}");
    }
    // the published loops' text (task.language), with the BDDL tag beside it
    let t = rows.iter().find(|r| r["suite"] == "libero_goal" && r["task_id"] == 6).unwrap();
    assert_eq!(t["instruction"], "put the cream cheese in the bowl");
    assert_eq!(t["instruction_bddl"], "put the cream cheese on the bowl");
}

#[test]
fn a_missing_bundle_folder_is_a_clear_error() {
    let out = pipeline(&["tasks", "--bundles", "/nonexistent/bundles"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/bundles") && err.contains("./setup.sh"), "{err}");
}

fn stderr_of(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Bad input from the issue-18 catalogue: each a clear error (or, for SQL without a run, an
/// answer), never an empty run.
#[test]
fn zero_steps_or_trials_are_errors_and_sql_needs_no_run_for_functions() {
    let tmp = std::env::temp_dir().join(format!("libero-cli-bad-{}", std::process::id()));
    let spec = tmp.join("specs.parquet");
    let out = pipeline(&["specs", "--suites", "libero_object", "--trials", "0", "-o", spec.to_str().unwrap()]);
    assert!(!out.status.success() && stderr_of(&out).contains("--trials"), "{}", stderr_of(&out));
    assert!(!spec.exists(), "an empty spec table was written");

    let out = pipeline(&[
        "specs",
        "--suites",
        "libero_object",
        "--tasks",
        "0",
        "--trials",
        "1",
        "-o",
        spec.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr_of(&out));
    let run = tmp.join("run");
    let out = pipeline(&[
        "run",
        spec.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--policy",
        "lift",
        "--max-steps",
        "0",
    ]);
    assert!(!out.status.success() && stderr_of(&out).contains("--max-steps"), "{}", stderr_of(&out));
    assert!(!run.join("manifest.json").exists(), "a run was started");

    let out = pipeline(&["sql", "SELECT wilson_lo(3, 10) AS lo, wilson_hi(3, 10) AS hi", "--csv"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", stderr_of(&out));
    let row: Vec<f64> = text.lines().nth(1).unwrap().split(',').map(|v| v.parse().unwrap()).collect();
    assert!((row[0] - 0.1078).abs() < 1e-3 && (row[1] - 0.6032).abs() < 1e-3, "{text}");
    let _ = std::fs::remove_dir_all(&tmp);
}

/// Started outside the repository with no --bundles, the binary still finds the bundles of the
/// checkout it was built in; pointed at a folder without bundles, the error lists where it looked.
#[test]
fn the_binary_finds_its_bundles_from_any_working_directory() {
    let elsewhere = std::env::temp_dir();
    let out = Command::new(pipeline_bin())
        .args(["tasks"])
        .current_dir(&elsewhere)
        .env_remove("LIBERO_BUNDLES")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("libero_spatial"));

    let empty = elsewhere.join(format!("libero-no-bundles-{}", std::process::id()));
    std::fs::create_dir_all(&empty).unwrap();
    let out = Command::new(pipeline_bin())
        .args(["tasks"])
        .current_dir(&elsewhere)
        .env("LIBERO_BUNDLES", &empty)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        stderr_of(&out).contains(empty.to_str().unwrap()) && stderr_of(&out).contains("setup.sh"),
        "{}",
        stderr_of(&out)
    );
    let _ = std::fs::remove_dir_all(&empty);
}
