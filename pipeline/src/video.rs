//! `pipeline video`: an MP4 of a stored episode, made by replaying its stored actions.
//!
//! No policy is needed: the env is reset to the episode's init state and seed and driven with
//! the actions of the `steps` table (wait steps included). The replay also proves determinism:
//! the goal value and the end-effector position after every replayed step must equal the stored
//! ones (to 1e-9 m), else the command fails and names the first step that differs. The video shows agentview | eye-in-hand under a caption
//! (instruction, step, goal so far) and ends on a card with the outcome.

use crate::media::{Mp4Writer, PanelArgs, render_card, render_panel};
use crate::session::{self, SuccessDefinition};
use anyhow::{Context, Result, bail};
use arrow::array::{Array, AsArray};
use arrow::datatypes::{Float32Type, Float64Type, Int32Type, Int64Type};
use libero_sim::bundle::BundleSet;
use libero_sim::env::LiberoEnv;
use libero_sim::gl::GlContext;
use std::path::{Path, PathBuf};
use std::rc::Rc;

#[derive(clap::Args)]
pub struct Args {
    /// The run (folder or object-store URL).
    #[arg(long)]
    run: String,
    /// Episode key(s) `suite/task_id/init_state_id/seed` (see `episodes.episode_key`).
    #[arg(long = "episode", required = true)]
    episodes: Vec<String>,
    /// Output folder; files are named `{suite}_task{i}_init{j}.mp4`.
    #[arg(long, default_value = "outputs/videos")]
    out: PathBuf,
    /// Frames per second of the video.
    #[arg(long, default_value_t = 10)]
    fps: u32,
    /// Render every N-th env step (the env runs at 20 Hz: 2 at 10 fps is real time).
    #[arg(long, default_value_t = 2)]
    every: u32,
    #[command(flatten)]
    panel: PanelArgs,
}

/// One stored episode: what the replay needs and what the final card says.
struct StoredEpisode {
    key: String,
    suite: String,
    task_id: u32,
    init_state_id: usize,
    seed: u64,
    instruction: String,
    success: Option<bool>,
    n_policy_steps: i32,
    error: Option<String>,
    actions: Vec<[f32; 7]>,
    goals: Vec<bool>,
    /// Stored end-effector position after each step: the replay must reproduce it exactly.
    eef_pos: Vec<[f64; 3]>,
}

pub fn run(bundles: &Path, args: Args) -> Result<()> {
    let set = BundleSet::open(bundles)?;
    let episodes = tokio::runtime::Runtime::new()?.block_on(load_episodes(&args.run, &args.episodes))?;
    let gl = Rc::new(GlContext::new()?);
    for ep in episodes {
        let path = args.out.join(format!("{}_task{}_init{}.mp4", ep.suite, ep.task_id, ep.init_state_id));
        let frames = replay_to_video(&set, &gl, &ep, &args, &path)?;
        println!(
            "{}  ({} frames, replay matched the stored goal and end-effector position of all {} steps)",
            path.display(),
            frames,
            ep.goals.len()
        );
    }
    Ok(())
}

fn replay_to_video(set: &BundleSet, gl: &Rc<GlContext>, ep: &StoredEpisode, args: &Args, path: &Path) -> Result<u64> {
    if args.every == 0 || args.fps == 0 {
        bail!("--every and --fps must be at least 1");
    }
    let bundle = set.load(ep.suite.parse().map_err(anyhow::Error::msg)?, ep.task_id)?;
    let mut env = LiberoEnv::new(&bundle)?;
    env.reset(ep.init_state_id, ep.seed)?;
    let layout = args.panel.layout();
    let options = args.panel.options(&layout);
    let mut renderer = env.renderer(gl.clone(), options)?;
    let mut video = Mp4Writer::create(path, layout.width(), layout.height(), args.fps)?;
    let caption = |step: usize, goal_seen: bool| {
        format!("{}  step {step}/{}  goal reached: {}\n{}", ep.key, ep.actions.len(), yes_no(goal_seen), ep.instruction)
    };
    video.push(&render_panel(&mut env, &mut renderer, &layout, &caption(0, false))?)?;
    let mut goal_seen = false;
    for (i, (action, &stored_goal)) in ep.actions.iter().zip(&ep.goals).enumerate() {
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
        let stored = ep.eef_pos[i];
        let gap = replayed.iter().zip(&stored).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        if gap > 1e-9 {
            bail!(
                "replay of {} is not deterministic: at step {i} the end effector is {gap:.2e} m from the stored \
                 position; was the run made with other bundles or another MuJoCo? (see its manifest)",
                ep.key
            );
        }
        goal_seen |= out.goal.satisfied;
        let last = i + 1 == ep.actions.len();
        if (i + 1) % args.every as usize == 0 || last {
            video.push(&render_panel(&mut env, &mut renderer, &layout, &caption(i + 1, goal_seen))?)?;
        }
    }
    let outcome = match (&ep.error, ep.success) {
        (Some(e), _) => format!("ERROR\n{}", crate::media::wrap(e, 50, 4)),
        (None, Some(true)) => "SUCCESS".to_string(),
        _ => "FAILURE".to_string(),
    };
    let card = format!(
        "{outcome}\n\n{}\npolicy steps: {}\nfailure mode: {}\n\n{}",
        ep.key,
        ep.n_policy_steps,
        if ep.success == Some(true) { "-" } else { "not classified yet" },
        crate::media::wrap(&ep.instruction, 50, 3)
    );
    let background = if ep.success == Some(true) { [0.05, 0.3, 0.1] } else { [0.35, 0.05, 0.05] };
    let card = render_card(&mut renderer, layout.width(), layout.height(), &card, background)?;
    for _ in 0..2 * args.fps {
        video.push(&card)?;
    }
    video.finish()
}

fn yes_no(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

async fn load_episodes(run: &str, keys: &[String]) -> Result<Vec<StoredEpisode>> {
    let (ctx, store) = session::open(run, SuccessDefinition::AnyStep, None).await?;
    let mut out = Vec::new();
    for key in keys {
        let quoted = format!("'{}'", key.replace('\'', "''"));
        let rows = ctx
            .sql(&format!(
                "SELECT suite, task_id, init_state_id, seed, instruction, success, n_policy_steps, error \
                 FROM episodes WHERE episode_key = {quoted}"
            ))
            .await?
            .collect()
            .await?;
        let Some(b) = rows.iter().find(|b| b.num_rows() > 0) else {
            bail!(
                "{} has no episode {key:?}; list them with `pipeline sql \"SELECT episode_key FROM episodes\" --run {run}`",
                store.url()
            );
        };
        let text = |i: usize| b.column(i).as_string::<i32>().value(0).to_string();
        let success = b.column(5).as_boolean();
        let error = b.column(7).as_string::<i32>();
        let steps = ctx
            .sql(&format!("SELECT action, goal, eef_pos FROM steps WHERE episode_key = {quoted} ORDER BY step"))
            .await?
            .collect()
            .await?;
        let (mut actions, mut goals, mut eef_pos) = (Vec::new(), Vec::new(), Vec::new());
        for s in &steps {
            let list = s.column(0).as_fixed_size_list();
            for r in 0..s.num_rows() {
                let value = list.value(r);
                let a: [f32; 7] = value
                    .as_primitive::<Float32Type>()
                    .values()
                    .as_ref()
                    .try_into()
                    .context("actions have 7 components")?;
                actions.push(a);
                goals.push(s.column(1).as_boolean().value(r));
                let p = s.column(2).as_fixed_size_list().value(r);
                eef_pos.push(
                    p.as_primitive::<Float64Type>().values().as_ref().try_into().context("eef_pos has 3 components")?,
                );
            }
        }
        out.push(StoredEpisode {
            key: key.clone(),
            suite: text(0),
            task_id: b.column(1).as_primitive::<Int32Type>().value(0) as u32,
            init_state_id: b.column(2).as_primitive::<Int32Type>().value(0) as usize,
            seed: b.column(3).as_primitive::<Int64Type>().value(0) as u64,
            instruction: text(4),
            success: (!success.is_null(0)).then(|| success.value(0)),
            n_policy_steps: b.column(6).as_primitive::<Int32Type>().value(0),
            error: (!error.is_null(0)).then(|| error.value(0).to_string()),
            actions,
            goals,
            eef_pos,
        });
    }
    Ok(out)
}
