//! `pipeline compact` on real runs: the same rows before and after (every column of both tables),
//! a kill at each stage of a compaction (and a SIGKILL at any moment) loses and duplicates nothing, a compacted run resumes and
//! re-scores, pyarrow/polars/duckdb read it as before, and a run being written is refused.

use libero_e2e::{ok, pipeline, pipeline_bin, repo_root, test_dir};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn sql_text(run: &Path, query: &str) -> String {
    ok(pipeline(&["sql", query, "--run", run.to_str().unwrap(), "--csv"]))
}

/// Every column of every row of both tables, in a fixed order: what compaction must keep.
fn contents(run: &Path) -> (String, String) {
    (
        sql_text(run, "SELECT * FROM steps ORDER BY episode_key, step"),
        sql_text(run, "SELECT * FROM episodes ORDER BY episode_key"),
    )
}

fn files(run: &Path, table: &str) -> usize {
    std::fs::read_dir(run.join(table)).unwrap().count()
}

fn specs(dir: &Path, tasks: &str, trials: &str) -> PathBuf {
    let spec = dir.join(format!("specs-{trials}.parquet"));
    ok(pipeline(&[
        "specs",
        "--suites",
        "libero_object",
        "--tasks",
        tasks,
        "--trials",
        trials,
        "-o",
        spec.to_str().unwrap(),
    ]));
    spec
}

fn compact_with_fault(run: &Path, fault: Option<&str>) -> std::process::Output {
    let mut cmd = Command::new(pipeline_bin());
    cmd.args(["compact", run.to_str().unwrap()]).current_dir(repo_root());
    if let Some(f) = fault {
        cmd.env("LIBERO_FAULT", f);
    }
    cmd.output().unwrap()
}

#[test]
fn compaction_keeps_every_row_survives_kills_and_the_run_still_resumes() {
    let d = test_dir("compaction", "kills");
    let spec = specs(&d, "0,1", "3");
    let run = d.join("run");
    let run_s = run.to_str().unwrap();
    ok(pipeline(&["run", spec.to_str().unwrap(), "--out", run_s, "--policy", "lift", "--max-steps", "8"]));
    let before = contents(&run);
    assert_eq!(files(&run, "steps"), 6);

    // Killed after staging (before the commit): nothing visible changed; the next compaction
    // starts over.
    let out = compact_with_fault(&run, Some("compact:staged"));
    assert!(!out.status.success(), "the fault hook did not stop it");
    assert_eq!(contents(&run), before);
    assert_eq!(files(&run, "steps"), 6);

    // Killed after the commit: the next command that opens the run finishes it.
    let out = compact_with_fault(&run, Some("compact:committed"));
    assert!(!out.status.success());
    assert_eq!(contents(&run), before, "rows lost or duplicated after a kill past the commit");
    assert_eq!((files(&run, "steps"), files(&run, "episodes")), (1, 1), "one file per table once finished");
    assert!(!run.join("staging").exists() || std::fs::read_dir(run.join("staging")).unwrap().count() == 0);

    // Idempotent: nothing left to compact.
    let again = ok(compact_with_fault(&run, None));
    assert!(again.contains("0 episodes"), "{again}");
    assert_eq!(contents(&run), before);

    // A compacted run re-scores and resumes: the 6 compacted episodes are not run again.
    ok(pipeline(&["results", "--run", run_s, "--success", "last-step", "--out", d.join("out").to_str().unwrap()]));
    let more = specs(&d, "0,1", "4");
    let out = pipeline(&["run", more.to_str().unwrap(), "--out", run_s, "--policy", "lift", "--max-steps", "8"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && err.contains("6 already finished, 2 to run"), "{err}");
    let counts = sql_text(&run, "SELECT count(*), count(DISTINCT episode_key) FROM episodes");
    assert_eq!(counts.lines().nth(1), Some("8,8"));
    let steps = sql_text(&run, "SELECT count(*) FROM steps");
    assert_eq!(steps.lines().nth(1), Some((8 * 18).to_string().as_str()));

    // The compacted run through the notebook tools, as before: polars and pyarrow, and duckdb.
    let script = format!(
        "import polars as pl, pyarrow.dataset as ds\n\
         e = pl.read_parquet('{r}/episodes/*.parquet'); s = pl.read_parquet('{r}/steps/*.parquet')\n\
         assert e.height == 8 and e['episode_key'].n_unique() == 8, e.height\n\
         assert s.height == 8 * 18, s.height\n\
         assert ds.dataset('{r}/episodes', format='parquet').count_rows() == 8\n\
         print('ok')",
        r = run_s
    );
    let py = Command::new(repo_root().join(".nb-venv/bin/python")).args(["-c", &script]).output().unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    let duck = format!(
        "import duckdb\nn = duckdb.sql(\"SELECT count(DISTINCT episode_key) FROM '{run_s}/episodes/*.parquet'\").fetchone()[0]\nassert n == 8, n"
    );
    let py = Command::new(repo_root().join(".venv/bin/python")).args(["-c", &duck]).output().unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
}

#[test]
fn compacting_a_run_that_is_being_written_is_refused() {
    let d = test_dir("compaction", "writer");
    let spec = specs(&d, "0,1,2", "4");
    let run = d.join("run");
    let mut child = Command::new(pipeline_bin())
        .args(["run", spec.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", "random"])
        .current_dir(repo_root())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !run.join("writer.json").exists() {
        assert!(t0.elapsed() < Duration::from_secs(120), "the run never started writing");
        assert!(child.try_wait().unwrap().is_none(), "the run ended before the check");
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = compact_with_fault(&run, None);
    child.kill().unwrap();
    child.wait().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("being written by `pipeline run`"), "{err}");
    // The killed run's lock names a process that is gone: compaction goes ahead.
    let out = ok(compact_with_fault(&run, None));
    assert!(out.contains("contents equal"), "{out}");
}

/// `pipeline run` compacts a run at its end once it has `--compact-at` one-episode parts (500 by
/// default); fewer stay as they are.
#[test]
fn a_run_compacts_itself_at_its_end_past_the_threshold() {
    let d = test_dir("compaction", "auto");
    let spec = specs(&d, "0", "3");
    for (at, expected_files) in [("3", 1), ("4", 3)] {
        let run = d.join(format!("run-{at}"));
        let out = pipeline(&[
            "run",
            spec.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--policy",
            "lift",
            "--max-steps",
            "4",
            "--compact-at",
            at,
        ]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert_eq!(files(&run, "episodes"), expected_files, "--compact-at {at}");
        let counts = sql_text(&run, "SELECT count(*), count(DISTINCT episode_key) FROM episodes");
        assert_eq!(counts.lines().nth(1), Some("3,3"));
    }
}

/// A real SIGKILL at increasing moments of a compaction (not only at the stage hooks): whatever
/// moment it lands, the next command sees every row once, and a later compaction finishes.
#[test]
fn sigkill_at_any_moment_of_a_compaction_loses_and_duplicates_nothing() {
    let d = test_dir("compaction", "sigkill");
    let spec = specs(&d, "0,1,2", "4");
    let run = d.join("run");
    ok(pipeline(&[
        "run",
        spec.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--policy",
        "lift",
        "--max-steps",
        "6",
    ]));
    let before = contents(&run);
    let mut killed = 0;
    for delay_ms in [5u64, 20, 40, 80, 160, 320] {
        let mut child = Command::new(pipeline_bin())
            .args(["compact", run.to_str().unwrap()])
            .current_dir(repo_root())
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(delay_ms));
        if child.try_wait().unwrap().is_none() {
            child.kill().unwrap(); // SIGKILL
            killed += 1;
        }
        child.wait().unwrap();
        assert_eq!(contents(&run), before, "after a SIGKILL {delay_ms} ms into a compaction");
    }
    assert!(killed > 0, "every compaction finished before its kill: nothing was tested");
    ok(compact_with_fault(&run, None));
    assert_eq!(contents(&run), before);
    assert_eq!(files(&run, "episodes"), 1);
}
