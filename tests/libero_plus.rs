//! LIBERO-Plus perturbations against the reference code path on the same MuJoCo: camera viewpoints
//! (the compiled camera pose and the rendered frame) and robot init poses (the state over 70 steps),
//! recorded at set-up by `scripts/reference/plus_oracle.py` into `data/plus_golden/`; the hooks'
//! controls (an edit equal to the nominal value changes nothing; a perturbed episode leaves nothing
//! behind in a reused env); and the variant table and spec rows.

use libero_e2e::*;
use libero_sim::env::{EpisodeEdits, LiberoEnv};
use libero_sim::gl::GlContext;
use libero_sim::render::{Look, Orientation, RenderOptions};
use libero_sim::viewpoint::{self, ViewParams};
use std::path::PathBuf;
use std::rc::Rc;
use std::sync::Arc;

fn plus_golden() -> PathBuf {
    let d = repo_root().join("data/plus_golden");
    assert!(d.join(".complete").exists(), "no LIBERO-Plus reference episodes at {}: run ./setup.sh --tests", d.display());
    d
}

fn cases(prefix: &str) -> Vec<(String, serde_json::Value)> {
    let mut out: Vec<(String, serde_json::Value)> = std::fs::read_dir(plus_golden())
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(prefix))
        .map(|e| {
            let meta = std::fs::read_to_string(e.path().join("case.json")).unwrap();
            (e.file_name().to_string_lossy().into_owned(), serde_json::from_str(&meta).unwrap())
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    assert!(!out.is_empty(), "no {prefix}* cases in data/plus_golden");
    out
}

fn env_of(meta: &serde_json::Value) -> LiberoEnv {
    let suite = meta["suite"].as_str().unwrap().parse().unwrap();
    let bundle = bundles().load(suite, meta["task_id"].as_u64().unwrap() as u32).unwrap();
    LiberoEnv::new(&bundle).unwrap()
}

fn arr<const N: usize>(v: &serde_json::Value) -> [f64; N] {
    std::array::from_fn(|i| v[i].as_f64().unwrap())
}

#[test]
fn camera_viewpoints_compile_and_render_as_the_reference() {
    let gl = Rc::new(GlContext::new().unwrap());
    let mut worst_psnr = f64::INFINITY;
    for (name, meta) in cases("camera_") {
        let mut env = env_of(&meta);
        let v: [f64; 5] = arr(&meta["view"]);
        let view =
            ViewParams { azimuth_deg: v[0], elevation_deg: v[1], distance_pct: v[2], pan_deg: v[3], tilt_deg: v[4] };
        let problem = meta["problem"].as_str().unwrap();
        let pose = viewpoint::plus_agentview(viewpoint::nominal_agentview(problem).unwrap(), &view);
        env.set_episode_edits(EpisodeEdits { agentview: Some(pose), ..Default::default() }).unwrap();
        env.reset(0, 0).unwrap();
        let cam = env.model().name_to_id(mujoco_rs::prelude::MjtObj::mjOBJ_CAMERA, "agentview") as usize;
        let (pos, quat) = (env.model().cam_pos()[cam], env.model().cam_quat()[cam]);
        let (rpos, rquat): ([f64; 3], [f64; 4]) = (arr(&meta["cam_pos"]), arr(&meta["cam_quat"]));
        let dpos = pos.iter().zip(&rpos).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        let dquat = quat.iter().zip(&rquat).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        println!("{name}: cam_pos max |diff| {dpos:.1e}, cam_quat max |diff| {dquat:.1e}");
        assert!(
            dpos == 0.0 && dquat <= 2e-16,
            "{name}: compiled agentview {pos:?} {quat:?} vs reference {rpos:?} {rquat:?}"
        );

        let theirs = read_png(&plus_golden().join(&name).join("agentview.png"), Orientation::Reference);
        let mut renderer =
            env.renderer(gl.clone(), RenderOptions { look: Look::Mujoco337, ..Default::default() }).unwrap();
        let ours = env.render(&mut renderer, "agentview", theirs.width, theirs.height).unwrap();
        let psnr = ours.psnr(&theirs);
        println!("{name}: agentview PSNR {psnr:.1} dB against the reference env's frame");
        worst_psnr = worst_psnr.min(psnr);
        assert!(psnr >= 40.0, "{name}: agentview {psnr:.1} dB against the reference (need >= 40)");
        // The control: the nominal camera renders something else (the edit took effect).
        env.set_episode_edits(EpisodeEdits::default()).unwrap();
        env.reset(0, 0).unwrap();
        let nominal = env.render(&mut renderer, "agentview", theirs.width, theirs.height).unwrap();
        if view != ViewParams::NOMINAL {
            assert!(nominal.psnr(&theirs) < 30.0, "{name}: the nominal camera looks like the perturbed one");
        }
    }
    println!("worst camera-viewpoint PSNR: {worst_psnr:.1} dB");
}

#[test]
fn robot_init_poses_step_as_the_reference() {
    let mut worst = 0.0f64;
    for (name, meta) in cases("robot_") {
        let mut env = env_of(&meta);
        let q: [f64; 7] = arr(&meta["robot_init_qpos"]);
        env.set_episode_edits(EpisodeEdits { robot_init_qpos: Some(q), ..Default::default() }).unwrap();
        env.reset(0, 0).unwrap();
        let dir = plus_golden().join(&name);
        let actions = read_npy(&dir.join("actions.npy"));
        let states = read_npy(&dir.join("states.npy"));
        let mut max_diff = 0.0f64;
        let mut unperturbed_diff = 0.0f64;
        let mut base = env_of(&meta);
        base.reset(0, 0).unwrap();
        for t in 0..actions.rows {
            let a: [f64; 7] = actions.row(t).try_into().unwrap();
            env.step(a).unwrap();
            base.step(a).unwrap();
            let (ours, theirs) = (env.state(), states.row(t));
            let d = ours[1..].iter().zip(&theirs[1..]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            max_diff = max_diff.max(d);
            let d0 = base.state()[1..].iter().zip(&theirs[1..]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            unperturbed_diff = unperturbed_diff.max(d0);
        }
        println!(
            "{name}: qpos/qvel max |diff| {max_diff:.2e} over {} steps (unperturbed env: {unperturbed_diff:.2e})",
            actions.rows
        );
        assert!(max_diff <= 1e-6, "{name}: state differs from the reference by {max_diff:e} (limit 1e-6)");
        // The control: the perturbation is real (the unperturbed env ends elsewhere).
        assert!(unperturbed_diff > 1e-3, "{name}: the robot init pose changed nothing ({unperturbed_diff:e})");
        worst = worst.max(max_diff);
    }
    println!("worst robot-init state difference: {worst:.2e}");
}

#[test]
fn the_reset_time_kinematics_at_the_nominal_pose_are_the_bundles_snapshot() {
    let set = bundles();
    for (suite, task) in [("libero_spatial", 0), ("libero_object", 0), ("libero_10", 0)] {
        let bundle = set.load(suite.parse().unwrap(), task).unwrap();
        let mut env = LiberoEnv::new(&bundle).unwrap();
        let c = &bundle.task.controller;
        let q0: [f64; 7] = std::array::from_fn(|i| c.initial_joint[i]);
        let s = env.arm_state_at_rest(&q0);
        let snap = libero_sim::osc::ArmState::from_snapshot(c);
        let diff = (s.ee_pos - snap.ee_pos)
            .amax()
            .max((s.ee_ori - snap.ee_ori).amax())
            .max((s.j_pos - snap.j_pos).amax())
            .max((s.j_ori - snap.j_ori).amax())
            .max((s.mass - snap.mass).amax());
        println!("{suite}/{task}: reset-time cache computed at init_qpos vs recorded: max |diff| {diff:.1e}");

        assert_eq!(diff, 0.0, "{suite}/{task}: the cache at the nominal init_qpos is not the recorded one");
    }
}

/// An edit equal to the nominal value, and a perturbed episode before an unperturbed one on the
/// same env, leave the unperturbed episode bit for bit what it is on a fresh env.
#[test]
fn edits_are_undone_and_nominal_edits_change_nothing() {
    let set = bundles();
    let bundle = set.load("libero_spatial".parse().unwrap(), 0).unwrap();
    let q0: [f64; 7] = std::array::from_fn(|i| bundle.task.controller.initial_joint[i]);
    let actions: Vec<[f64; 7]> =
        (0..40).map(|t| [0.3 * ((t as f64) * 0.2).sin(), 0.2, -0.3, 0.0, 0.1, 0.0, 1.0]).collect();
    let run = |env: &mut LiberoEnv| -> Vec<f64> {
        env.reset(3, 7).unwrap();
        for a in &actions {
            env.step(*a).unwrap();
        }
        env.state()
    };
    let fresh = run(&mut LiberoEnv::new(&bundle).unwrap());
    let mut env = LiberoEnv::new(&bundle).unwrap();
    env.set_episode_edits(EpisodeEdits { robot_init_qpos: Some(q0), ..Default::default() }).unwrap();
    let nominal_q = run(&mut env);
    let q = [0.1, -0.2, 0.05, -2.3, 0.0, 2.1, 0.9];
    let view = ViewParams { azimuth_deg: 40.0, ..ViewParams::NOMINAL };
    let pose = viewpoint::plus_agentview(viewpoint::nominal_agentview("libero_tabletop_manipulation").unwrap(), &view);
    env.set_episode_edits(EpisodeEdits { robot_init_qpos: Some(q), agentview: Some(pose), ..Default::default() })
        .unwrap();
    let perturbed = run(&mut env);
    env.set_episode_edits(EpisodeEdits::default()).unwrap();
    let after = run(&mut env);
    let cam = env.model().name_to_id(mujoco_rs::prelude::MjtObj::mjOBJ_CAMERA, "agentview") as usize;
    let fresh_env = LiberoEnv::new(&bundle).unwrap();
    assert_eq!(env.model().cam_pos()[cam], fresh_env.model().cam_pos()[cam], "the camera edit was not undone");
    assert_eq!(nominal_q, fresh, "robot_init_qpos = the nominal init_qpos changed the episode");
    assert_eq!(after, fresh, "a perturbed episode left something behind in the reused env");
    assert_ne!(perturbed, fresh, "the robot init pose changed nothing");
    // out-of-range joint positions are refused by name
    let err = env.set_episode_edits(EpisodeEdits { robot_init_qpos: Some([0.0; 7]), ..Default::default() });
    assert!(err.unwrap_err().to_string().contains("robot_init_qpos[3]"));
}

/// `pipeline specs --benchmark libero-plus`: every offline variant, counted per category as the
/// authors classify them (Layout's 696 displaced-object variants when their bundles are built,
/// else a note that names the set-up step: `tests/plus_layout.rs`), and the categories that cannot
/// run here refused with the reason.
#[test]
fn plus_specs_hold_every_offline_variant_and_refuse_the_rest_with_the_reason() {
    let d = test_dir("plus", "specs");
    let all = d.join("all.parquet");
    let out = pipeline(&["specs", "--benchmark", "libero-plus", "--base-trials", "0", "-o", all.to_str().unwrap()]);
    let note = String::from_utf8_lossy(&out.stderr).into_owned();
    ok(out);
    let layout_built = bundles().tasks().iter().filter(|t| t.suite.ends_with("_plus_layout")).count() == 696;
    let file = std::fs::File::open(&all).unwrap();
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file).unwrap().build().unwrap();
    let mut counts: std::collections::BTreeMap<String, [usize; 3]> = Default::default();
    let mut names = std::collections::BTreeSet::new();
    for batch in reader {
        use arrow::array::{Array, AsArray};
        let b = batch.unwrap();
        let col = |n: &str| b.column_by_name(n).unwrap().clone();
        let (category, variant, qpos, noise) =
            (col("category"), col("variant"), col("robot_init_qpos"), col("sensor_noise"));
        for i in 0..b.num_rows() {
            let c = counts.entry(category.as_string::<i32>().value(i).to_string()).or_default();
            c[0] += 1;
            c[1] += qpos.is_valid(i) as usize;
            c[2] += noise.is_valid(i) as usize;
            names.insert(variant.as_string::<i32>().value(i).to_string());
        }
    }
    // perturbation-spec.md §D1: the authors' per-category counts over the four suites
    let mut want: std::collections::BTreeMap<String, [usize; 3]> =
        [("Camera", [1599, 0, 0]), ("Language", [1537, 0, 0]), ("Noise", [1601, 0, 1601]), ("Robot", [1550, 1550, 0])]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect();
    if layout_built {
        want.insert("Layout".into(), [696, 0, 0]);
    } else {
        assert!(note.contains("./setup.sh --suites libero_plus_layout"), "Layout left out without a word:\n{note}");
    }
    assert!(note.contains("added distractors (829)"), "{note}");
    assert_eq!(counts, want);
    assert_eq!(names.len(), if layout_built { 6983 } else { 6287 }, "variant names are not unique");
    for (category, reason) in [("light", "Hugging Face"), ("background", "Hugging Face")] {
        let out =
            pipeline(&["specs", "--benchmark", "libero-plus", "--categories", category, "-o", all.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(reason), "{category}: {err}");
    }
    let out =
        pipeline(&["specs", "--benchmark", "libero-plus", "--categories", "lighting", "-o", all.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("Camera, Robot, Language"));
}

/// The privileged expert reads the simulator state: a camera, noise or language variant is, for it,
/// its base episode (same task, init state 0, seed) step for step; a robot init pose is not. And
/// the generalisation table scores the run.
#[test]
fn the_expert_control_is_unmoved_by_what_it_does_not_see() {
    let d = test_dir("plus", "expert");
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&[
        "specs",
        "--benchmark",
        "libero-plus",
        "--suites",
        "libero_spatial",
        "--categories",
        "camera,robot,language,noise",
        "--per-category",
        "2",
        "--base-trials",
        "1",
        "-o",
        s,
    ]));
    let run = d.join("run");
    let r = run.to_str().unwrap();
    let refused = pipeline(&["run", s, "--out", r, "--policy", "expert", "--max-steps", "40"]);
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("--allow-unseen-perturbations"),
        "a blind policy on camera rows must be refused"
    );
    assert!(!run.join("episodes").exists(), "an episode ran before the refusal");
    ok(pipeline(&["run", s, "--out", r, "--policy", "expert", "--max-steps", "40", "--allow-unseen-perturbations"]));
    let again =
        pipeline(&["run", s, "--out", r, "--policy", "expert", "--max-steps", "40", "--allow-unseen-perturbations"]);
    let again = format!("{}{}", String::from_utf8_lossy(&again.stdout), String::from_utf8_lossy(&again.stderr));
    assert!(again.contains("18 already finished, 0 to run"), "the resume re-ran perturbed episodes:\n{again}");
    // per variant: the number of steps whose action or end-effector differs from the base episode's
    let q = "SELECT e.category, e.variant, count(*) FILTER (WHERE s.action <> b.action OR s.eef_pos <> b.eef_pos) \
             FROM episodes e JOIN steps s ON s.episode_key = e.episode_key \
             JOIN episodes eb ON eb.category IS NULL AND eb.task_id = e.task_id AND eb.init_state_id = e.init_state_id AND eb.seed = e.seed \
             JOIN steps b ON b.episode_key = eb.episode_key AND b.step = s.step \
             WHERE e.category IS NOT NULL GROUP BY 1, 2 ORDER BY 1, 2";
    let rows = sql_rows(&run, q, &[]);
    assert_eq!(rows.len(), 8, "{rows:?}");
    for row in &rows {
        let differing: u32 = row[2].parse().unwrap();
        match row[0].as_str() {
            "Robot" => assert!(differing > 0, "a robot init pose changed nothing: {row:?}"),
            _ => assert_eq!(differing, 0, "the expert's episode changed under a perturbation it cannot see: {row:?}"),
        }
    }
    // A replay re-applies the robot init pose: it must retrace the stored end effector (within
    // 1e-9 m, checked by `pipeline video`), and its file is the variant's own.
    let key =
        &sql_rows(&run, "SELECT episode_key FROM episodes WHERE category = 'Robot' ORDER BY 1 LIMIT 1", &[])[0][0];
    let videos = d.join("videos");
    let text = ok(pipeline(&["video", "--run", r, "--episode", key, "--out", videos.to_str().unwrap(), "--preview"]));
    let variant = key.rsplit_once("/v").unwrap().1;
    assert!(
        std::fs::read_dir(&videos)
            .unwrap()
            .flatten()
            .any(|e| e.file_name().to_string_lossy().ends_with(&format!("_v{variant}.mp4"))),
        "{text}"
    );
    let out = ok(pipeline(&["generalisation", "--run", r, "--out", d.join("out").to_str().unwrap()]));
    for c in ["Camera", "Robot", "Language", "Noise", "this run", "OpenVLA (published)"] {
        assert!(out.contains(c), "generalisation lacks {c}:\n{out}");
    }
    let csv = std::fs::read_to_string(d.join("out/generalisation.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 4 + 4, "{csv}");
    // Every variant is paired with its twin (the base row of its task at init state 0), so the
    // expert's drop under what it cannot see is exactly 0.
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |row: &[&str], name: &str| row[header.iter().position(|h| *h == name).unwrap()].to_string();
    for line in csv.lines().skip(1) {
        let row: Vec<&str> = line.split(',').collect();
        assert_eq!(col(&row, "paired"), "true", "{line}");
        if col(&row, "category") != "Robot" {
            assert_eq!(col(&row, "drop_from_base").parse::<f64>().unwrap(), 0.0, "{line}");
        }
    }
}

/// A spec file a user writes: perturbation columns on ordinary rows, run by a policy that sees.
/// Its actions follow what it sees (the camera and the noise change them, the instruction does
/// not reach this toy), a second run reproduces them bit for bit, and bad values stop the run
/// before any episode, naming the row.
#[test]
fn a_seeing_policy_gets_the_perturbed_images_deterministically() {
    use arrow::array::{ArrayRef, Float64Array, Int32Array, Int64Array, RecordBatch, StringArray};
    use tch::{CModule, Device, Kind, Tensor};
    let d = test_dir("plus", "seeing");
    let file = d.join("model.pt");
    let size = 64;
    let inputs = [
        Tensor::rand([1, 3, size, size], (Kind::Float, Device::Cpu)),
        Tensor::rand([1, 8], (Kind::Float, Device::Cpu)),
    ];
    // 0.05·mean(agentview) per component: the action follows the picture it is shown
    CModule::create_by_tracing("Toy", "forward", &inputs, &mut |x| {
        let mean = x[0].mean_dim([1i64, 2, 3].as_slice(), false, Kind::Float).unsqueeze(1);
        vec![(mean * 0.05 + x[1].narrow(1, 0, 7) * 0.0).unsqueeze(1)]
    })
    .unwrap()
    .save(&file)
    .unwrap();
    std::fs::write(
        d.join("model.json"),
        format!(r#"{{"inputs": ["agentview", "state"], "image_size": {size}, "preprocessing": "rot180", "chunk_size": 1, "replan_steps": 1}}"#),
    )
    .unwrap();
    let write_specs = |path: &std::path::Path, noise: i32| {
        let n = 4;
        let cols: Vec<(&str, ArrayRef)> = vec![
            ("suite", Arc::new(StringArray::from(vec!["libero_spatial"; n]))),
            ("task_id", Arc::new(Int32Array::from(vec![0; n]))),
            ("init_state_id", Arc::new(Int32Array::from(vec![0; n]))),
            ("seed", Arc::new(Int64Array::from(vec![7; n]))),
            ("camera_azimuth_deg", Arc::new(Float64Array::from(vec![None, Some(90.0), None, None]))),
            ("sensor_noise", Arc::new(Int32Array::from(vec![None, None, Some(noise), None]))),
            // `head`: glass blur at the toy's 64 px (the 2025 code needs 224 or more)
            ("sensor_noise_revision", Arc::new(StringArray::from(vec![None, None, Some("head"), None]))),
            ("instruction_override", Arc::new(StringArray::from(vec![None, None, None, Some("do the other thing")]))),
        ];
        let batch = RecordBatch::try_from_iter(cols).unwrap();
        let mut w =
            parquet::arrow::ArrowWriter::try_new(std::fs::File::create(path).unwrap(), batch.schema(), None).unwrap();
        w.write(&batch).unwrap();
        w.close().unwrap();
    };
    let specs = d.join("specs.parquet");
    write_specs(&specs, 45);
    let policy = format!("torchscript:{}", file.display());
    let actions = |run: &std::path::Path| -> Vec<Vec<String>> {
        ok(pipeline(&[
            "run",
            specs.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--policy",
            &policy,
            "--max-steps",
            "3",
        ]));
        sql_rows(
            run,
            "SELECT COALESCE(e.perturbation_params, 'none'), CAST(s.action[1] AS VARCHAR) FROM episodes e JOIN steps s \
             ON s.episode_key = e.episode_key WHERE s.policy_step = 0 ORDER BY e.episode_key",
            &[],
        )
    };
    let first = actions(&d.join("run1"));
    let second = actions(&d.join("run2"));
    assert_eq!(first, second, "the same spec rows gave other actions");
    let by = |needle: &str| {
        // the JSON's commas split the CSV row: match the whole row, the action is its last field
        let row = first.iter().find(|r| r.join(",").contains(needle)).unwrap_or_else(|| panic!("{needle}: {first:?}"));
        row.last().unwrap().clone()
    };
    let base = by("none");
    assert_ne!(by("azimuth_deg"), base, "the camera view did not reach the policy");
    assert_ne!(by("sensor_noise"), base, "the sensor noise did not reach the policy");
    assert_eq!(by("do the other thing"), base, "an instruction the toy ignores changed its action");
    let e = sql_rows(
        &d.join("run1"),
        "SELECT instruction, instruction_source FROM episodes WHERE perturbation_params LIKE '%other thing%'",
        &[],
    );
    assert_eq!(e, [["do the other thing", "spec"]]);
    // bad input: named, before any episode
    let bad = d.join("bad.parquet");
    write_specs(&bad, 51);
    let out = pipeline(&["run", bad.to_str().unwrap(), "--out", d.join("run3").to_str().unwrap(), "--policy", &policy]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("row 2") && err.contains("sensor_noise"), "{err}");
    assert!(!d.join("run3/episodes").exists());
}
