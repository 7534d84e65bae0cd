//! Render parity: our camera frames against the reference env's, for the same sim state.
//!
//! `data/frames/mujoco-3.3.7/` holds frames the reference env rendered with the library we link
//! (task 0 of each suite, init states 0–2, the init state and the golden state after step 40; and
//! the LIBERO-PRO test tasks, init state 0, rendered by the PRO oracle venv);
//! `data/frames/mujoco-3.2.3/` holds frames the reference env rendered on the published stack's
//! MuJoCo (every task, init state 0). Both are 256 × 256 and hold, in `360/`, task 0 of each
//! suite at init state 0 rendered at lerobot-eval's 360 × 360 (its LIBERO env's camera size; what
//! `lerobot:` policies ask for), the same states' steps. All are made at set-up by
//! `scripts/reference/frames.py`.

use libero_e2e::{bundles, golden_dir, read_npy, read_png, repo_root};
use libero_sim::SimError;
use libero_sim::env::LiberoEnv;
use libero_sim::gl::GlContext;
use libero_sim::render::{Frame, Look, Orientation, Quality, RenderOptions};
use libero_udfs::policy_cameras::{AGENTVIEW, PolicyCameras, WRIST};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// The camera size lerobot-eval renders LIBERO at: lerobot 0.6.1's `LiberoEnv` config overrides
/// the env's 256 with 360 × 360 (`envs/configs.py`), and its policies ask the pipeline for that.
const LEROBOT_SIZE: u32 = 360;

/// One reference frame: `[<size>/]<suite>__<NN>__init<k>__s<SSS>__<camera>.png`.
struct ReferenceFrame {
    path: PathBuf,
    suite: String,
    task_id: u32,
    init: usize,
    step: usize,
    camera: String,
    /// Rendered at lerobot-eval's size (`LEROBOT_SIZE`, the frames in `360/`): ours are rendered as
    /// the pipeline renders a policy's cameras at that size. Otherwise the set-up's 256 × 256.
    lerobot_size: bool,
}

impl ReferenceFrame {
    fn name(&self) -> String {
        let stem = self.path.file_stem().unwrap().to_string_lossy().into_owned();
        if self.lerobot_size { format!("{LEROBOT_SIZE}/{stem}") } else { stem }
    }
}

/// The reference frames of `stack`: the set-up's 256 × 256 ones and those at lerobot-eval's size.
fn reference_frames(stack: &str) -> Vec<ReferenceFrame> {
    let dir = repo_root().join("data/frames").join(stack);
    assert!(dir.exists(), "no reference frames at {}: run ./setup.sh --tests", dir.display());
    let lerobot = dir.join(LEROBOT_SIZE.to_string());
    assert!(
        lerobot.exists(),
        "no {LEROBOT_SIZE} x {LEROBOT_SIZE} reference frames at {}: run ./setup.sh --tests",
        lerobot.display()
    );
    let mut out = frames_in(&dir, false);
    out.extend(frames_in(&lerobot, true));
    out
}

fn frames_in(dir: &Path, lerobot_size: bool) -> Vec<ReferenceFrame> {
    let mut out: Vec<ReferenceFrame> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| {
            let path = e.unwrap().path();
            let name = path.file_stem()?.to_str()?.to_string();
            if path.extension()? != "png" {
                return None;
            }
            let parts: Vec<&str> = name.split("__").collect();
            let [suite, task, init, step, camera] = parts[..] else { panic!("unexpected frame name {name}") };
            Some(ReferenceFrame {
                suite: suite.into(),
                task_id: task.parse().unwrap(),
                init: init.trim_start_matches("init").parse().unwrap(),
                step: step.trim_start_matches('s').parse().unwrap(),
                camera: camera.into(),
                path,
                lerobot_size,
            })
        })
        .collect();
    out.sort_by(|a, b| a.path.cmp(&b.path));
    assert!(!out.is_empty(), "no frames in {}", dir.display());
    out
}

/// One frame compared: its name, PSNR, largest absolute difference of a channel, our mean
/// brightness and the reference's.
#[derive(Debug)]
struct Compared {
    name: String,
    psnr: f64,
    max_diff: u8,
    ours: f64,
    theirs: f64,
}

/// Render every reference frame's state with `look`, tasks compiled once each. The 256 × 256
/// frames through a renderer with the scene's own offscreen buffer (as the reference's); those at
/// lerobot-eval's 360 × 360 as the pipeline renders a policy's cameras at that size: in the
/// default look through `PolicyCameras` itself (a 360 × 360 buffer, on a rollout worker's GL
/// thread), in another look with its options.
fn render_like(frames: &[ReferenceFrame], look: Look) -> Vec<Compared> {
    let set = bundles();
    let gl = Rc::new(GlContext::new().unwrap());
    let mut by_task: BTreeMap<(String, u32), Vec<&ReferenceFrame>> = BTreeMap::new();
    for f in frames {
        by_task.entry((f.suite.clone(), f.task_id)).or_default().push(f);
    }
    let mut out = Vec::new();
    let mut lerobot_time = std::time::Duration::ZERO;
    for ((suite, task_id), frames) in by_task {
        let bundle = set.load(suite.parse().unwrap(), task_id).unwrap();
        let mut env = LiberoEnv::new(&bundle).unwrap();
        // A renderer of the other look first: a look must not leak into the next renderer.
        let other = if look == Look::Mujoco323 { Look::Mujoco337 } else { Look::Mujoco323 };
        drop(env.renderer(gl.clone(), RenderOptions { look: other, ..Default::default() }).unwrap());
        let mut renderer = env.renderer(gl.clone(), RenderOptions { look, ..Default::default() }).unwrap();
        let mut at_lerobot_size = None;
        let mut policy_cameras = None;
        let mut captured = None;
        for f in frames {
            let theirs = read_png(&f.path, Orientation::Reference);
            let poses = bundle.fixture_poses(0, f.init).unwrap().clone();
            let state = if f.step == 0 {
                bundle.init_state(f.init).unwrap().to_vec()
            } else {
                let dir = golden_dir().join(format!("{suite}__{task_id:02}__init{}", f.init));
                read_npy(&dir.join("states.npy")).row(f.step - 1).to_vec()
            };
            env.reset_to(&poses, &state).unwrap();
            let start = std::time::Instant::now();
            let ours = if !f.lerobot_size {
                env.render(&mut renderer, &f.camera, theirs.width, theirs.height).unwrap()
            } else if look == Look::Mujoco323 {
                // `PolicyCameras`' look; both cameras of a state in one capture, as an episode's step takes them
                let at = (f.init, f.step);
                if captured.as_ref().is_none_or(|(state, _)| *state != at) {
                    let cameras =
                        policy_cameras.get_or_insert_with(|| PolicyCameras::new(&mut env, LEROBOT_SIZE).unwrap());
                    captured = Some((at, cameras.capture(&mut env, true).unwrap()));
                }
                let images = &captured.as_ref().unwrap().1;
                let image = match f.camera.as_str() {
                    AGENTVIEW => &images.agentview,
                    WRIST => &images.wrist,
                    other => panic!("a policy camera {other}"),
                };
                let (width, height, rgb) = (image.width, image.height, image.rgb.clone());
                Frame { width, height, rgb, orientation: Orientation::Reference }
            } else {
                let options = RenderOptions {
                    look,
                    quality: Quality::Reference,
                    max_width: LEROBOT_SIZE,
                    max_height: LEROBOT_SIZE,
                };
                let r = at_lerobot_size.get_or_insert_with(|| env.renderer(gl.clone(), options).unwrap());
                env.render(r, &f.camera, LEROBOT_SIZE, LEROBOT_SIZE).unwrap()
            };
            if f.lerobot_size {
                lerobot_time += start.elapsed();
            }
            assert_eq!((ours.width, ours.height), (theirs.width, theirs.height), "{}", f.name());
            let max_diff = ours.rgb.iter().zip(&theirs.rgb).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
            let (psnr, ours, theirs) = (ours.psnr(&theirs), ours.mean_brightness(), theirs.mean_brightness());
            out.push(Compared { name: f.name(), psnr, max_diff, ours, theirs });
        }
    }
    println!("rendering at {LEROBOT_SIZE} x {LEROBOT_SIZE} (renderers made, frames drawn): {lerobot_time:.2?}");
    for c in &out {
        println!(
            "{:<64} PSNR {:>6.1} dB   max diff {:>3}   brightness ours {:>6.1} reference {:>6.1}",
            c.name, c.psnr, c.max_diff, c.ours, c.theirs
        );
    }
    out
}

/// The frames at lerobot-eval's size, after checking that there are `n` of them, task 0 of each
/// canonical suite: prints their figures.
fn at_lerobot_size(results: &[Compared], n: usize) -> Vec<&Compared> {
    let at: Vec<&Compared> = results.iter().filter(|c| c.name.starts_with(&format!("{LEROBOT_SIZE}/"))).collect();
    assert_eq!(at.len(), n, "frames at {LEROBOT_SIZE} x {LEROBOT_SIZE} (./setup.sh --tests renders them)");
    for camera in [AGENTVIEW, WRIST] {
        let of: Vec<_> = at.iter().filter(|c| c.name.ends_with(camera)).collect();
        assert_eq!(of.len(), n / 2, "{camera} frames at {LEROBOT_SIZE}");
        for suite in ["libero_spatial", "libero_object", "libero_goal", "libero_10"] {
            assert!(
                of.iter().any(|c| c.name.contains(&format!("/{suite}__00__"))),
                "no {suite} {camera} at {LEROBOT_SIZE}"
            );
        }
    }
    let worst = at.iter().map(|c| c.psnr).fold(f64::INFINITY, f64::min);
    let max_diff = at.iter().map(|c| c.max_diff).max().unwrap();
    let identical = at.iter().filter(|c| c.psnr.is_infinite()).count();
    println!(
        "at {LEROBOT_SIZE} x {LEROBOT_SIZE}: {identical} of {n} frames identical, worst PSNR {worst:.1} dB, largest difference {max_diff}"
    );
    at
}

#[test]
fn frames_match_the_reference_env_on_the_linked_mujoco() {
    let frames = reference_frames("mujoco-3.3.7");
    // LIBERO-PRO's suites too: one task each (its new objects' meshes and textures included),
    // rendered by the PRO oracle venv on the same MuJoCo.
    for (suite, task) in libero_e2e::PRO_TEST_TASKS {
        let n = frames.iter().filter(|f| f.suite == suite && f.task_id == task).count();
        assert_eq!(n, 4, "{suite} task {task}: 2 cameras x steps 0 and 40 (./setup.sh renders them)");
    }
    let results = render_like(&frames, Look::Mujoco337);
    let identical = results.iter().filter(|r| r.psnr.is_infinite()).count();
    println!("{identical} of {} frames identical to the reference", results.len());
    // at lerobot-eval's 360 x 360: task 0 of each suite, init state 0, steps 0 and 40, both cameras
    at_lerobot_size(&results, 16);
    let bad: Vec<_> = results.iter().filter(|r| r.psnr < 40.0).collect();
    assert!(bad.is_empty(), "frames below 40 dB against the reference (same MuJoCo): {bad:?}");
}

#[test]
fn the_default_look_is_the_published_stacks_on_every_task() {
    assert_eq!(Look::default(), Look::Mujoco323);
    let frames = reference_frames("mujoco-3.2.3");
    let results = render_like(&frames, Look::default());
    let worst = results.iter().map(|r| r.psnr).fold(f64::INFINITY, f64::min);
    println!("worst PSNR against MuJoCo 3.2.3 frames: {worst:.1} dB over {} frames", results.len());
    // at lerobot-eval's 360 x 360, through the pipeline's `PolicyCameras`: task 0 of each suite,
    // init state 0, both cameras
    at_lerobot_size(&results, 8);
    let bad: Vec<_> = results.iter().filter(|r| r.psnr < 40.0).collect();
    assert!(bad.is_empty(), "frames below 40 dB against the published stack (MuJoCo 3.2.3): {bad:?}");
    // The control: without the look, libero_object is visibly darker than the published frames.
    let object: Vec<ReferenceFrame> =
        frames.into_iter().filter(|f| f.suite == "libero_object" && f.camera == AGENTVIEW && !f.lerobot_size).collect();
    let raw = render_like(&object, Look::Mujoco337);
    let darker = raw.iter().filter(|r| r.psnr < 30.0 && r.ours < r.theirs - 10.0).count();
    assert!(darker > raw.len() / 2, "MuJoCo 3.3.7's own look should differ on libero_object: {raw:?}");
}

#[test]
fn an_unknown_camera_lists_the_scene_cameras() {
    let bundle = bundles().load("libero_spatial".parse().unwrap(), 0).unwrap();
    let mut env = LiberoEnv::new(&bundle).unwrap();
    env.reset(0, 0).unwrap();
    let gl = Rc::new(GlContext::new().unwrap());
    let mut renderer = env.renderer(gl, RenderOptions::default()).unwrap();
    let err = env.render(&mut renderer, "wrist", 64, 64).unwrap_err();
    assert!(matches!(err, SimError::UnknownCamera { .. }), "{err}");
    let msg = err.to_string();
    assert!(msg.contains("agentview") && msg.contains("robot0_eye_in_hand"), "{msg}");
    // A frame larger than the offscreen buffer is refused with the fix named.
    let err = env.render(&mut renderer, "agentview", 4096, 4096).unwrap_err().to_string();
    assert!(err.contains("max_width"), "{err}");
}

/// Several workers rendering through one shared GL thread (as a run's workers do on a GPU,
/// `libero_sim::gl_thread`) get, bit for bit, the frames each gets on a GL context of its own:
/// three threads, three suites' scenes (other textures and meshes, so three uploads and three
/// buffers) on the one context, renders interleaved.
#[test]
fn workers_sharing_one_gl_thread_get_the_frames_of_a_context_each() {
    use libero_sim::gl_thread::{GlThread, OnGlThread};
    let set = bundles();
    let shared = GlThread::start(libero_sim::gl::next_device().unwrap().as_ref()).unwrap();
    // per worker: its frames through the shared thread, and on a context of its own
    type Frames = Vec<Vec<u8>>;
    let frames: Vec<(Frames, Frames)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..3u32)
            .map(|task| {
                let (set, shared) = (&set, shared.clone());
                scope.spawn(move || {
                    let suite = ["libero_goal", "libero_object", "libero_spatial"][task as usize];
                    let bundle = set.load(suite.parse().unwrap(), task).unwrap();
                    let mut env = LiberoEnv::new(&bundle).unwrap();
                    env.reset(task as usize, 0).unwrap();
                    let options = RenderOptions { max_width: 128, max_height: 128, ..Default::default() };
                    let pair = |env: &mut LiberoEnv, r: &mut libero_sim::render::SceneRenderer| {
                        ["agentview", "robot0_eye_in_hand"].map(|c| env.render(r, c, 128, 128).unwrap().rgb).to_vec()
                    };
                    let mut through_shared = Vec::new();
                    // SAFETY: env and renderer are used on the GL thread while this thread waits.
                    let mut renderer =
                        unsafe { OnGlThread::make(shared, |gl| env.renderer(gl.clone(), options)) }.unwrap();
                    for _ in 0..3 {
                        through_shared.extend(unsafe { renderer.with(|r| pair(&mut env, r)) });
                        env.step([0.2, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]).unwrap();
                    }
                    drop(renderer);
                    env.reset(task as usize, 0).unwrap();
                    let gl = Rc::new(GlContext::new().unwrap());
                    let mut renderer = env.renderer(gl, options).unwrap();
                    let mut own = Vec::new();
                    for _ in 0..3 {
                        own.extend(pair(&mut env, &mut renderer));
                        env.step([0.2, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]).unwrap();
                    }
                    (through_shared, own)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for (task, (through_shared, own)) in frames.iter().enumerate() {
        assert_eq!(through_shared.len(), 6);
        for (i, (a, b)) in through_shared.iter().zip(own).enumerate() {
            let n = a.iter().zip(b).filter(|(x, y)| x != y).count();
            assert!(n == 0, "task {task}, frame {i}: {n} of {} bytes differ from a context's own frame", a.len());
        }
    }
    // and the scenes differ: a frame of one task is not another's
    assert!(frames[0].0[0] != frames[1].0[0]);
}

/// Renderers of one scene on one GL context share its upload (`SceneRenderer::shares_upload_with`:
/// as the workers of one task do on a GPU's shared GL thread), and each draws, bit for bit, what a
/// renderer with an upload of its own draws: two envs of one task, the second with an episode's
/// edits (lights, an object's colour, the camera pose), their renders interleaved with each other's
/// and another scene's, and the edited one going on alone once the renderer that uploaded the scene
/// is dropped. Another suite's scene (other meshes and textures), another buffer size or another
/// look gets an upload of its own; a renderer never reads back what another one drew.
#[test]
fn renderers_of_one_scene_share_its_upload_and_draw_what_their_own_upload_draws() {
    use libero_sim::env::{Appearance, EpisodeEdits, Lighting};
    use libero_sim::viewpoint::CameraPose;
    let set = bundles();
    let bundle = set.load("libero_spatial".parse().unwrap(), 1).unwrap();
    let other = set.load("libero_object".parse().unwrap(), 0).unwrap();
    let options = RenderOptions { max_width: 128, max_height: 128, ..Default::default() };
    let pair = |env: &mut LiberoEnv, r: &mut libero_sim::render::SceneRenderer| {
        ["agentview", "robot0_eye_in_hand"].map(|c| env.render(r, c, 128, 128).unwrap().rgb)
    };
    let envs = || {
        let (mut plain, mut edited) = (LiberoEnv::new(&bundle).unwrap(), LiberoEnv::new(&bundle).unwrap());
        let object = edited.object_names().next().expect("a scene with objects").to_string();
        edited
            .set_episode_edits(EpisodeEdits {
                lighting: Some(Lighting { ambient: Some(0.6), diffuse: Some(0.3), specular: Some(0.1) }),
                appearance: Some(Appearance { objects: vec![object], rgba: [0.9, 0.1, 0.1, 1.0] }),
                agentview: Some(CameraPose { pos: [0.9, 0.1, 1.5], quat: [0.65, 0.28, 0.28, 0.65] }),
                ..Default::default()
            })
            .unwrap();
        plain.reset(0, 0).unwrap();
        edited.reset(3, 0).unwrap();
        [plain, edited]
    };
    let step = |env: &mut LiberoEnv| env.step([0.3, 0.0, 0.1, 0.0, 0.0, 0.0, -1.0]).unwrap();
    // one GL context, both renderers on it, renders interleaved
    let gl = Rc::new(GlContext::new().unwrap());
    let [mut plain, mut edited] = envs();
    let mut r_plain = plain.renderer(gl.clone(), options).unwrap();
    let mut r_edited = edited.renderer(gl.clone(), options).unwrap();
    assert!(r_plain.shares_upload_with(&r_edited), "renderers of one scene on one GL context uploaded it twice");
    let mut env_other = LiberoEnv::new(&other).unwrap();
    env_other.reset(0, 0).unwrap();
    let mut r_other = env_other.renderer(gl.clone(), options).unwrap();
    assert!(!r_other.shares_upload_with(&r_plain), "another suite's scene shared this one's upload");
    let look = RenderOptions { look: Look::Mujoco337, ..options };
    let r_look = LiberoEnv::new(&other).unwrap().renderer(gl.clone(), look).unwrap();
    assert!(!r_look.shares_upload_with(&r_other), "another look shared this one's upload");
    // (LIBERO's scenes make a 640x480 buffer; a renderer asking for less gets that one)
    let larger = RenderOptions { max_width: 1024, max_height: 1024, ..Default::default() };
    let r_larger = LiberoEnv::new(&bundle).unwrap().renderer(gl.clone(), larger).unwrap();
    assert!(!r_larger.shares_upload_with(&r_plain), "a larger buffer shared a smaller one's upload");
    // a renderer reads back only what it drew itself
    let rect = libero_sim::render::Rect::new(0, 0, 128, 128);
    let camera = r_plain.camera_id("agentview").unwrap();
    plain.draw_camera(&mut r_plain, camera, rect).unwrap();
    edited.draw_camera(&mut r_edited, camera, rect).unwrap();
    assert!(r_plain.read(rect).is_err(), "a renderer read back what another one drew into their shared buffer");
    let mut shared = Vec::new();
    let mut other_frames = Vec::new();
    for _ in 0..2 {
        shared.push(pair(&mut plain, &mut r_plain));
        other_frames.push(pair(&mut env_other, &mut r_other));
        shared.push(pair(&mut edited, &mut r_edited));
        step(&mut plain);
        step(&mut edited);
    }
    // the renderer that made the upload gone, the other goes on with it
    drop(r_plain);
    shared.push(pair(&mut edited, &mut r_edited));
    assert!(other_frames[0][0] != shared[0][0], "another scene's renderer drew the first scene");
    // each env on a GL context (and a thread) of its own
    let own: Vec<Vec<[Vec<u8>; 2]>> = std::thread::scope(|scope| {
        let handles: Vec<_> = envs()
            .into_iter()
            .map(|mut env| {
                scope.spawn(move || {
                    let mut r = env.renderer(Rc::new(GlContext::new().unwrap()), options).unwrap();
                    (0..3)
                        .map(|_| {
                            let frames = pair(&mut env, &mut r);
                            step(&mut env);
                            frames
                        })
                        .collect()
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert_eq!(shared.len(), 5);
    for (i, frames) in shared.iter().enumerate() {
        let (env, at) = if i < 4 { (i % 2, i / 2) } else { (1, 2) };
        for (camera, (a, b)) in frames.iter().zip(&own[env][at]).enumerate() {
            let n = a.iter().zip(b).filter(|(x, y)| x != y).count();
            assert!(n == 0, "env {env}, step {at}, camera {camera}: {n} bytes differ from its own upload's frame");
        }
    }
    // the two envs' pictures differ, so each renderer drew its own scene state
    assert!(shared[0][0] != shared[1][0]);
}

/// A renderer kept across a task's episodes (as a run's worker keeps its env's, so the scene is
/// uploaded once per task, not once per episode) draws each episode's frames bit for bit as a
/// renderer made for that episode: after a reset to another init state, and with an episode's
/// edits of the model (LIBERO-PRO's lights and colours, LIBERO-Plus's camera pose) and without.
#[test]
fn a_renderer_kept_across_episodes_draws_what_a_new_one_draws() {
    use libero_sim::env::{Appearance, EpisodeEdits, Lighting};
    use libero_sim::viewpoint::CameraPose;
    let bundle = bundles().load("libero_spatial".parse().unwrap(), 1).unwrap();
    let mut env = LiberoEnv::new(&bundle).unwrap();
    let options = RenderOptions { max_width: 128, max_height: 128, ..Default::default() };
    let gl = Rc::new(GlContext::new().unwrap());
    let pair = |env: &mut LiberoEnv, r: &mut libero_sim::render::SceneRenderer| {
        ["agentview", "robot0_eye_in_hand"].map(|c| env.render(r, c, 128, 128).unwrap().rgb)
    };
    let mut kept = env.renderer(gl.clone(), options).unwrap();
    let first = object_edits(&env);
    let episodes = [(0, EpisodeEdits::default()), (3, first), (5, EpisodeEdits::default())];
    let mut seen = Vec::new();
    for (init, edits) in episodes {
        env.set_episode_edits(edits).unwrap();
        env.reset(init, 0).unwrap();
        for step in 0..2 {
            // a new renderer with an upload of its own: on a GL context of its own, on a thread of
            // its own (on this GL context it would share `kept`'s upload)
            let fresh = std::thread::scope(|scope| {
                let env = &mut env;
                scope
                    .spawn(move || {
                        let mut new = env.renderer(Rc::new(GlContext::new().unwrap()), options).unwrap();
                        pair(env, &mut new)
                    })
                    .join()
                    .unwrap()
            });
            let again = pair(&mut env, &mut kept);
            for (camera, (a, b)) in again.iter().zip(&fresh).enumerate() {
                let n = a.iter().zip(b).filter(|(x, y)| x != y).count();
                assert!(
                    n == 0,
                    "init state {init}, step {step}, camera {camera}: {n} bytes differ from a new renderer's"
                );
            }
            seen.push(again[0].clone());
            env.step([0.3, 0.0, 0.1, 0.0, 0.0, 0.0, -1.0]).unwrap();
        }
    }
    // the episodes' pictures differ, so the comparison saw three different scenes
    assert!(seen[0] != seen[2] && seen[2] != seen[4] && seen[0] != seen[4]);

    /// Lights, an object's colour and the camera pose changed, as the perturbation suites change them.
    fn object_edits(env: &LiberoEnv) -> EpisodeEdits {
        let object = env.object_names().next().expect("a scene with objects").to_string();
        EpisodeEdits {
            lighting: Some(Lighting { ambient: Some(0.6), diffuse: Some(0.3), specular: Some(0.1) }),
            appearance: Some(Appearance { objects: vec![object], rgba: [0.9, 0.1, 0.1, 1.0] }),
            agentview: Some(CameraPose { pos: [0.9, 0.1, 1.5], quat: [0.65, 0.28, 0.28, 0.65] }),
            ..Default::default()
        }
    }
}
