//! `pipeline export RUN --format lerobot --out DIR`: a run's chosen episodes (its failures by
//! default, or any SQL predicate over the `scored` view) as a LeRobotDataset that lerobot 0.6.1's
//! `LeRobotDataset` and training code read directly: "curate the failures back into collect".
//!
//! No policy runs: each episode is replayed from its stored actions, as `pipeline video` does (and
//! checked the same way: every replayed step must reproduce the stored goal and end-effector
//! position, or joints and reward). A frame is the observation before a policy step (the cameras
//! as a policy sees them, the state), that step's stored action, and what followed it
//! (`next.success`, `next.done`; ALOHA-sim's `next.reward`; a real-time run's `held`, the steps
//! whose action was the hold, not the policy's). LIBERO's wait steps are the protocol's settling,
//! not frames. With `--cap N` an episode's frames stop at policy step N, as its scoring does.
//!
//! Features follow lerobot's own names for each benchmark: LIBERO `observation.images.image` and
//! `.image2` (agentview and wrist: the render rotated 180°, as lerobot's `LiberoProcessorStep`
//! gives them to its policies) and the 8-D `observation.state` (eef position, axis-angle of robosuite's
//! `robot0_eef_quat`, fingers), `action` 7-D; ALOHA-sim `observation.images.top` (480 × 640),
//! `observation.state` = `agent_pos` (14), `action` 14-D. The frame rate is the env's control rate.
//!
//! The dataset is written to a temporary folder beside `--out` and renamed into place when
//! complete: an export that fails (a predicate that matches nothing, an episode that cannot be
//! replayed) leaves nothing behind, and an existing `--out` is never touched.

use crate::lerobot_dataset::{Camera, DatasetLayout, DatasetWriter, Frame, PartialDir, VideoEncoding};
use crate::session::Scoring;
use crate::video::{ReplayBundles, StoredEpisode, StoredSteps, load_episodes};
use anyhow::{Context, Result, bail};
use arrow::array::AsArray;
use libero_policies::preprocess::{QuatSign, libero_state};
use libero_schema::Benchmark;
use libero_sim::aloha::{AlohaEnv, AlohaTask};
use libero_sim::env::LiberoEnv;
use libero_sim::gl::GlContext;
use libero_sim::render::{Look, Quality, RenderOptions};
use libero_udfs::policy_cameras::{AGENTVIEW, WRIST};
use std::path::{Path, PathBuf};
use std::rc::Rc;

pub const EXAMPLES: &str = "\
Examples:
  pipeline export runs/pi05 --out datasets/pi05-failures                 # the run's failures
  pipeline export runs/pi05 --out datasets/goal --where \"suite = 'libero_goal'\"
  pipeline export runs/pi05 --out datasets/exact --video lossless        # the rendered pixels exactly";

/// The default selection: the failures that have a step to replay.
pub const FAILURES: &str = "NOT scored_success AND n_policy_steps > 0";

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// lerobot 0.6.1's LeRobotDataset (v3.0): Parquet frames, an MP4 per camera and episode, meta.
    Lerobot,
}

#[derive(clap::Args)]
pub struct Args {
    /// The run (folder or object-store URL).
    run: String,
    /// The dataset format.
    #[arg(long, value_enum, default_value_t = Format::Lerobot)]
    format: Format,
    /// The dataset folder to create (it must not exist).
    #[arg(long)]
    out: PathBuf,
    /// Which episodes: an SQL predicate over the `scored` view (every `episodes` column, plus
    /// `scored_success` and `errored` under --success/--cap). Default: the failures,
    /// `NOT scored_success AND n_policy_steps > 0`.
    #[arg(long = "where", default_value = FAILURES)]
    predicate: String,
    /// LIBERO's camera size in pixels (square). Default 256: the published LIBERO datasets'
    /// (OpenVLA's regenerated ones, lerobot's HuggingFaceVLA/libero). ALOHA-sim's top camera is
    /// always 480 × 640.
    #[arg(long, default_value_t = 256)]
    camera_size: u32,
    /// How the camera videos are encoded.
    #[arg(long, value_enum, default_value_t = VideoEncoding::H264)]
    video: VideoEncoding,
    #[command(flatten)]
    scoring: Scoring,
}

pub fn run(bundles: &Path, args: Args) -> Result<()> {
    let Format::Lerobot = args.format;
    if args.out.exists() {
        bail!(
            "--out {} already exists; export into a new folder (an existing dataset is never overwritten or added to)",
            args.out.display()
        );
    }
    if args.camera_size == 0 || args.camera_size % 2 == 1 {
        bail!("--camera-size {} must be an even number of pixels, e.g. 256", args.camera_size);
    }
    let (episodes, manifest) = tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, store) = args.scoring.open_run(&args.run).await?;
        let manifest = store.read_manifest().await?.context("the run has no manifest")?;
        let query = format!("SELECT episode_key FROM scored WHERE {} ORDER BY episode_key", args.predicate);
        let rows = ctx
            .sql(&query)
            .await
            .with_context(|| format!("--where {:?} is not a predicate over the scored view", args.predicate))?
            .collect()
            .await
            .with_context(|| format!("--where {:?}", args.predicate))?;
        let keys: Vec<String> =
            rows.iter().flat_map(|b| (0..b.num_rows()).map(|r| b.column(0).as_string::<i32>().value(r).to_string())).collect();
        if keys.is_empty() {
            bail!(
                "--where {:?} matches no episode of {} (scored {}); nothing was written. See the episodes with `pipeline sql \"SELECT episode_key, scored_success, n_policy_steps FROM scored\" --run {}`",
                args.predicate,
                args.run,
                args.scoring.describe(),
                args.run
            );
        }
        // each episode's failure mode is looked up: derive them once, not per episode
        crate::session::materialize(&ctx, "failure_modes").await.context("queries/failure_modes.sql")?;
        let episodes = load_episodes(&ctx, store.url().as_str(), &keys).await?;
        anyhow::Ok((episodes, manifest))
    })?;
    if let Some(ep) = episodes.iter().find(|e| e.n_policy_steps == 0) {
        bail!(
            "episode {} has no policy step to replay ({}); nothing was written. Leave it out, e.g. --where \"({}) AND n_policy_steps > 0\"",
            ep.key,
            ep.error.as_deref().unwrap_or("it never started"),
            args.predicate
        );
    }
    let env = manifest.env;
    let layout = match env {
        Benchmark::Libero => DatasetLayout {
            fps: manifest.control_freq_hz as u32,
            robot_type: "panda",
            cameras: ["observation.images.image", "observation.images.image2"]
                .map(|key| Camera { key: key.into(), width: args.camera_size, height: args.camera_size })
                .to_vec(),
            state_names: [
                "eef_pos_x",
                "eef_pos_y",
                "eef_pos_z",
                "eef_axisangle_x",
                "eef_axisangle_y",
                "eef_axisangle_z",
            ]
            .into_iter()
            .chain(["gripper_qpos_0", "gripper_qpos_1"])
            .map(String::from)
            .collect(),
            action_names: ["x", "y", "z", "rot_x", "rot_y", "rot_z", "gripper"].map(String::from).to_vec(),
            reward: false,
            held: manifest.realtime.is_some(),
            encoding: args.video,
        },
        Benchmark::AlohaSim => {
            let joints = ["waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate", "gripper"];
            let names: Vec<String> =
                ["left", "right"].iter().flat_map(|arm| joints.iter().map(move |j| format!("{arm}_{j}"))).collect();
            DatasetLayout {
                fps: manifest.control_freq_hz as u32,
                robot_type: "aloha",
                cameras: vec![Camera { key: "observation.images.top".into(), width: 640, height: 480 }],
                state_names: names.clone(),
                action_names: names,
                reward: true,
                held: manifest.realtime.is_some(),
                encoding: args.video,
            }
        }
    };
    remove_abandoned_partials(&args.out);
    let partial = partial_path(&args.out);
    let _ = std::fs::remove_dir_all(&partial);
    let cleanup = PartialDir::new(partial.clone());
    let mut writer = DatasetWriter::create(&partial, layout)?;
    let mut set = ReplayBundles::new(bundles);
    let gl = Rc::new(GlContext::new()?);
    let wait = manifest.num_steps_wait.max(0) as usize;
    // the policy steps scored (`--cap`), and so exported
    let cap = args.scoring.cap.map_or(usize::MAX, |c| c as usize);
    for (i, ep) in episodes.iter().enumerate() {
        writer.begin_episode(&ep.instruction)?;
        match &ep.steps {
            StoredSteps::Libero { .. } => {
                replay_libero(set.libero()?, &gl, ep, wait, cap, args.camera_size, &mut writer)
            }
            StoredSteps::Aloha { .. } => replay_aloha(set.aloha()?, &gl, ep, cap, &mut writer),
        }
        .with_context(|| format!("exporting episode {}; nothing was written", ep.key))?;
        writer.end_episode()?;
        eprintln!("[{}/{}] {} ({} frames)", i + 1, episodes.len(), ep.key, (ep.n_policy_steps as usize).min(cap));
    }
    let provenance = serde_json::json!({
        "run": args.run,
        "run_config": manifest.run_config,
        "policy": manifest.policy,
        "policy_identity": manifest.policy_identity,
        "where": args.predicate,
        "scoring": args.scoring.describe(),
        "realtime": manifest.realtime,
        "camera_size": args.camera_size,
        "episodes": episodes.iter().enumerate().map(|(i, e)| serde_json::json!({
            "episode_index": i, "episode_key": e.key, "success": e.success,
            "failure_mode": e.failure_mode, "error": e.error,
        })).collect::<Vec<_>>(),
    });
    let (n_episodes, n_frames) = writer.finish(&[("libero_eval.json", provenance)])?;
    std::fs::rename(&partial, &args.out)
        .with_context(|| format!("moving the finished dataset to {}", args.out.display()))?;
    cleanup.keep();
    println!(
        "wrote {}: a LeRobotDataset (v3.0) of {n_episodes} episodes, {n_frames} frames at {} fps, from {} (where {})",
        args.out.display(),
        manifest.control_freq_hz,
        args.run,
        args.predicate
    );
    println!(
        "load it: LeRobotDataset(repo_id=\"local/{}\", root=\"{}\")",
        args.out.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(),
        args.out.display()
    );
    Ok(())
}

/// Remove the half-written datasets of exports into `out` whose process is gone (killed before
/// it could clean up): `.NAME.partial-PID` beside it, PID not running.
fn remove_abandoned_partials(out: &Path) {
    let name = out.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let prefix = format!(".{name}.partial-");
    let dir = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let file = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = file.strip_prefix(&prefix).and_then(|p| p.parse::<u32>().ok()) else { continue };
        if !Path::new(&format!("/proc/{pid}")).exists() && std::fs::remove_dir_all(e.path()).is_ok() {
            eprintln!("removed {}, left by an export that was killed", e.path().display());
        }
    }
}

fn partial_path(out: &Path) -> PathBuf {
    let name = out.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "dataset".into());
    out.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}

/// A LIBERO episode's frames: the wait steps replayed unrecorded, then per policy step the two
/// cameras (as the policy saw them, rotated upright as lerobot's env processor does) and the state
/// before it, its action, and the goal after it.
fn replay_libero(
    set: &libero_sim::bundle::BundleSet,
    gl: &Rc<GlContext>,
    ep: &StoredEpisode,
    wait: usize,
    cap: usize,
    size: u32,
    writer: &mut DatasetWriter,
) -> Result<()> {
    let StoredSteps::Libero { perturbation, protocol, actions, eef_pos, held } = &ep.steps else {
        bail!("not a LIBERO episode")
    };
    let bundle = set.load(ep.suite.parse().map_err(anyhow::Error::msg)?, ep.task_id)?;
    let mut env = LiberoEnv::new(&bundle)?;
    // the camera pose and robot init pose of a perturbed row; sensor noise was the policy's input
    // only, and the frames are clean
    env.set_episode_edits(perturbation.env_edits(&bundle.task.problem)?)?;
    env.reset_under(*protocol, ep.init_state_id, ep.seed)?;
    let options =
        RenderOptions { look: Look::Mujoco323, quality: Quality::Reference, max_width: size, max_height: size };
    let mut renderer = env.renderer(gl.clone(), options)?;
    for (i, action) in actions.iter().enumerate().take(wait.saturating_add(cap)) {
        let frame = if i >= wait {
            let obs = env.observation();
            let q = obs.hand_quat;
            let state = libero_state(obs.eef_pos, [q[1], q[2], q[3], q[0]], obs.gripper_qpos, QuatSign::AsGiven);
            let image = env.render(&mut renderer, AGENTVIEW, size, size)?.policy_view();
            let image2 = env.render(&mut renderer, WRIST, size, size)?.policy_view();
            Some((state.map(|v| v as f32), image.rgb, image2.rgb))
        } else {
            None
        };
        let out = env.step(action.map(f64::from)).with_context(|| format!("replaying step {i}"))?;
        if out.goal.satisfied != ep.goals[i] {
            bail!(
                "the replay is not deterministic: at step {i} the goal is {} but the run stored {}; was the run made with other bundles or another MuJoCo? (see its manifest)",
                out.goal.satisfied,
                ep.goals[i]
            );
        }
        let gap = env.observation().eef_pos.iter().zip(&eef_pos[i]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        if gap > 1e-9 {
            bail!(
                "the replay is not deterministic: at step {i} the end effector is {gap:.2e} m from the stored position; was the run made with other bundles or another MuJoCo? (see its manifest)"
            );
        }
        if let Some((state, image, image2)) = frame {
            writer.push(&Frame {
                images: vec![&image, &image2],
                state: &state,
                action: action.as_slice(),
                reward: None,
                success: out.goal.satisfied,
                held: held[i],
            })?;
        }
    }
    Ok(())
}

/// An ALOHA-sim episode's frames: per step the `top` camera and `agent_pos` before it, its action,
/// and the reward after it.
fn replay_aloha(
    bundle: &libero_sim::aloha::AlohaBundle,
    gl: &Rc<GlContext>,
    ep: &StoredEpisode,
    cap: usize,
    writer: &mut DatasetWriter,
) -> Result<()> {
    let StoredSteps::Aloha { actions, agent_pos, reward, held } = &ep.steps else { bail!("not an ALOHA-sim episode") };
    let task = AlohaTask::from_id(ep.task_id as i64).with_context(|| format!("no ALOHA-sim task {}", ep.task_id))?;
    let seed = u32::try_from(ep.seed).with_context(|| format!("seed {} is outside numpy's range", ep.seed))?;
    let mut env = AlohaEnv::new(bundle, task)?;
    env.reset(seed)?;
    let mut renderer = env.renderer(gl.clone())?;
    for (i, action) in actions.iter().enumerate().take(cap) {
        let state = env.agent_pos().map(|v| v as f32);
        let top = env.render_top(&mut renderer)?;
        let replayed = env.step(action).with_context(|| format!("replaying step {i}"))? as i32;
        if replayed != reward[i] {
            bail!(
                "the replay is not deterministic: at step {i} the reward is {replayed} but the run stored {}; was the run made with another ALOHA-sim bundle or another MuJoCo? (see its manifest)",
                reward[i]
            );
        }
        let gap = env.agent_pos().iter().zip(&agent_pos[i]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        if gap > 1e-9 {
            bail!(
                "the replay is not deterministic: at step {i} the joints are {gap:.2e} rad from the stored agent_pos"
            );
        }
        writer.push(&Frame {
            images: vec![&top.rgb],
            state: &state,
            action: action.as_slice(),
            reward: Some(replayed as f32),
            success: replayed == libero_sim::aloha::MAX_REWARD as i32,
            held: held[i],
        })?;
    }
    Ok(())
}
