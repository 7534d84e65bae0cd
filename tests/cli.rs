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
    assert!(rows.iter().any(|r| r["instruction"] == "Put the cream cheese on the bowl"));
}

#[test]
fn a_missing_bundle_folder_is_a_clear_error() {
    let out = pipeline(&["tasks", "--bundles", "/nonexistent/bundles"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/bundles") && err.contains("./setup.sh"), "{err}");
}
