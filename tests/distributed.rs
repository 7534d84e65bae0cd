//! Runs and queries on an Apache Ballista cluster of separate processes on localhost: a
//! `pipeline scheduler` and `pipeline executor`s, as users start them.
//!
//! A run through the cluster equals the same run on the local engine (steps and episodes, apart
//! from wall times); a re-run has nothing left to do; `sql`, `results`, `failures` and `report`
//! give the local engine's answers; an executor SIGKILLed mid-run loses and duplicates nothing;
//! an executor whose bundles differ from the run's refuses its episodes; an unreachable
//! scheduler stops a command before anything starts.

use libero_e2e::{ok, pipeline, pipeline_bin, repo_root, test_dir};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A port free on localhost now.
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// A child process killed when dropped; its stderr goes to a log file.
struct Process {
    child: Child,
    log: PathBuf,
}

impl Process {
    fn start(args: &[&str], log: PathBuf, bundles: Option<&Path>) -> Process {
        let mut command = Command::new(pipeline_bin());
        command.args(args).current_dir(repo_root()).stdout(Stdio::null());
        command.stderr(std::fs::File::create(&log).unwrap());
        if let Some(b) = bundles {
            command.env("LIBERO_BUNDLES", b);
        }
        Process { child: command.spawn().unwrap(), log }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A scheduler and its executors (one slot each), killed when dropped.
struct Cluster {
    scheduler: Process,
    executors: Vec<Process>,
    port: u16,
}

impl Cluster {
    fn start(dir: &Path, executors: usize, bundles: Option<&Path>) -> Cluster {
        let port = free_port();
        let p = port.to_string();
        let scheduler = Process::start(
            &[
                "scheduler",
                "--bind",
                "127.0.0.1",
                "--port",
                &p,
                "--executor-timeout-s",
                "6",
                "--expire-interval-s",
                "1",
            ],
            dir.join("scheduler.log"),
            None,
        );
        let t0 = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(t0.elapsed() < Duration::from_secs(30), "the scheduler did not listen: {}", scheduler.log());
            std::thread::sleep(Duration::from_millis(100));
        }
        let executors = (0..executors)
            .map(|i| {
                let work = dir.join(format!("executor-{i}"));
                std::fs::create_dir_all(&work).unwrap();
                Process::start(
                    &[
                        "executor",
                        "--scheduler",
                        &format!("127.0.0.1:{port}"),
                        "--port",
                        &free_port().to_string(),
                        "--grpc-port",
                        &free_port().to_string(),
                        "--vcores",
                        "1",
                        "--heartbeat-s",
                        "1",
                        "--work-dir",
                        work.to_str().unwrap(),
                    ],
                    dir.join(format!("executor-{i}.log")),
                    bundles,
                )
            })
            .collect();
        Cluster { scheduler, executors, port }
    }

    fn engine(&self) -> String {
        format!("ballista://127.0.0.1:{}", self.port)
    }

    fn logs(&self) -> String {
        let mut text = format!("scheduler:\n{}", self.scheduler.log());
        for (i, e) in self.executors.iter().enumerate() {
            text += &format!("\nexecutor {i}:\n{}", e.log());
        }
        text
    }
}

/// `pipeline specs` for libero_spatial tasks 0 and 1, `trials` each.
fn specs(dir: &Path, trials: u32) -> PathBuf {
    let specs = dir.join("specs.parquet");
    let t = trials.to_string();
    ok(pipeline(&[
        "specs",
        "--suites",
        "libero_spatial",
        "--tasks",
        "0,1",
        "--trials",
        &t,
        "-o",
        specs.to_str().unwrap(),
    ]));
    specs
}

/// Every stored column of steps and episodes but the wall-time ones, as CSV, in key order.
fn stored_rows(run: &Path) -> (String, String) {
    let q = |sql: &str| ok(pipeline(&["sql", sql, "--run", run.to_str().unwrap(), "--csv"]));
    let steps = q(
        "SELECT * EXCLUDE (sim_ms, policy_ms, render_ms, queue_ms, prepare_ms, forward_ms) FROM steps ORDER BY episode_key, step",
    );
    let episodes =
        q("SELECT * EXCLUDE (wall_s, sim_s, policy_s, render_s, started_at) FROM episodes ORDER BY episode_key");
    (steps, episodes)
}

fn episode_part_names(run: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(run.join("episodes"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

const RUN: [&str; 4] = ["--policy", "random", "--max-steps", "8"];

#[test]
fn a_run_on_the_cluster_equals_the_local_run_and_its_queries_the_local_answers() {
    let d = test_dir("distributed", "equal");
    let specs = specs(&d, 3);
    let cluster = Cluster::start(&d, 2, None);
    let (local, remote) = (d.join("local"), d.join("cluster"));
    let run = |out: &Path, engine: &str| {
        let mut args = vec!["run", specs.to_str().unwrap(), "--out", out.to_str().unwrap(), "--engine", engine];
        args.extend(RUN);
        pipeline(&args)
    };
    ok(run(&local, "local"));
    let out = run(&remote, &cluster.engine());
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}\n{}", cluster.logs());
    assert!(stderr.contains("in 6 partitions"), "{stderr}");
    // both executors ran episodes of it (each logs the run once, when its checks pass)
    for (i, e) in cluster.executors.iter().enumerate() {
        assert!(e.log().contains("build, MuJoCo and bundles match"), "executor {i} ran nothing:\n{}", cluster.logs());
    }
    assert_eq!(episode_part_names(&remote), episode_part_names(&local));
    assert_eq!(episode_part_names(&remote).len(), 6);
    assert_eq!(stored_rows(&remote), stored_rows(&local), "the cluster's rows differ from the local engine's");
    // the pending files of the attempt are gone; a re-run has nothing to do
    assert!(
        std::fs::read_dir(remote.join("pending"))
            .map(|r| r.flatten().all(|e| std::fs::read_dir(e.path()).unwrap().next().is_none()))
            .unwrap_or(true)
    );
    let again = run(&remote, &cluster.engine());
    assert!(
        String::from_utf8_lossy(&again.stderr).contains("(6 already finished, 0 to run)"),
        "{}",
        String::from_utf8_lossy(&again.stderr)
    );

    // queries on the cluster: the local engine's answers
    let engine = cluster.engine();
    let r = remote.to_str().unwrap();
    for query in [
        "SELECT suite, count(*) AS n, sum(CAST(success AS INT)) AS s, wilson_lo(sum(CAST(success AS INT)), count(*)) AS lo FROM scored GROUP BY suite",
        "SELECT episode_key, n_policy_steps, goal_held_at(goal_changes, 3) FROM episodes ORDER BY episode_key",
        "SELECT count(*) FROM published WHERE benchmark = 'libero'",
        "SELECT count(*), max(step) FROM steps",
    ] {
        let on = |e: &str| ok(pipeline(&["sql", query, "--run", r, "--csv", "--engine", e]));
        assert_eq!(on(&engine), on("local"), "{query}");
    }
    for command in ["results", "failures", "report"] {
        let on = |e: &str, out: &Path| {
            let o = out.to_str().unwrap();
            let text = ok(pipeline(&[command, "--run", r, "--out", o, "--engine", e])).replace(o, "OUT");
            (
                text,
                std::fs::read_to_string(out.join(if command == "failures" {
                    "failure_summary.csv"
                } else {
                    "results.csv"
                }))
                .unwrap(),
            )
        };
        let (a, b) =
            (on(&engine, &d.join(format!("{command}-cluster"))), on("local", &d.join(format!("{command}-local"))));
        assert_eq!(a.1, b.1, "{command}: the CSVs differ");
        if command != "report" {
            assert_eq!(a.0, b.0, "{command}: the printed tables differ");
        }
    }
}

#[test]
fn an_executor_killed_mid_run_loses_and_duplicates_no_episode() {
    let d = test_dir("distributed", "kill");
    let specs = specs(&d, 4);
    let local = d.join("local");
    let mut args = vec!["run", specs.to_str().unwrap(), "--out", local.to_str().unwrap()];
    args.extend(RUN);
    ok(pipeline(&args));

    let mut cluster = Cluster::start(&d, 2, None);
    let remote = d.join("cluster");
    let engine = cluster.engine();
    let mut args = vec!["run", specs.to_str().unwrap(), "--out", remote.to_str().unwrap(), "--engine", &engine];
    args.extend(RUN);
    args.extend(["--test-episode-delay-ms", "1500"]);
    let log = d.join("client.log");
    let mut client = Command::new(pipeline_bin())
        .args(&args)
        .current_dir(repo_root())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    let parts = || std::fs::read_dir(remote.join("episodes")).map(|r| r.count()).unwrap_or(0);
    let t0 = Instant::now();
    while parts() < 2 {
        assert!(t0.elapsed() < Duration::from_secs(120), "no progress:\n{}", cluster.logs());
        assert!(
            client.try_wait().unwrap().is_none(),
            "the run ended early: {}",
            std::fs::read_to_string(&log).unwrap()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // SIGKILL one executor while both are mid-episode (each sleeps 1.5 s before its next one)
    cluster.executors[0].child.kill().unwrap();
    cluster.executors[0].child.wait().unwrap();
    let at_kill = parts();
    assert!(at_kill < 8, "the run finished before the kill");
    let status = loop {
        if let Some(s) = client.try_wait().unwrap() {
            break s;
        }
        assert!(t0.elapsed() < Duration::from_secs(300), "the run did not finish:\n{}", cluster.logs());
        std::thread::sleep(Duration::from_millis(200));
    };
    let client_log = std::fs::read_to_string(&log).unwrap();
    if !status.success() {
        // Ballista gave the job up: a re-run of the same command must finish it.
        eprintln!("the cluster's job failed after the kill; re-running:\n{client_log}");
        let mut args = vec!["run", specs.to_str().unwrap(), "--out", remote.to_str().unwrap(), "--engine", &engine];
        args.extend(RUN);
        ok(pipeline(&args));
    }
    eprintln!(
        "{at_kill} episodes stored at the kill; the run finished {}",
        if status.success() { "on the survivor" } else { "on a re-run" }
    );
    assert_eq!(episode_part_names(&remote), episode_part_names(&local), "episodes lost or added");
    assert_eq!(stored_rows(&remote), stored_rows(&local), "the rows differ from the local engine's");
    let counts = ok(pipeline(&[
        "sql",
        "SELECT count(*), count(DISTINCT episode_key) FROM episodes",
        "--run",
        remote.to_str().unwrap(),
        "--csv",
    ]));
    assert_eq!(counts.lines().nth(1), Some("8,8"), "{counts}");
}

#[test]
fn an_executor_whose_bundles_differ_refuses_the_run_and_nothing_is_written() {
    let d = test_dir("distributed", "refuse");
    let specs = specs(&d, 1);
    // the bundles, with task 0's provenance changed (as a rebuild from other sources would)
    let bundles = libero_e2e::bundles();
    let root = bundles.root().to_path_buf();
    let other = d.join("bundles");
    std::fs::create_dir_all(&other).unwrap();
    let task0 = bundles.tasks().iter().find(|t| t.suite == "libero_spatial" && t.task_id == 0).unwrap().path.clone();
    let top = Path::new(&task0).components().next().unwrap().as_os_str().to_owned();
    for e in std::fs::read_dir(&root).unwrap() {
        let e = e.unwrap();
        if e.file_name() != top {
            std::os::unix::fs::symlink(e.path(), other.join(e.file_name())).unwrap();
        }
    }
    // mirror the task's folder with links, but a changed provenance.json
    let mut from = root.join(&top);
    let mut to = other.join(&top);
    for part in Path::new(&task0).components().skip(1) {
        std::fs::create_dir_all(&to).unwrap();
        for e in std::fs::read_dir(&from).unwrap() {
            let e = e.unwrap();
            if e.file_name() != part.as_os_str() {
                std::os::unix::fs::symlink(e.path(), to.join(e.file_name())).unwrap();
            }
        }
        from = from.join(part);
        to = to.join(part);
    }
    std::fs::create_dir_all(&to).unwrap();
    for e in std::fs::read_dir(&from).unwrap() {
        let e = e.unwrap();
        if e.file_name() == "provenance.json" {
            let mut p: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(e.path()).unwrap()).unwrap();
            p["rebuilt_from"] = "another source".into();
            std::fs::write(to.join("provenance.json"), p.to_string()).unwrap();
        } else {
            std::os::unix::fs::symlink(e.path(), to.join(e.file_name())).unwrap();
        }
    }
    let cluster = Cluster::start(&d, 1, Some(&other));
    let remote = d.join("cluster");
    let mut args = vec!["run", specs.to_str().unwrap(), "--out", remote.to_str().unwrap(), "--engine"];
    let engine = cluster.engine();
    args.push(&engine);
    args.extend(RUN);
    let out = pipeline(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a run on an executor with other bundles went through");
    assert!(
        err.contains("refuses the episodes") && err.contains("bundles") && err.contains("hash"),
        "{err}\n{}",
        cluster.logs()
    );
    assert!(std::fs::read_dir(remote.join("episodes")).map(|r| r.count()).unwrap_or(0) == 0, "episodes were written");
}

#[test]
fn an_unreachable_scheduler_stops_a_command_before_anything_starts() {
    let d = test_dir("distributed", "unreachable");
    let specs = specs(&d, 1);
    let engine = format!("ballista://127.0.0.1:{}", free_port());
    let run = d.join("run");
    let mut args = vec!["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--engine", &engine];
    args.extend(RUN);
    let t0 = Instant::now();
    let out = pipeline(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("no Ballista scheduler answers") && err.contains("pipeline scheduler"), "{err}");
    assert!(t0.elapsed() < Duration::from_secs(30), "took {:?}", t0.elapsed());
    assert!(!run.join("manifest.json").exists(), "the run was started");
    let out = pipeline(&["results", "--run", run.to_str().unwrap(), "--engine", &engine]);
    assert!(!out.status.success());
    // a local folder with a scheduler elsewhere is refused (executors could not write to it)
    let far = "ballista://scheduler.invalid:50050";
    let mut args = vec!["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--engine", far];
    args.extend(RUN);
    let err = String::from_utf8_lossy(&pipeline(&args).stderr).into_owned();
    assert!(err.contains("no Ballista scheduler answers"), "{err}");
}
