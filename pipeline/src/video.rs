//! `pipeline video`: an MP4 of a stored episode, made by replaying its stored actions; and
//! `pipeline videos`: the episodes `queries/video_selection.sql` picks (by default, per suite, the
//! first failure and the first episode of each failure mode), to `outputs/failures/`.
//!
//! No policy is needed: the env is reset to the episode's init state and seed and driven with
//! the actions of the `steps` table (wait steps included). The replay also proves determinism:
//! the goal value and the end-effector position after every replayed step must equal the stored
//! ones (to 1e-9 m), else the command fails and names the first step that differs. The video shows agentview | eye-in-hand
//! under a caption (episode, step, goal so far, final outcome and failure mode, instruction) and
//! ends on a card with the outcome.
//!
//! An ALOHA-sim episode (suite `aloha_sim`) is replayed the same way in its own env: reset from
//! its seed, driven with the stored 14-D actions; the reward and `agent_pos` after every step
//! must equal the stored ones (the joints to 1e-9 rad). The video shows the `top` camera at the
//! 640 × 480 a policy sees, under the same caption (the reward so far in place of the goal).

use crate::media::{Mp4Writer, PanelArgs, render_aloha_panel, render_card, render_panel};
use crate::results::write_csv;
use crate::session::{self, RunScoring, Scoring};
use anyhow::{Context, Result, bail};
use arrow::array::StringArray;
use arrow::array::{Array, AsArray};
use arrow::datatypes::{DataType, Field, Schema};
use arrow::datatypes::{Float32Type, Float64Type, Int32Type, Int64Type};
use arrow::record_batch::RecordBatch;
use libero_schema::Benchmark;
use libero_sim::aloha::{AlohaBundle, AlohaEnv, AlohaTask};
use libero_sim::bundle::BundleSet;
use libero_sim::env::LiberoEnv;
use libero_sim::gl::GlContext;
use libero_udfs::perturbation::EpisodePerturbation;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::Arc;

pub const VIDEO_EXAMPLES: &str = "\
Examples:
  pipeline video --run runs/pi05 --episode libero_goal/3/12/7      # suite/task/init state/seed
  pipeline video --run runs/aloha-expert --episode aloha_sim/0/0/1000 --out outputs/aloha";

#[derive(clap::Args)]
pub struct Args {
    /// The run (folder or object-store URL).
    #[arg(long)]
    run: String,
    /// Episode key(s) `suite/task_id/init_state_id/seed`, `.../v<variant>` for a perturbed episode
    /// (see `episodes.episode_key`).
    #[arg(long = "episode", required = true)]
    episodes: Vec<String>,
    /// Output folder; files are named `{suite}_task{i}_init{j}.mp4` (`..._v{variant}.mp4` for a
    /// perturbed episode).
    #[arg(long, default_value = "outputs/videos")]
    out: PathBuf,
    /// How the outcome and failure mode on the frames are scored.
    #[command(flatten)]
    scoring: Scoring,
    #[command(flatten)]
    render: RenderArgs,
}

pub const VIDEOS_EXAMPLES: &str = "\
Examples:
  pipeline videos --run runs/pi05 --dry-run       # print the selection only
  pipeline videos --run runs/pi05                 # outputs/failures/*.mp4 and selection.csv";

/// `pipeline videos`: render what the selection query picks.
#[derive(clap::Args)]
pub struct SelectedArgs {
    #[command(flatten)]
    scoring: RunScoring,
    /// Output folder for the MP4s and `selection.csv` (the selected rows, with each file name).
    #[arg(long, default_value = "outputs/failures")]
    out: PathBuf,
    /// Print the selection and render nothing.
    #[arg(long)]
    dry_run: bool,
    #[command(flatten)]
    render: RenderArgs,
}

/// How stored episodes are drawn.
#[derive(clap::Args)]
pub struct RenderArgs {
    /// Frames per second of the video.
    #[arg(long, default_value_t = 10)]
    fps: u32,
    /// Render every N-th env step. Default: real time at --fps 10, i.e. 2 for LIBERO (20 Hz) and
    /// 5 for ALOHA-sim (50 Hz).
    #[arg(long)]
    every: Option<u32>,
    #[command(flatten)]
    panel: PanelArgs,
}

/// One stored episode: what the replay needs and what the final card says.
pub(crate) struct StoredEpisode {
    pub(crate) key: String,
    pub(crate) suite: String,
    pub(crate) task_id: u32,
    pub(crate) init_state_id: usize,
    pub(crate) seed: u64,
    pub(crate) instruction: String,
    pub(crate) success: Option<bool>,
    /// The primary failure mode (`queries/failure_modes.sql`) under the chosen scoring.
    pub(crate) failure_mode: Option<String>,
    pub(crate) n_policy_steps: i32,
    pub(crate) error: Option<String>,
    pub(crate) goals: Vec<bool>,
    pub(crate) steps: StoredSteps,
}

/// A stored episode's steps as its benchmark's replay needs them.
// one value per replayed episode, beside its steps' vectors: the variants' sizes do not matter
#[allow(clippy::large_enum_variant)]
pub(crate) enum StoredSteps {
    Libero {
        /// What the episode's spec row perturbed (`episodes.perturbation_params`), re-applied.
        perturbation: EpisodePerturbation,
        /// The loop it reproduced (`episodes.protocol`): which fixture poses it started from.
        protocol: libero_schema::EvalProtocol,
        actions: Vec<[f32; 7]>,
        /// Stored end-effector position after each step: the replay must reproduce it exactly.
        eef_pos: Vec<[f64; 3]>,
        /// Whether each step ran a real-time hold (`steps.held`; false in closed-loop runs).
        held: Vec<bool>,
    },
    Aloha {
        actions: Vec<[f32; 14]>,
        /// Stored joints after each step and the reward: the replay must reproduce both.
        agent_pos: Vec<[f64; 14]>,
        reward: Vec<i32>,
        held: Vec<bool>,
    },
}

impl StoredEpisode {
    fn len(&self) -> usize {
        self.goals.len()
    }
}

/// The bundles replays need, opened when an episode of their benchmark first asks.
pub(crate) struct ReplayBundles {
    libero_dir: PathBuf,
    libero: Option<BundleSet>,
    aloha: Option<AlohaBundle>,
}

impl ReplayBundles {
    pub(crate) fn new(libero_dir: &Path) -> Self {
        ReplayBundles { libero_dir: libero_dir.to_path_buf(), libero: None, aloha: None }
    }
    pub(crate) fn libero(&mut self) -> Result<&BundleSet> {
        if self.libero.is_none() {
            self.libero = Some(BundleSet::open(&self.libero_dir)?);
        }
        Ok(self.libero.as_ref().expect("opened above"))
    }
    pub(crate) fn aloha(&mut self) -> Result<&AlohaBundle> {
        if self.aloha.is_none() {
            self.aloha = Some(AlohaBundle::open(crate::bundles_location::resolve_aloha(None))?);
        }
        Ok(self.aloha.as_ref().expect("opened above"))
    }
}

pub fn run(bundles: &Path, args: Args) -> Result<()> {
    let mut set = ReplayBundles::new(bundles);
    let episodes = tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, store) = args.scoring.open_run(&args.run).await?;
        load_episodes(&ctx, store.url().as_str(), &args.episodes).await
    })?;
    render_all(&mut set, &episodes, &args.render, &args.out)?;
    Ok(())
}

/// `pipeline videos`: run the selection query, render every row it returns, and write
/// `selection.csv` beside the videos.
pub fn run_selected(bundles: &Path, args: SelectedArgs) -> Result<()> {
    if args.dry_run {
        let selection = tokio::runtime::Runtime::new()?.block_on(async {
            let (ctx, _) = args.scoring.open().await?;
            session::materialize(&ctx, "failure_modes").await.context("queries/failure_modes.sql")?;
            session::queries::run(&ctx, session::queries::VIDEO_SELECTION).await
        })?;
        println!("success definition: {}", args.scoring.scoring.describe());
        println!("{}", arrow::util::pretty::pretty_format_batches(&selection)?);
        return Ok(());
    }
    let selection =
        render_selection_with(bundles, &args.scoring.run, args.scoring.scoring.clone(), &args.out, &args.render)?;
    println!("success definition: {}", args.scoring.scoring.describe());
    println!("{}", arrow::util::pretty::pretty_format_batches(&selection)?);
    println!("wrote {0}/selection.csv and {0}/videos.json", args.out.display());
    Ok(())
}

/// Render the episodes the selection query picks from `run` into `out` (default drawing).
pub fn render_selection(bundles: &Path, run: &str, scoring: Scoring, out: &Path) -> Result<Vec<RecordBatch>> {
    let render = RenderArgs { fps: 10, every: None, panel: PanelArgs::default() };
    render_selection_with(bundles, run, scoring, out, &render)
}

/// Run the selection, render its rows, and write `selection.csv` (the rows, with each video's
/// file name) and `videos.json` (the files and the run configuration they were made from, which
/// the report checks before it shows a video as this run's).
fn render_selection_with(
    bundles: &Path,
    run: &str,
    scoring: Scoring,
    out: &Path,
    render: &RenderArgs,
) -> Result<Vec<RecordBatch>> {
    let mut set = ReplayBundles::new(bundles);
    let (selection, episodes, run_config) = tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, store) = scoring.open_run(run).await?;
        let run_config = store.read_manifest().await?.context("the run has no manifest")?.run_config;
        // The selection and the frames read the failure modes: derive them once.
        session::materialize(&ctx, "failure_modes").await.context("queries/failure_modes.sql")?;
        let selection = session::queries::run(&ctx, session::queries::VIDEO_SELECTION).await?;
        let mut keys = vec![];
        for b in &selection {
            let col = b
                .column_by_name("episode_key")
                .context("queries/video_selection.sql must return an episode_key column")?
                .as_string::<i32>();
            keys.extend((0..b.num_rows()).map(|r| col.value(r).to_string()));
        }
        let episodes = load_episodes(&ctx, store.url().as_str(), &keys).await?;
        anyhow::Ok((selection, episodes, run_config))
    })?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let files: Vec<String> = episodes.iter().map(video_name).collect();
    let mut names = files.iter();
    let with_files = selection
        .iter()
        .map(|b| {
            let col: StringArray = (0..b.num_rows()).map(|_| names.next().cloned()).collect();
            let mut fields: Vec<_> = b.schema().fields().iter().cloned().collect();
            fields.push(Arc::new(Field::new("video", DataType::Utf8, true)));
            let mut columns = b.columns().to_vec();
            columns.push(Arc::new(col));
            RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)
        })
        .collect::<Result<Vec<_>, _>>()?;
    write_csv(&out.join("selection.csv"), &with_files)?;
    if episodes.is_empty() {
        println!("the selection is empty (no failed episode under this scoring): no video to render");
    }
    render_all(&mut set, &episodes, render, out)?;
    let index = serde_json::json!({"run": run, "run_config": run_config, "videos": files});
    std::fs::write(out.join("videos.json"), serde_json::to_vec_pretty(&index)?)?;
    Ok(with_files)
}

fn video_name(ep: &StoredEpisode) -> String {
    video_file_name(&ep.suite, ep.task_id, ep.init_state_id, &ep.key)
}

/// `{suite}_task{i}_init{j}.mp4`, with `_v{variant}` before the extension for a perturbed episode
/// (its key's `/v<variant>`), so the perturbed copies of one base episode get files of their own.
pub fn video_file_name(
    suite: &str,
    task_id: impl std::fmt::Display,
    init: impl std::fmt::Display,
    key: &str,
) -> String {
    let variant = key.split('/').nth(4).and_then(|v| v.strip_prefix('v'));
    let tail = variant.map(|v| format!("_v{v}")).unwrap_or_default();
    format!("{suite}_task{task_id}_init{init}{tail}.mp4")
}

fn render_all(set: &mut ReplayBundles, episodes: &[StoredEpisode], render: &RenderArgs, out: &Path) -> Result<()> {
    if episodes.is_empty() {
        return Ok(());
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let gl = Rc::new(GlContext::new()?);
    for ep in episodes {
        let path = out.join(video_name(ep));
        let (frames, matched) = match &ep.steps {
            StoredSteps::Libero { .. } => {
                (replay_to_video(set.libero()?, &gl, ep, render, &path)?, "goal and end-effector position")
            }
            StoredSteps::Aloha { .. } => {
                (replay_aloha_to_video(set.aloha()?, &gl, ep, render, &path)?, "reward and joints")
            }
        };
        println!(
            "{}  ({} frames, replay matched the stored {matched} of all {} steps)",
            path.display(),
            frames,
            ep.len()
        );
    }
    Ok(())
}

/// "SUCCESS", "FAILURE · dropped" or "ERROR · error": the outcome the frames announce.
fn outcome_line(ep: &StoredEpisode) -> String {
    match (&ep.error, ep.success, &ep.failure_mode) {
        (Some(_), _, _) => "ERROR".to_string(),
        (None, Some(true), None) => "SUCCESS".to_string(),
        (None, _, Some(mode)) => format!("FAILURE - {mode}"),
        _ => "FAILURE".to_string(),
    }
}

fn replay_to_video(
    set: &BundleSet,
    gl: &Rc<GlContext>,
    ep: &StoredEpisode,
    args: &RenderArgs,
    path: &Path,
) -> Result<u64> {
    let StoredSteps::Libero { perturbation, protocol, actions, eef_pos, .. } = &ep.steps else {
        bail!("{} is not a LIBERO episode", ep.key);
    };
    let every = frame_interval(args, 2)?;
    let bundle = set.load(ep.suite.parse().map_err(anyhow::Error::msg)?, ep.task_id)?;
    let mut env = LiberoEnv::new(&bundle)?;
    // The episode's camera pose and robot init pose: the same physics, seen as the policy saw it
    // (sensor noise is on the policy's input only; the video shows the clean frames).
    env.set_episode_edits(perturbation.env_edits(&bundle.task.problem)?)?;
    env.reset_under(*protocol, ep.init_state_id, ep.seed)?;
    let layout = args.panel.layout();
    let options = args.panel.options(&layout);
    let mut renderer = env.renderer(gl.clone(), options)?;
    let mut video = Mp4Writer::create(path, layout.width(), layout.height(), args.fps)?;
    let outcome = outcome_line(ep);
    let caption = |step: usize, goal_seen: bool| {
        format!(
            "{}  step {step}/{}  goal so far: {}\noutcome: {outcome}\n{}",
            ep.key,
            actions.len(),
            yes_no(goal_seen),
            ep.instruction
        )
    };
    video.push(&render_panel(&mut env, &mut renderer, &layout, &caption(0, false))?)?;
    let mut goal_seen = false;
    for (i, (action, &stored_goal)) in actions.iter().zip(&ep.goals).enumerate() {
        let out = env.step(action.map(f64::from)).with_context(|| format!("replaying step {i} of {}", ep.key))?;
        if out.goal.satisfied != stored_goal {
            bail!(
                "replay of {} is not deterministic: at step {i} the goal is {} but the run stored {}; \
                 was the run made with other bundles or another MuJoCo? (see its manifest)",
                ep.key,
                out.goal.satisfied,
                stored_goal
            );
        }
        let replayed = env.observation().eef_pos;
        let stored = eef_pos[i];
        let gap = replayed.iter().zip(&stored).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        if gap > 1e-9 {
            bail!(
                "replay of {} is not deterministic: at step {i} the end effector is {gap:.2e} m from the stored \
                 position; was the run made with other bundles or another MuJoCo? (see its manifest)",
                ep.key
            );
        }
        goal_seen |= out.goal.satisfied;
        let last = i + 1 == actions.len();
        if (i + 1) % every == 0 || last {
            video.push(&render_panel(&mut env, &mut renderer, &layout, &caption(i + 1, goal_seen))?)?;
        }
    }
    finish_video(video, &mut renderer, &layout, ep, outcome, args.fps)
}

/// `--every`, or `real_time` (the env steps per frame at --fps 10); both at least 1.
fn frame_interval(args: &RenderArgs, real_time: u32) -> Result<usize> {
    let every = args.every.unwrap_or(real_time);
    if every == 0 || args.fps == 0 {
        bail!("--every and --fps must be at least 1");
    }
    Ok(every as usize)
}

/// An ALOHA-sim episode replayed in its env from its seed, the `top` camera under the caption.
fn replay_aloha_to_video(
    bundle: &AlohaBundle,
    gl: &Rc<GlContext>,
    ep: &StoredEpisode,
    args: &RenderArgs,
    path: &Path,
) -> Result<u64> {
    let StoredSteps::Aloha { actions, agent_pos, reward, .. } = &ep.steps else {
        bail!("{} is not an ALOHA-sim episode", ep.key);
    };
    let every = frame_interval(args, 5)?;
    let task = AlohaTask::from_id(ep.task_id as i64)
        .with_context(|| format!("{}: no ALOHA-sim task {}", ep.key, ep.task_id))?;
    let seed =
        u32::try_from(ep.seed).with_context(|| format!("{}: seed {} is outside numpy's range", ep.key, ep.seed))?;
    let mut env = AlohaEnv::new(bundle, task)?;
    env.reset(seed)?;
    let layout = args.panel.aloha_layout();
    let mut renderer = env.renderer_with(gl.clone(), args.panel.aloha_options(&layout))?;
    let mut video = Mp4Writer::create(path, layout.width(), layout.height(), args.fps)?;
    let outcome = outcome_line(ep);
    let caption = |step: usize, reward: i32, best: i32| {
        format!(
            "{}  step {step}/{}  reward {reward} (best {best} of 4)\noutcome: {outcome}\n{}",
            ep.key,
            actions.len(),
            ep.instruction
        )
    };
    video.push(&render_aloha_panel(&mut env, &mut renderer, &layout, &caption(0, 0, 0))?)?;
    let mut best = 0;
    for (i, action) in actions.iter().enumerate() {
        let replayed = env.step(action).with_context(|| format!("replaying step {i} of {}", ep.key))? as i32;
        if replayed != reward[i] {
            bail!(
                "replay of {} is not deterministic: at step {i} the reward is {replayed} but the run stored {}; \
                 was the run made with another ALOHA-sim bundle or another MuJoCo? (see its manifest)",
                ep.key,
                reward[i]
            );
        }
        let gap = env.agent_pos().iter().zip(&agent_pos[i]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        if gap > 1e-9 {
            bail!(
                "replay of {} is not deterministic: at step {i} the joints are {gap:.2e} rad from the stored \
                 agent_pos; was the run made with another ALOHA-sim bundle or another MuJoCo? (see its manifest)",
                ep.key
            );
        }
        best = best.max(replayed);
        if (i + 1) % every == 0 || i + 1 == actions.len() {
            video.push(&render_aloha_panel(&mut env, &mut renderer, &layout, &caption(i + 1, replayed, best))?)?;
        }
    }
    finish_video(video, &mut renderer, &layout, ep, outcome, args.fps)
}

/// The outcome card, shown for two seconds, and the file closed.
fn finish_video(
    mut video: Mp4Writer,
    renderer: &mut libero_sim::render::SceneRenderer,
    layout: &crate::media::PanelLayout,
    ep: &StoredEpisode,
    outcome: String,
    fps: u32,
) -> Result<u64> {
    let headline = match &ep.error {
        Some(e) => format!("ERROR\n{}", crate::media::wrap(e, 50, 4)),
        None => outcome,
    };
    let card = format!(
        "{headline}\n\n{}\npolicy steps: {}\nfailure mode: {}\n\n{}",
        ep.key,
        ep.n_policy_steps,
        ep.failure_mode.as_deref().unwrap_or("-"),
        crate::media::wrap(&ep.instruction, 50, 3)
    );
    let background =
        if ep.failure_mode.is_none() && ep.error.is_none() { [0.05, 0.3, 0.1] } else { [0.35, 0.05, 0.05] };
    let card = render_card(renderer, layout.width(), layout.height(), &card, background)?;
    for _ in 0..2 * fps {
        video.push(&card)?;
    }
    video.finish()
}

fn yes_no(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

/// The stored episodes `keys` of the run open in `ctx` (`run` names it in errors).
pub(crate) async fn load_episodes(
    ctx: &datafusion::prelude::SessionContext,
    run: &str,
    keys: &[String],
) -> Result<Vec<StoredEpisode>> {
    let mut out = Vec::new();
    for key in keys {
        let quoted = format!("'{}'", key.replace('\'', "''"));
        let rows = ctx
            .sql(&format!(
                "SELECT suite, task_id, init_state_id, seed, instruction, success, n_policy_steps, error, \
                 perturbation_params, protocol FROM episodes WHERE episode_key = {quoted}"
            ))
            .await?
            .collect()
            .await?;
        let Some(b) = rows.iter().find(|b| b.num_rows() > 0) else {
            bail!(
                "{run} has no episode {key:?}; list them with `pipeline sql \"SELECT episode_key FROM episodes\" --run {run}`"
            );
        };
        let text = |i: usize| b.column(i).as_string::<i32>().value(0).to_string();
        let modes = ctx
            .sql(&format!("SELECT failure_mode FROM failure_modes WHERE episode_key = {quoted}"))
            .await?
            .collect()
            .await
            .context("queries/failure_modes.sql")?;
        let failure_mode =
            modes.iter().find(|m| m.num_rows() > 0).map(|m| m.column(0).as_string::<i32>().value(0).to_string());
        let success = b.column(5).as_boolean();
        let error = b.column(7).as_string::<i32>();
        let suite = text(0);
        let (goals, steps) = match Benchmark::of_suite(&suite) {
            Benchmark::Libero => {
                let params = b.column(8).as_string::<i32>();
                let perturbation = match params.is_null(0) {
                    true => EpisodePerturbation::default(),
                    false => EpisodePerturbation::from_canonical(params.value(0))
                        .map_err(anyhow::Error::msg)
                        .with_context(|| format!("episode {key}"))?,
                };
                let protocol = b.column(9).as_string::<i32>();
                // null in runs before tables v9: all canonical
                let protocol = match protocol.is_null(0) {
                    true => libero_schema::EvalProtocol::Canonical,
                    false => protocol
                        .value(0)
                        .parse()
                        .map_err(anyhow::Error::msg)
                        .with_context(|| format!("episode {key}"))?,
                };
                let rows = step_rows(ctx, &quoted, "action, goal, eef_pos, coalesce(held, false)").await?;
                let (mut actions, mut goals, mut eef_pos, mut held) = (vec![], vec![], vec![], vec![]);
                for s in &rows {
                    for r in 0..s.num_rows() {
                        actions.push(fixed_row::<Float32Type, 7>(s, 0, r).context("actions have 7 components")?);
                        goals.push(s.column(1).as_boolean().value(r));
                        eef_pos.push(fixed_row::<Float64Type, 3>(s, 2, r).context("eef_pos has 3 components")?);
                        held.push(s.column(3).as_boolean().value(r));
                    }
                }
                (goals, StoredSteps::Libero { perturbation, protocol, actions, eef_pos, held })
            }
            Benchmark::AlohaSim => {
                let rows = step_rows(ctx, &quoted, "action, goal, agent_pos, reward, coalesce(held, false)").await?;
                let (mut actions, mut goals, mut agent_pos, mut reward, mut held) =
                    (vec![], vec![], vec![], vec![], vec![]);
                for s in &rows {
                    for r in 0..s.num_rows() {
                        actions.push(fixed_row::<Float32Type, 14>(s, 0, r).context("actions have 14 components")?);
                        goals.push(s.column(1).as_boolean().value(r));
                        agent_pos.push(fixed_row::<Float64Type, 14>(s, 2, r).context("agent_pos has 14 components")?);
                        reward.push(s.column(3).as_primitive::<Int32Type>().value(r));
                        held.push(s.column(4).as_boolean().value(r));
                    }
                }
                (goals, StoredSteps::Aloha { actions, agent_pos, reward, held })
            }
        };
        out.push(StoredEpisode {
            key: key.clone(),
            suite,
            task_id: b.column(1).as_primitive::<Int32Type>().value(0) as u32,
            init_state_id: b.column(2).as_primitive::<Int32Type>().value(0) as usize,
            seed: b.column(3).as_primitive::<Int64Type>().value(0) as u64,
            instruction: text(4),
            success: (!success.is_null(0)).then(|| success.value(0)),
            failure_mode,
            n_policy_steps: b.column(6).as_primitive::<Int32Type>().value(0),
            error: (!error.is_null(0)).then(|| error.value(0).to_string()),
            goals,
            steps,
        });
    }
    Ok(out)
}

/// `columns` of an episode's step rows, in step order.
async fn step_rows(
    ctx: &datafusion::prelude::SessionContext,
    quoted_key: &str,
    columns: &str,
) -> Result<Vec<RecordBatch>> {
    Ok(ctx
        .sql(&format!("SELECT {columns} FROM steps WHERE episode_key = {quoted_key} ORDER BY step"))
        .await?
        .collect()
        .await?)
}

/// Row `row` of the fixed-size-list column `column` as an array of `N`.
fn fixed_row<T: arrow::datatypes::ArrowPrimitiveType, const N: usize>(
    batch: &RecordBatch,
    column: usize,
    row: usize,
) -> Result<[T::Native; N]> {
    let value = batch.column(column).as_fixed_size_list().value(row);
    Ok(value.as_primitive::<T>().values().as_ref().try_into()?)
}
