//! LIBERO-Plus's displaced-object layouts (`(_moved)_level{L}_sample{s}`): each variant a bundle of
//! its own (`<suite>_plus_layout`, task id = the variant's id), built by
//! `scripts/reference/plus_layout.py` with the unchanged exporter. The set-up always builds the
//! tests' sample ([`TEST_PER_SUITE`] per suite, the variants `--per-category 1` picks) and records
//! reference episodes on it (`data/plus_layout_golden/`, golden.py's episodes at init state 0);
//! `./setup.sh --suites libero_plus_layout` builds the rest, and every layout bundle with reference
//! episodes is checked here.
//!
//! Checked: each bundle compiles to the reference's model, is a moved scene (its regions and init
//! state are not its base task's), steps as the reference for 80 steps (state within 1e-6, fixture
//! poses bit for bit, goal terms equal) and scores the reference's goal states as it does; the
//! spec rows point at the layout bundles (or the command names the set-up step that builds
//! them); the expert succeeds on them and the random baseline does not.

use libero_e2e::*;
use libero_schema::{BaseSuite, Suite};
use libero_sim::env::LiberoEnv;
use libero_sim::scene;
use std::path::PathBuf;

/// Layout bundles per suite the default set-up builds (keep equal to setup.sh PLUS_LAYOUT_TEST_PER_SUITE).
const TEST_PER_SUITE: usize = 1;
const STATE_TOLERANCE: f64 = 1e-6;
const MIN_STEPS: usize = 60;

fn layout_golden() -> PathBuf {
    let d = repo_root().join("data/plus_layout_golden");
    assert!(
        d.join(".complete").exists(),
        "no LIBERO-Plus layout reference episodes at {}: run ./setup.sh --tests (it builds the tests' sample of layout bundles)",
        d.display()
    );
    d
}

/// (suite, task id, folder) of every layout reference episode of `kind` (`init`, `goal_states`).
fn golden(kind: &str) -> Vec<(Suite, u32, PathBuf)> {
    let mut out: Vec<(Suite, u32, PathBuf)> = std::fs::read_dir(layout_golden())
        .unwrap()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let parts: Vec<&str> = name.split("__").collect();
            (parts.len() == 3 && parts[2].starts_with(kind))
                .then(|| (parts[0].parse().unwrap(), parts[1].parse().unwrap(), e.path()))
        })
        .collect();
    out.sort();
    out
}

fn npy(dir: &std::path::Path, name: &str) -> libero_sim::npy::Array2 {
    read_npy(&dir.join(format!("{name}.npy")))
}

#[test]
fn layout_bundles_are_moved_scenes_that_compile_to_the_reference_model() {
    let set = bundles();
    let layout: Vec<_> = set.tasks().iter().filter(|t| t.suite.ends_with("_plus_layout")).collect();
    for base in BaseSuite::CANONICAL {
        let n = layout.iter().filter(|t| t.suite == Suite::plus_layout(base).name()).count();
        assert!(n >= TEST_PER_SUITE, "{} has {n} layout bundles: run ./setup.sh --tests", Suite::plus_layout(base));
    }
    let mut levels = std::collections::BTreeSet::new();
    for t in &layout {
        let suite: Suite = t.suite.parse().unwrap();
        let bundle = set.load(suite, t.task_id).unwrap();
        let model = scene::compile(&bundle).unwrap();
        let diffs = scene::compare_with_reference(&model, &bundle.reference_model().unwrap());
        assert!(diffs.is_empty(), "{suite} task {}: {diffs:#?}", t.task_id);
        assert_eq!(bundle.init_states.rows, 1, "one init state per layout variant");
        assert_eq!(
            (bundle.task.base_suite.as_str(), bundle.task.perturbation.as_deref()),
            (suite.base.name(), Some("plus_layout"))
        );
        assert!(bundle.task.cameras.iter().any(|c| c == "agentview"));
        // its base task: the same goal and objects, but the regions (sites) and start moved
        let base_name = bundle.task.name.split("_level").next().unwrap();
        let base_name = base_name.strip_suffix("_moved").unwrap_or(base_name);
        let base = set.tasks().iter().find(|b| b.suite == suite.base.name() && b.name == base_name).unwrap();
        let base = set.load(Suite::base(suite.base), base.task_id).unwrap();
        assert_eq!(bundle.task.goal, base.task.goal, "{}", bundle.task.name);
        let sites = |b: &libero_sim::bundle::TaskBundle| {
            b.reference_model().unwrap().arrays["site_pos"].as_array().unwrap().clone()
        };
        assert_ne!(sites(&bundle), sites(&base), "{}: the regions did not move", bundle.task.name);
        let start = bundle.init_states.row(0);
        assert!(
            (0..base.init_states.rows).all(|i| base.init_states.row(i) != start),
            "{}: its init state is one of the base task's",
            bundle.task.name
        );
        let level = bundle.task.name.rsplit_once("_level").unwrap().1.split('_').next().unwrap().to_string();
        levels.insert(level);
    }
    println!("{} layout bundles, levels {levels:?}", layout.len());
}

/// golden.py's episode (10 wait steps, then smooth random motion with gripper toggles) from init
/// state 0 in the scene of the published loop's first reset after env.seed(0).
#[test]
fn layout_bundles_step_as_the_reference() {
    let episodes = golden("init");
    for base in BaseSuite::CANONICAL {
        let n = episodes.iter().filter(|(s, ..)| s.base == base).count();
        assert!(n >= TEST_PER_SUITE, "{base:?}: {n} layout reference episodes (./setup.sh records them)");
    }
    let set = bundles();
    let mut failures = Vec::new();
    let mut worst = 0.0f64;
    println!("suite task  steps  max|Δstate|  goal");
    for (suite, task_id, dir) in &episodes {
        let bundle = set.load(*suite, *task_id).unwrap_or_else(|e| panic!("{e} (./setup.sh builds it)"));
        let mut env = LiberoEnv::new(&bundle).unwrap();
        env.reset(0, 0).unwrap();
        let reference: std::collections::BTreeMap<String, libero_sim::bundle::Pose> =
            serde_json::from_str(&std::fs::read_to_string(dir.join("fixtures.json")).unwrap()).unwrap();
        let ours = env.fixture_poses().unwrap();
        for (body, pose) in &reference {
            if ours.get(body) != Some(pose) {
                failures
                    .push(format!("{suite} {task_id}: fixture {body} ours {:?} reference {pose:?}", ours.get(body)));
            }
        }
        let (actions, states, goal) = (npy(dir, "actions"), npy(dir, "states"), npy(dir, "goal"));
        assert!(actions.rows >= MIN_STEPS, "{suite} {task_id}: {} steps recorded", actions.rows);
        let (mut d_max, mut goal_diffs) = (0.0f64, 0);
        for t in 0..actions.rows {
            let out = env.step(actions.row(t).try_into().unwrap()).unwrap();
            let ours = env.state();
            let theirs = states.row(t);
            assert_eq!(ours[0], theirs[0], "time differs at step {t}");
            d_max = ours[1..].iter().zip(&theirs[1..]).map(|(a, b)| (a - b).abs()).fold(d_max, f64::max);
            let mut got = vec![out.goal.satisfied];
            got.extend(&out.goal.terms);
            let want: Vec<bool> = goal.row(t).iter().map(|&x| x == 1.0).collect();
            goal_diffs += (got != want) as usize;
        }
        println!(
            "  {suite} {task_id} {:>5} {d_max:>12.3e}  {}",
            actions.rows,
            if goal_diffs == 0 { "same" } else { "DIFF" }
        );
        worst = worst.max(d_max);
        if d_max > STATE_TOLERANCE || goal_diffs > 0 {
            failures.push(format!("{suite} {task_id}: max |Δ state| {d_max:e}, goal differs at {goal_diffs} steps"));
        }
    }
    println!("{} layout episodes, max |Δ state| {worst:e}", episodes.len());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// States where the reference's goal holds (objects placed, articulations set, settled): the
/// success check of a moved scene (its goal regions moved with it) must agree with the reference.
#[test]
fn the_success_check_agrees_with_the_reference_on_layout_goal_states() {
    let sets = golden("goal_states");
    assert!(sets.len() >= 4, "{} layout goal-state sets (./setup.sh records them)", sets.len());
    let set = bundles();
    let mut satisfied = 0;
    for (suite, task_id, dir) in &sets {
        let bundle = set.load(*suite, *task_id).unwrap();
        let mut env = LiberoEnv::new(&bundle).unwrap();
        let poses = bundle.fixture_poses(0, 0).unwrap().clone();
        let (states, goal) = (npy(dir, "states"), npy(dir, "goal"));
        for i in 0..states.rows {
            let g = env.reset_to(&poses, states.row(i)).unwrap();
            let mut got = vec![g.satisfied];
            got.extend(&g.terms);
            let want: Vec<bool> = goal.row(i).iter().map(|&x| x == 1.0).collect();
            assert_eq!(got, want, "{suite} {task_id} goal state {i}");
            satisfied += g.satisfied as usize;
        }
    }
    assert!(satisfied > 0, "no goal state satisfied the goal: the check was not exercised");
}

fn column_strings(batch: &arrow::array::RecordBatch, name: &str) -> Vec<Option<String>> {
    use arrow::array::{Array, AsArray};
    let c = arrow::compute::cast(batch.column_by_name(name).unwrap(), &arrow::datatypes::DataType::Utf8).unwrap();
    let c = c.as_string::<i32>();
    (0..c.len()).map(|i| c.is_valid(i).then(|| c.value(i).to_string())).collect()
}

fn read_specs(path: &std::path::Path) -> arrow::array::RecordBatch {
    let file = std::fs::File::open(path).unwrap();
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file).unwrap().build().unwrap();
    let batches: Vec<_> = reader.map(|b| b.unwrap()).collect();
    arrow::compute::concat_batches(&batches[0].schema(), &batches).unwrap()
}

#[test]
fn layout_specs_point_at_their_own_bundles_or_name_the_set_up_step() {
    let d = test_dir("plus_layout", "specs");
    let out = d.join("layout.parquet");
    let o = out.to_str().unwrap();
    let set = bundles();
    for mode in ["bddl", "official-filename"] {
        ok(pipeline(&[
            "specs",
            "--benchmark",
            "libero-plus",
            "--categories",
            "layout",
            "--per-category",
            &TEST_PER_SUITE.to_string(),
            "--base-trials",
            "0",
            "--instruction-mode",
            mode,
            "-o",
            o,
        ]));
        let b = read_specs(&out);
        assert_eq!(b.num_rows(), 4 * TEST_PER_SUITE);
        let col = |n: &str| column_strings(&b, n);
        let (suite, task, init, variant, variant_id) =
            (col("suite"), col("task_id"), col("init_state_id"), col("variant"), col("variant_id"));
        let (level, sample, text) = (col("layout_level"), col("layout_sample"), col("instruction_override"));
        for i in 0..b.num_rows() {
            let s: Suite = suite[i].as_deref().unwrap().parse().unwrap();
            assert_eq!(s.perturbation, Some(libero_schema::Perturbation::PlusLayout));
            assert_eq!(col("category")[i].as_deref(), Some("Layout"));
            assert_eq!(task[i], variant_id[i], "the layout bundle's task id is the variant's id");
            assert_eq!(init[i].as_deref(), Some("0"));
            let entry = set.entry(s, task[i].as_deref().unwrap().parse().unwrap()).unwrap();
            let name = variant[i].clone().unwrap();
            assert_eq!(entry.name, name);
            assert!(name.ends_with(&format!(
                "_level{}_sample{}",
                level[i].as_ref().unwrap(),
                sample[i].as_ref().unwrap()
            )));
            // the nominal view, rendered through LIBERO-Plus's rounding like every Plus row
            for (c, v) in [("camera_azimuth_deg", "0"), ("camera_distance_pct", "100"), ("camera_tilt_deg", "0")] {
                assert_eq!(col(c)[i].as_deref().map(|x| x.trim_end_matches(".0")), Some(v), "{c}");
            }
            let text = text[i].as_deref().unwrap();
            match mode {
                "bddl" => assert_eq!(text, entry.instructions.bddl),
                _ => assert!(
                    text.ends_with(&format!(
                        " level{} sample{}",
                        level[i].as_ref().unwrap(),
                        sample[i].as_ref().unwrap()
                    )),
                    "{text}"
                ),
            }
        }
    }
    // the layout suites are not LIBERO-Plus's --suites: the error says how to ask for them
    let wrong = pipeline(&["specs", "--benchmark", "libero-plus", "--suites", "libero_goal_plus_layout", "-o", o]);
    let err = String::from_utf8_lossy(&wrong.stderr);
    assert!(!wrong.status.success() && err.contains("--suites libero_goal --categories layout"), "{err}");
    // every Layout variant: the 696 when built, else an error that names the set-up step
    let all =
        pipeline(&["specs", "--benchmark", "libero-plus", "--categories", "layout", "--base-trials", "0", "-o", o]);
    let built = set.tasks().iter().filter(|t| t.suite.ends_with("_plus_layout")).count();
    if built == 696 {
        ok(all);
        assert_eq!(read_specs(&out).num_rows(), 696);
    } else {
        let err = String::from_utf8_lossy(&all.stderr);
        assert!(!all.status.success(), "{built} of 696 layout bundles built, yet the specs were written");
        assert!(err.contains("./setup.sh --suites libero_plus_layout") && err.contains("have no bundle"), "{err}");
    }
}

/// Positive and negative controls on the tests' layout variants: the privileged expert (which
/// reads the moved objects and regions) succeeds, the random baseline does not; layout does not
/// break the success check.
#[test]
fn the_expert_succeeds_on_layout_variants_and_random_does_not() {
    let d = test_dir("plus_layout", "controls");
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&[
        "specs",
        "--benchmark",
        "libero-plus",
        "--categories",
        "layout",
        "--per-category",
        &TEST_PER_SUITE.to_string(),
        "--base-trials",
        "0",
        "-o",
        s,
    ]));
    let mut rates = Vec::new();
    for policy in ["expert", "random"] {
        let run = d.join(policy);
        ok(pipeline(&["run", s, "--out", run.to_str().unwrap(), "--policy", policy]));
        let rows = sql_rows(&run, "SELECT count(*), sum(CAST(success AS INT)), count(error_kind) FROM episodes", &[]);
        let (n, wins, errors): (usize, usize, usize) =
            (rows[0][0].parse().unwrap(), rows[0][1].parse().unwrap(), rows[0][2].parse().unwrap());
        assert_eq!((n, errors), (4 * TEST_PER_SUITE, 0), "{policy}");
        println!("{policy}: {wins}/{n}");
        rates.push(wins);
    }
    assert!(rates[0] >= 2, "the expert succeeded on {} of {} layout variants", rates[0], 4 * TEST_PER_SUITE);
    assert_eq!(rates[1], 0, "the random baseline succeeded on a layout variant");
    // LIBERO-Plus's table scores them (no twin: its own scene and init state, so never paired);
    // LIBERO-PRO's does not take them for a PRO suite.
    let run = d.join("expert");
    let r = run.to_str().unwrap();
    ok(pipeline(&["generalisation", "--run", r, "--out", d.join("out").to_str().unwrap()]));
    let csv = std::fs::read_to_string(d.join("out/generalisation.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let at = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let layout: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|r| r[at("category")] == "Layout")
        .collect();
    assert_eq!(layout.len(), 4 + 1, "a row per suite and the pooled one:\n{csv}");
    for row in &layout {
        assert_eq!(row[at("paired")], "false", "{row:?}");
    }
    let all = layout.iter().find(|r| r[at("base_suite")] == "all").unwrap();
    assert_eq!(all[at("n_success")].parse::<usize>().unwrap(), rates[0]);
    let robustness = pipeline(&["robustness", "--run", r, "--out", d.join("out").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&robustness.stderr);
    assert!(!robustness.status.success() && err.contains("no LIBERO-PRO suite"), "{err}");
}
