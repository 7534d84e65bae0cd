//! `pipeline run --processes N` on the real environment: the episodes dealt to N processes of the
//! binary store the rows one process stores, each process records its session, and a process
//! that dies mid-run costs only its unfinished episodes, named, which the same command resumes.

use libero_e2e::{ok, pipeline, pipeline_bin, repo_root, sql_rows, test_dir};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

fn steps_of(run: &Path) -> Vec<Vec<String>> {
    sql_rows(run, "SELECT episode_key, step, action, eef_pos, goal FROM steps ORDER BY episode_key, step", &[])
}

#[test]
fn two_processes_store_what_one_does() {
    let dir = test_dir("processes", "equal");
    let specs = dir.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0,1", "--trials", "2", "-o", s]));
    let (one, two) = (dir.join("one"), dir.join("two"));
    let common = ["--policy", "expert", "--max-steps", "30", "--jobs", "2"];
    ok(pipeline(&[&["run", s, "--out", one.to_str().unwrap()][..], &common].concat()));
    let out = pipeline(&[&["run", s, "--out", two.to_str().unwrap(), "--processes", "2"][..], &common].concat());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    for k in 0..2 {
        assert!(stderr.contains(&format!("[process {k}/2] 2 of the run's 4 episodes are this process's")), "{stderr}");
    }
    let rows = steps_of(&two);
    assert_eq!(rows.len(), 4 * (10 + 30), "4 episodes of 10 wait and 30 policy steps");
    assert_eq!(rows, steps_of(&one), "the same rows from two processes as from one");
    assert_eq!(std::fs::read_dir(two.join("sessions")).unwrap().count(), 2, "one session record per process");
    // the parent prints the whole run's results, as a run of one process does
    assert!(String::from_utf8_lossy(&out.stdout).contains("libero_spatial"));
    // nothing left: a resume, with any number of processes, runs nothing
    let again = pipeline(&[&["run", s, "--out", two.to_str().unwrap(), "--processes", "3"][..], &common].concat());
    assert!(String::from_utf8_lossy(&again.stderr).contains("(4 already finished, 0 to run)"));

    let refused = pipeline(&[
        "run",
        s,
        "--out",
        dir.join("refused").to_str().unwrap(),
        "--processes",
        "3",
        "--policy",
        "openvla:/nonexistent?batch=4&devices=cpu,cpu",
    ]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && err.contains("lists 2") && err.contains("ask for 2 processes"), "{err}");
    assert!(!dir.join("refused").exists(), "refused before the run was made");
}

/// One process killed mid-run (as a lost GPU would end it): the parent waits for the other, stops
/// naming the dead one, keeps every episode the other stored, and the same command then runs only
/// what is missing.
#[test]
fn a_process_that_dies_costs_its_unfinished_episodes_and_the_run_resumes() {
    let dir = test_dir("processes", "dies");
    let specs = dir.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "4", "-o", s]));
    let run = dir.join("run");
    let r = run.to_str().unwrap();
    let args = [
        "run",
        s,
        "--out",
        r,
        "--policy",
        "expert",
        "--max-steps",
        "20",
        "--jobs",
        "2",
        "--processes",
        "2",
        "--test-episode-delay-ms",
        "4000",
    ];
    let mut parent = Command::new(pipeline_bin())
        .args(args)
        .current_dir(repo_root())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(parent.stderr.take().unwrap()).lines().map_while(Result::ok);
    let mut seen = Vec::new();
    let victim: u32 = loop {
        let line = lines.next().unwrap_or_else(|| panic!("no pid of process 1/2 in:\n{}", seen.join("\n")));
        seen.push(line.clone());
        if let Some(rest) = line.strip_prefix("process 1/2: pid ") {
            break rest.split(',').next().unwrap().trim().parse().unwrap();
        }
    };
    // within its first episode's delay: nothing of process 1 is stored yet
    std::thread::sleep(std::time::Duration::from_millis(1500));
    assert!(Command::new("kill").args(["-9", &victim.to_string()]).status().unwrap().success());
    seen.extend(lines);
    let status = parent.wait().unwrap();
    let stderr = seen.join("\n");
    assert!(!status.success(), "{stderr}");
    assert!(stderr.contains("process 1/2 (expert) ended with signal: 9"), "{stderr}");
    assert!(stderr.contains("Run the same command again to resume them"), "{stderr}");
    let stored = sql_rows(&run, "SELECT init_state_id FROM episodes ORDER BY init_state_id", &[]);
    assert_eq!(stored, vec![vec!["0".to_string()], vec!["2".to_string()]], "process 0's rows 0 and 2 only\n{stderr}");

    let resumed = pipeline(&args[..args.len() - 2]);
    let err = String::from_utf8_lossy(&resumed.stderr);
    assert!(resumed.status.success(), "{err}");
    assert!(err.contains("(2 already finished, 2 to run)"), "{err}");
    assert_eq!(sql_rows(&run, "SELECT COUNT(*) FROM episodes", &[]), vec![vec!["4".to_string()]]);
}
