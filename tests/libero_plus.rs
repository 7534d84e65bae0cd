//! LIBERO-Plus perturbations against the reference code path on the same MuJoCo: camera viewpoints
//! (the compiled camera pose and the rendered frame) and robot init poses (the state over 70 steps),
//! recorded at set-up by `scripts/reference/plus_oracle.py` into `data/plus_golden/`; the hooks'
//! controls (an edit equal to the nominal value changes nothing; a perturbed episode leaves nothing
//! behind in a reused env); and the variant table and spec rows.

mod support;

use libero_sim::env::{EpisodeEdits, LiberoEnv};
use libero_sim::gl::GlContext;
use libero_sim::render::{Look, Orientation, RenderOptions};
use libero_sim::viewpoint::{self, ViewParams};
use std::path::PathBuf;
use std::rc::Rc;
use support::*;

fn plus_golden() -> PathBuf {
    let d = repo_root().join("data/plus_golden");
    assert!(d.join(".complete").exists(), "no LIBERO-Plus reference episodes at {}: run ./setup.sh", d.display());
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
    env.set_episode_edits(EpisodeEdits { robot_init_qpos: Some(q), agentview: Some(pose) }).unwrap();
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
