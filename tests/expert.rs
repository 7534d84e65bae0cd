//! The privileged scripted expert through the ordinary pipeline, on the real environment: the
//! positive control (the success detector fires when a task *is* done, and the grasp evidence is in
//! the stored steps), and real episodes where any-step and last-step scoring disagree.
//!
//! Kept small for CI (6 episodes); the full canonical protocol (50 trials × 40 tasks) is the
//! README's documented command.

use libero_e2e::{ok, pipeline, test_dir};
use std::path::{Path, PathBuf};

fn tmp(name: &str) -> PathBuf {
    test_dir("expert", name)
}

fn sql(run: &Path, query: &str, extra: &[&str]) -> Vec<Vec<String>> {
    libero_e2e::sql_rows(run, query, extra)
}

/// Specs for `suite` / `tasks` with `trials` per task, run with the expert into `dir/run`.
fn expert_run(dir: &Path, suite: &str, tasks: &str, trials: &str) -> PathBuf {
    let specs = dir.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", suite, "--tasks", tasks, "--trials", trials, "-o", s]));
    let run = dir.join("run");
    ok(pipeline(&["run", s, "--out", run.to_str().unwrap(), "--policy", "expert"]));
    run
}

#[test]
fn the_expert_solves_real_tasks_and_its_grasps_are_in_the_stored_steps() {
    let d = tmp("positive");
    // Bowl onto the plate (rim grasp) on libero_spatial; both solved on every init state measured.
    let run = expert_run(&d, "libero_spatial", "0,8", "2");
    let rows = sql(
        &run,
        "SELECT count(*), sum(CAST(success AS INT)), sum(CAST(error_kind IS NOT NULL AS INT)) FROM episodes",
        &[],
    );
    assert_eq!(rows[0], ["4", "4", "0"], "the expert must solve these episodes");
    // The evidence: the bowl touched the gripper, and was lifted, before the goal held.
    let rows = sql(
        &run,
        "SELECT s.episode_key, \
                min(CASE WHEN array_has(s.gripper_contacts, 'akita_black_bowl_1') THEN s.policy_step END) AS first_grasp, \
                min(e.first_success_step) AS first_success \
         FROM steps s JOIN episodes e ON e.episode_key = s.episode_key \
         GROUP BY s.episode_key ORDER BY s.episode_key",
        &[],
    );
    assert_eq!(rows.len(), 4);
    for r in &rows {
        let (grasp, success): (i64, i64) = (r[1].parse().unwrap(), r[2].parse().unwrap());
        assert!(grasp < success, "{}: grasped at {grasp}, succeeded at {success}", r[0]);
    }
    // The run records a privileged policy: nobody mistakes it for a learned one.
    let m = sql(&run, "SELECT policy, policy_identity FROM manifest", &[]);
    assert_eq!(m[0][0], "expert");
    assert!(m[0].join(",").contains("privileged"), "{m:?}");
    libero_e2e::assert_goal_evidence_matches_steps(&run, 90);
}

#[test]
fn real_expert_episodes_where_any_step_and_last_step_disagree() {
    let d = tmp("rescoring");
    // "Put the wine bottle on the rack": the expert sets it on the rack (the goal holds), and it
    // tips off after the release: an any-step success and a last-step failure.
    let run = expert_run(&d, "libero_goal", "9", "1");
    let r = run.to_str().unwrap();
    let q = "SELECT count(*), sum(CAST(scored_success AS INT)) FROM scored";
    assert_eq!(sql(&run, q, &[])[0], ["1", "1"], "any-step");
    assert_eq!(sql(&run, q, &["--success", "last-step"])[0], ["1", "0"], "last-step");
    // The stored evidence says the same: the goal held at some steps and not at the last one.
    let rows = sql(
        &run,
        "SELECT sum(CAST(goal AS INT)), max(policy_step), \
                bool_or(goal AND policy_step = (SELECT max(policy_step) FROM steps)) FROM steps",
        &[],
    );
    assert!(rows[0][0].parse::<i64>().unwrap() > 0, "{rows:?}");
    assert_eq!(rows[0][2], "false");
    // A cap before the first success turns it into a failure under either definition.
    let first: i64 = sql(&run, "SELECT first_success_step FROM episodes", &[])[0][0].parse().unwrap();
    let cap = (first - 1).to_string();
    assert_eq!(sql(&run, q, &["--cap", &cap])[0], ["1", "0"], "cap {cap}");
    // results.csv says which definition it used, from the same stored steps.
    for (success, expect) in [("any-step", "1"), ("last-step", "0")] {
        let out = d.join(success);
        ok(pipeline(&["results", "--run", r, "--success", success, "--out", out.to_str().unwrap()]));
        let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
        let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
        let row: Vec<&str> = csv.lines().nth(1).unwrap().split(',').collect();
        let col = |n: &str| row[header.iter().position(|h| *h == n).unwrap()];
        assert_eq!((col("success_definition"), col("n_success")), (success, expect));
    }
    // Its failure mode under last-step scoring says so; any-step has no failure to explain.
    let fm = sql(&run, "SELECT failure_mode, goal_progress FROM failure_modes", &["--success", "last-step"]);
    assert_eq!(fm, [["transient_success", "true"]]);
    assert!(sql(&run, "SELECT failure_mode FROM failure_modes", &[]).is_empty());
    // The rollout recorded which objects matter: the bottle and the rack that owns the region.
    let interest = sql(&run, "SELECT array_to_string(objects_of_interest, ' ') FROM episodes", &[]);
    assert_eq!(interest, [["wine_bottle_1 wine_rack_1"]]);
    // Re-scoring reads the episode's goal changes; they say what the steps say, for both
    // definitions and a cap between the first success and the last step.
    libero_e2e::assert_goal_evidence_matches_steps(&run, (first + 20) as u32);
}

/// The expert forced to let go early in its first carry (`--policy expert-drop`): a real drop, on
/// the real scene, which the failure analysis must call `dropped`, with the bowl as the object.
#[test]
fn a_forced_early_release_of_the_expert_is_a_dropped_failure() {
    let d = tmp("drop");
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", "1", "-o", s]));
    let run = d.join("run");
    ok(pipeline(&["run", s, "--out", run.to_str().unwrap(), "--policy", "expert-drop", "--max-steps", "120"]));
    let out = d.join("outputs");
    ok(pipeline(&["failures", "--run", run.to_str().unwrap(), "--out", out.to_str().unwrap()]));
    let rows = sql(
        &run,
        "SELECT failure_mode, fallen_object, interest_fall_m >= 0.03, interest_grasped, policy FROM failure_modes",
        &[],
    );
    assert_eq!(rows, [["dropped", "akita_black_bowl_1", "true", "true", "expert-drop"]]);
    let csv = std::fs::read_to_string(out.join("failure_modes.csv")).unwrap();
    assert!(csv.lines().nth(1).is_some_and(|l| l.contains(",dropped,")), "{csv}");

    // The selection query picks it (first failure of the suite, first `dropped`), and `videos`
    // renders it by replay under the selection's file name.
    let videos = d.join("failures");
    ok(pipeline(&["videos", "--run", run.to_str().unwrap(), "--out", videos.to_str().unwrap(), "--size", "128"]));
    let selection = std::fs::read_to_string(videos.join("selection.csv")).unwrap();
    let row = selection.lines().nth(1).unwrap_or_default();
    assert!(row.contains("first dropped") && row.contains("first failure"), "{selection}");
    assert!(row.ends_with("libero_spatial_task0_init0.mp4"), "{selection}");
    let mp4 = std::fs::metadata(videos.join("libero_spatial_task0_init0.mp4")).unwrap();
    assert!(mp4.len() > 10_000, "{} bytes", mp4.len());
}

/// `pipeline bench run --lengths`: the canonical protocol's wall time at the lengths of the
/// expert's real successes (`queries/protocol_projection.sql`), checked against the stored
/// episodes: each suite's mean success length (first success step + 1), its 500 episodes at
/// 97% success and the canonical cap otherwise, over the run's own policy steps per second. A
/// lengths run that lacks a suite's success projects no total and says which suite is missing.
#[test]
fn the_expert_lengths_project_the_canonical_protocol() {
    let dir = tmp("lengths");
    let specs = dir.join("specs.parquet");
    let s = specs.to_str().unwrap();
    let suites = "libero_spatial,libero_object,libero_goal,libero_10";
    // task 4 and 5 of each suite: the expert solves at least one of them in every suite
    ok(pipeline(&["specs", "--suites", suites, "--tasks", "4,5", "--trials", "1", "-o", s]));
    let run = dir.join("run");
    let r = run.to_str().unwrap();
    ok(pipeline(&["run", s, "--out", r, "--policy", "expert", "--stop-on-success", "--max-steps", "250"]));

    let out = ok(pipeline(&["bench", "run", "--run", r, "--no-rescoring", "--lengths", r, "--success-rate", "0.97"]));
    let rate: f64 = out
        .split(" policy steps/s\n")
        .next()
        .and_then(|head| head.rsplit(", ").next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no policy steps/s in:\n{out}"));
    let stored = sql(
        &run,
        "SELECT suite, SUM(CASE WHEN success THEN 1 ELSE 0 END), SUM(CASE WHEN success THEN first_success_step + 1 ELSE 0 END) FROM episodes GROUP BY suite",
        &[],
    );
    let caps = [("libero_spatial", 220.0), ("libero_object", 280.0), ("libero_goal", 300.0), ("libero_10", 520.0)];
    let mut total = 0.0;
    for (suite, cap) in caps {
        let s = stored.iter().find(|r| r[0] == suite).unwrap_or_else(|| panic!("{suite} not stored: {stored:?}"));
        let (successes, steps): (f64, f64) = (s[1].parse().unwrap(), s[2].parse().unwrap());
        assert!(successes >= 1.0, "the expert solved none of {suite}'s tasks 4 and 5: {stored:?}");
        let mean = steps / successes;
        let policy_steps = 500.0 * (0.97 * mean + 0.03 * cap);
        total += policy_steps;
        let printed = row_of(&out, suite);
        assert_eq!(printed[1], "2", "{suite}: 2 episodes\n{out}");
        assert_eq!(printed[2], format!("{successes}"), "{suite}\n{out}");
        assert_eq!(printed[3], format!("{mean:.1}"), "{suite}\n{out}");
        assert_eq!(printed[4], format!("{cap}"), "{suite}\n{out}");
        assert_eq!(printed[5], format!("{policy_steps:.0}"), "{suite}\n{out}");
    }
    let all = row_of(&out, "all four");
    assert_eq!(all[6], format!("{total:.0}"), "{out}");
    // the rate is printed to 0.1 step/s: the minutes from it agree to that rounding
    let minutes: f64 = all[7].parse().unwrap();
    let expected = total / rate / 60.0;
    assert!((minutes - expected).abs() <= 0.05 + expected * 1e-3, "{minutes} against {expected}\n{out}");

    // a lengths run of libero_spatial alone: no total, and the missing suites named
    let part = dir.join("spatial_only");
    for sub in ["episodes", "steps"] {
        std::fs::create_dir_all(part.join(sub)).unwrap();
        for entry in std::fs::read_dir(run.join(sub)).unwrap() {
            let path = entry.unwrap().path();
            if path.file_name().unwrap().to_string_lossy().contains("libero_spatial") {
                std::fs::copy(&path, part.join(sub).join(path.file_name().unwrap())).unwrap();
            }
        }
    }
    for f in ["manifest.json", "manifest.parquet", "specs.parquet"] {
        if run.join(f).exists() {
            std::fs::copy(run.join(f), part.join(f)).unwrap();
        }
    }
    let out = ok(pipeline(&["bench", "run", "--run", r, "--no-rescoring", "--lengths", part.to_str().unwrap()]));
    let all = row_of(&out, "all four");
    assert_eq!(all[6], "-", "no total without every suite:\n{out}");
    assert!(out.contains("no successful episode of libero_object, libero_goal, libero_10"), "{out}");

    let bad = pipeline(&["bench", "run", "--run", r, "--no-rescoring", "--lengths", r, "--success-rate", "97"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--success-rate 97 is not a rate"));
}

fn row_of(out: &str, label: &str) -> Vec<String> {
    let line = out.lines().find(|l| l.trim_start().starts_with(&format!("{label} "))).unwrap_or_else(|| {
        panic!("no row for {label} in:\n{out}");
    });
    line.split_whitespace().map(str::to_string).collect()
}
