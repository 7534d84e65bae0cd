//! `pipeline run --processes N` on the real environment: the episodes dealt to N processes of the
//! binary store the rows one process stores, each process records its session, and a process
//! that dies mid-run costs only its unfinished episodes, named, which the same command resumes.

use libero_e2e::{ok, pipeline, pipeline_bin, repo_root, spatial_task0_specs, sql_rows, test_dir};
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
        let says =
            format!("[process {k}/2] 2 of the run's 4 episodes are this process's (0 already finished, 2 to run)");
        assert!(stderr.contains(&says), "{stderr}");
    }
    let rows = steps_of(&two);
    assert_eq!(rows.len(), 4 * (10 + 30), "4 episodes of 10 wait and 30 policy steps");
    assert_eq!(rows, steps_of(&one), "the same rows from two processes as from one");
    // each process ran its own two episodes, none twice
    let sessions: Vec<u64> = std::fs::read_dir(two.join("sessions"))
        .unwrap()
        .map(|f| {
            let record: serde_json::Value = serde_json::from_slice(&std::fs::read(f.unwrap().path()).unwrap()).unwrap();
            record["episodes"].as_u64().unwrap()
        })
        .collect();
    assert_eq!(sessions, [2, 2], "one session record per process, two episodes each");
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
    let specs = spatial_task0_specs(&dir, "4");
    let s = specs.to_str().unwrap();
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
        "6000",
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
    let mut victim: Option<u32> = None;
    loop {
        let line =
            lines.next().unwrap_or_else(|| panic!("process 1/2 never started its episodes:\n{}", seen.join("\n")));
        seen.push(line.clone());
        if let Some(rest) = line.strip_prefix("process 1/2: pid ") {
            victim = Some(rest.split(',').next().unwrap().trim().parse().unwrap());
        }
        // its episodes have begun, each with a 6 s sleep first: nothing of process 1 is stored yet
        if line.starts_with("[process 1/2] 2 of the run's 4 episodes") {
            break;
        }
    }
    let victim = victim.expect("the pid comes before the child's first line");
    std::thread::sleep(std::time::Duration::from_millis(500));
    assert!(Command::new("kill").args(["-9", &victim.to_string()]).status().unwrap().success());
    seen.extend(lines);
    let status = parent.wait().unwrap();
    let stderr = seen.join("\n");
    assert!(!status.success(), "{stderr}");
    assert!(stderr.contains("process 1/2 (expert) ended with signal: 9"), "{stderr}");
    assert!(stderr.contains("run the same command again to run them"), "{stderr}");
    let stored = sql_rows(&run, "SELECT init_state_id FROM episodes ORDER BY init_state_id", &[]);
    assert_eq!(stored, vec![vec!["0".to_string()], vec!["2".to_string()]], "process 0's rows 0 and 2 only\n{stderr}");

    // the resume deals what is left to both processes afresh
    let resumed = pipeline(&args[..args.len() - 2]);
    let err = String::from_utf8_lossy(&resumed.stderr);
    assert!(resumed.status.success(), "{err}");
    assert!(err.contains("(2 already finished, 2 to run)"), "{err}");
    for k in 0..2 {
        assert!(
            err.contains(&format!("process {k}/2: pid ")) && err.contains(&format!("[process {k}/2] 1 of the run's 4")),
            "{err}"
        );
    }
    assert_eq!(sql_rows(&run, "SELECT COUNT(*) FROM episodes", &[]), vec![vec!["4".to_string()]]);
}

/// A model policy's devices dealt out: each process runs its own replica on its device, the
/// episodes it stores are the run's policy (the manifest's, every device listed), not its share's,
/// and its session record says where its cameras rendered.
#[test]
fn each_process_serves_its_device_and_stores_the_runs_policy() {
    let dir = test_dir("processes", "devices");
    let specs = spatial_task0_specs(&dir, "4");
    let s = specs.to_str().unwrap();
    let python = repo_root().join(".lerobot-venv/bin/python");
    assert!(python.exists(), "no venv at {}: run ./setup.sh --tests", python.display());
    // a policy that sees both cameras, so each process renders
    let policy = format!("python:sees:make?python={}&batch=2&size=32&devices=cpu,cpu", python.display());
    let run = dir.join("run");
    let fixtures = repo_root().join("tests/fixtures/python_policies");
    let out = libero_e2e::pipeline_with_env(
        &["run", s, "--out", run.to_str().unwrap(), "--policy", &policy, "--max-steps", "8", "--processes", "2"],
        &[("PYTHONPATH", fixtures.to_str().unwrap())],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("manifest.json")).unwrap()).unwrap();
    let named = manifest["policy"].as_str().unwrap().to_string();
    assert!(named.contains("devices=cpu,cpu"), "{named}");
    let share = named.replace("devices=cpu,cpu", "devices=cpu");
    for k in 0..2 {
        let says = format!(
            "[process {k}/2] 2 of the run's 4 episodes are this process's (0 already finished, 2 to run); policy {share}"
        );
        assert!(stderr.contains(&says), "{stderr}");
    }
    // (the policy text has a comma: compared in SQL, not split out of CSV)
    let stored =
        sql_rows(&run, &format!("SELECT COUNT(DISTINCT policy), BOOL_AND(policy = '{named}') FROM episodes"), &[]);
    assert_eq!(stored, vec![vec!["1".to_string(), "true".to_string()]], "every episode under the run's policy");
    assert_eq!(
        sql_rows(&run, "SELECT COUNT(*) FROM episodes WHERE error_kind IS NULL", &[]),
        vec![vec!["4".to_string()]]
    );
    // each process records where its cameras rendered (the policy asks for images), and `bench run`
    // says it under each invocation; the parent, which renders nothing, writes no record
    let bench = pipeline(&["bench", "run", "--run", run.to_str().unwrap(), "--no-rescoring"]);
    let said = String::from_utf8_lossy(&bench.stdout);
    assert!(bench.status.success(), "{said}{}", String::from_utf8_lossy(&bench.stderr));
    let records: Vec<serde_json::Value> = std::fs::read_dir(run.join("sessions"))
        .unwrap()
        .map(|f| serde_json::from_slice(&std::fs::read(f.unwrap().path()).unwrap()).unwrap())
        .collect();
    assert_eq!(records.len(), 2, "a record per process");
    let shown: Vec<&str> = said.lines().filter(|l| l.trim_start().starts_with("cameras: ")).collect();
    assert_eq!(shown.len(), 2, "a line under each invocation: {said}");
    for record in &records {
        let devices = record["render_devices"].as_array().expect("render_devices");
        assert!(!devices.is_empty(), "{record}");
        assert_eq!(record["model_gpus"], serde_json::json!([]), "the model ran on the CPU: {record}");
        let vendor = devices[0]["vendor"].as_str().unwrap();
        let software = devices[0]["software"].as_bool().unwrap();
        assert!(
            shown.iter().any(|l| l.contains(vendor) && l.contains("software renderer on the CPU") == software),
            "{record} not in {shown:?}"
        );
    }
    let relayed = "cameras rendered on: ";
    assert_eq!(stderr.matches(relayed).count(), 2, "each process says where it rendered: {stderr}");
}
