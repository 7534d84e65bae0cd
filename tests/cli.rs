//! The `pipeline` binary as users run it.

use libero_e2e::{pipeline_bin, repo_root};
use std::process::Command;

fn pipeline(args: &[&str]) -> std::process::Output {
    Command::new(pipeline_bin()).args(args).current_dir(repo_root()).output().expect("run pipeline")
}

/// Every visible subcommand, `bench`'s included.
const SUBCOMMANDS: [&str; 23] = [
    "tasks",
    "specs",
    "run",
    "results",
    "robustness",
    "generalisation",
    "failures",
    "report",
    "compact",
    "sql",
    "compare",
    "sample-size",
    "smoke",
    "video",
    "videos",
    "scheduler",
    "executor",
    "doctor",
    "bench",
    "bench sim",
    "bench render",
    "bench run",
    "bench perturbation",
];

#[test]
fn help_lists_the_subcommands_that_exist() {
    let out = pipeline(&["--help"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for cmd in SUBCOMMANDS.iter().filter(|c| !c.contains(' ')) {
        assert!(text.contains(&format!("  {cmd} ")), "{cmd} missing from --help:\n{text}");
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

/// docs/src/cli.md is the binary's own `--help`, page for page (`pipeline cli-reference`):
/// a flag added, renamed or re-described without regenerating the page fails here.
#[test]
fn the_cli_reference_page_is_the_binarys_own_help() {
    let out = pipeline(&["cli-reference"]);
    assert!(out.status.success(), "{}", stderr_of(&out));
    let generated = String::from_utf8(out.stdout).unwrap();
    for heading in ["# Command line\n", "\n## pipeline tasks\n", "\n## pipeline run\n", "\n## pipeline bench sim\n"] {
        assert!(generated.contains(heading), "{heading:?} missing from the page:\n{generated}");
    }
    assert!(!generated.contains("## pipeline cli-reference") && !generated.contains('\x1b'), "{generated}");
    let page = repo_root().join("docs/src/cli.md");
    if std::env::var_os("LIBERO_UPDATE_DOCS").is_some_and(|v| v == "1") {
        std::fs::write(&page, &generated).unwrap();
        return;
    }
    let stored = std::fs::read_to_string(&page).unwrap_or_default();
    if stored != generated {
        let first = stored.lines().zip(generated.lines()).position(|(a, b)| a != b);
        let line = first.unwrap_or(stored.lines().count().min(generated.lines().count()));
        panic!(
            "{} differs from `pipeline cli-reference` (first at line {}: {:?} there, {:?} from the binary); \
             regenerate it: target/release/pipeline cli-reference > docs/src/cli.md, or run this test with \
             LIBERO_UPDATE_DOCS=1",
            page.display(),
            line + 1,
            stored.lines().nth(line).unwrap_or("<end>"),
            generated.lines().nth(line).unwrap_or("<end>"),
        );
    }
}

/// Every subcommand's `--help` carries examples whose subcommand is its own.
#[test]
fn every_subcommand_help_has_examples() {
    for command in SUBCOMMANDS {
        let mut args: Vec<&str> = command.split(' ').collect();
        args.push("--help");
        let out = pipeline(&args);
        assert!(out.status.success(), "{command}: {}", stderr_of(&out));
        let help = String::from_utf8_lossy(&out.stdout);
        let examples =
            help.split("Examples:\n").nth(1).unwrap_or_else(|| panic!("no examples in {command} --help:\n{help}"));
        assert!(examples.contains(&format!("pipeline {command}")), "{command}'s examples:\n{examples}");
    }
}

fn tasks_json(args: &[&str]) -> Vec<serde_json::Value> {
    let out = pipeline(args);
    assert!(out.status.success(), "{args:?}: {}", stderr_of(&out));
    String::from_utf8_lossy(&out.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

/// `pipeline tasks` lists ALOHA-sim's two tasks (suite aloha_sim, from data/aloha) after LIBERO's,
/// seeded rather than with init states; `--suite aloha_sim` lists only them and needs no LIBERO
/// bundles.
#[test]
fn tasks_lists_aloha_sim_after_libero_and_alone_with_its_suite() {
    let rows = tasks_json(&["tasks", "--json"]);
    let first_aloha = rows.iter().position(|r| r["suite"] == "aloha_sim").expect("no aloha_sim rows (./setup.sh)");
    assert!(first_aloha >= 40 && rows[first_aloha..].iter().all(|r| r["suite"] == "aloha_sim"), "{rows:?}");
    let aloha = &rows[first_aloha..];
    assert_eq!(aloha.len(), 2, "{aloha:?}");
    assert_eq!((aloha[0]["task_id"].as_i64(), aloha[0]["name"].as_str()), (Some(0), Some("transfer_cube")));
    assert_eq!((aloha[1]["task_id"].as_i64(), aloha[1]["name"].as_str()), (Some(1), Some("insertion")));
    assert_eq!(aloha[0]["instruction"], "Transfer cube");
    assert!(aloha.iter().all(|r| r["init_states"].is_null() && r["seeded"] == true && r["first_seed"] == 1000));

    let missing_libero = ["--bundles", "/nonexistent/bundles"];
    let only = tasks_json(&[&["tasks", "--suite", "aloha_sim", "--json"][..], &missing_libero].concat());
    assert_eq!(only, aloha, "--suite aloha_sim lists the same two rows");

    let out = pipeline(&[&["tasks", "--suite", "aloha_sim"][..], &missing_libero].concat());
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", stderr_of(&out));
    let rows: Vec<&str> = table.lines().filter(|l| l.starts_with("aloha_sim ")).collect();
    assert_eq!(rows.len(), 2, "{table}");
    assert!(rows[0].contains("seeded") && rows[0].contains("Transfer cube"), "{table}");
    assert!(!table.contains("libero_"), "{table}");
}

/// Without the ALOHA-sim bundle, `pipeline tasks` still lists LIBERO's tasks and says in one line
/// how to build it; asked for by name, its absence is the error.
#[test]
fn a_missing_aloha_bundle_is_a_note_beside_libero_and_an_error_when_asked_for() {
    let out = pipeline(&["tasks", "--aloha-bundle", "/nonexistent/aloha"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", stderr_of(&out));
    assert!(text.contains("libero_spatial") && !text.contains("aloha_sim   "), "{text}");
    let note: Vec<&str> = text.lines().filter(|l| l.contains("/nonexistent/aloha")).collect();
    assert!(note.len() == 1 && note[0].contains("./setup.sh"), "{text}");

    let rows = tasks_json(&["tasks", "--json", "--aloha-bundle", "/nonexistent/aloha"]);
    assert!(rows.len() >= 40 && rows.iter().all(|r| r["suite"] != "aloha_sim"));

    let out = pipeline(&["tasks", "--suite", "aloha_sim", "--aloha-bundle", "/nonexistent/aloha"]);
    assert!(!out.status.success());
    assert!(
        stderr_of(&out).contains("/nonexistent/aloha") && stderr_of(&out).contains("./setup.sh"),
        "{}",
        stderr_of(&out)
    );
}

/// An unknown suite is refused with the valid names, ALOHA-sim's among them.
#[test]
fn an_unknown_suite_lists_aloha_sim_among_the_valid_names() {
    let out = pipeline(&["tasks", "--suite", "libero_nope"]);
    assert!(!out.status.success());
    let err = stderr_of(&out);
    assert!(err.contains("libero_nope") && err.contains("libero_spatial") && err.contains("aloha_sim"), "{err}");
}
