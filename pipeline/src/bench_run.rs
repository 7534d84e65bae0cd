//! `pipeline bench run --run RUN`: the figures of a stored run at scale, printed.
//!
//! - each `pipeline run` invocation that ran episodes: episodes, wall time, episodes/s, workers,
//!   peak RSS, task-model compiles and the devices its cameras rendered on (from
//!   `RUN/sessions/*.json`, which the run writes);
//! - files per table (`steps/`, `episodes/`);
//! - where a policy step's time goes (render, policy: queue / preparation / forward, env step),
//!   the episodes per hour, the model's busy fraction and the projected wall time of the canonical
//!   protocol, from the timings stored with every step (`queries/step_timing.sql`);
//! - with `--lengths`, that protocol's wall time at a succeeding policy's episode lengths
//!   (`queries/protocol_projection.sql`): a model with random weights runs every episode to its cap,
//!   while the wall time a user meets is that of a policy whose episodes stop at success;
//! - wall time of re-scoring as a user does it: `pipeline results` under each success definition,
//!   with and without a shorter cap, and `pipeline report` without videos, each a fresh process
//!   (median of `--repeats`).

use crate::run::SessionRecord;
use anyhow::{Context, Result, bail};
use libero_udfs::run_store::RunStore;
use std::process::Command;
use std::time::Instant;

pub const EXAMPLES: &str = "\
Examples:
  pipeline bench run --run runs/pi05
  pipeline bench run --run runs/pi05 --no-rescoring   # the run's own figures only
  pipeline bench run --run runs/oft --no-rescoring --lengths runs/expert --success-rate 0.97";

#[derive(clap::Args)]
pub struct RunArgs {
    /// The run to measure (folder or object-store URL).
    #[arg(long)]
    run: String,
    /// Repetitions of each re-scoring command; the median is printed.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// The shorter cap (policy steps) of the capped re-scorings.
    #[arg(long, default_value_t = 100)]
    cap: u32,
    /// Only the run's own figures (invocations, files, step timing), no re-scoring.
    #[arg(long)]
    no_rescoring: bool,
    /// Also project the canonical protocol (4 suites x 500 episodes) at the episode lengths of this
    /// stored run: each suite's mean length of its successful episodes (a run of a policy that
    /// succeeds, such as `--policy expert` over the four suites), at `--run`'s policy steps per second.
    #[arg(long, value_name = "RUN")]
    lengths: Option<String>,
    /// With `--lengths`: the success rate projected; the other episodes run to their suite's cap.
    #[arg(long, default_value_t = 0.97, value_name = "RATE")]
    success_rate: f64,
}

pub fn run(args: RunArgs) -> Result<()> {
    if args.lengths.is_some() && !(0.0..=1.0).contains(&args.success_rate) {
        bail!("--success-rate {} is not a rate: give a number in [0, 1], e.g. 0.97", args.success_rate);
    }
    let runtime = tokio::runtime::Runtime::new()?;
    let store = runtime.block_on(RunStore::connect(&args.run))?;
    let (sessions, files) = runtime.block_on(async {
        let mut sessions: Vec<SessionRecord> = Vec::new();
        for name in store.file_names("sessions").await? {
            let bytes = store.get(&format!("sessions/{name}")).await?.unwrap_or_default();
            sessions.push(serde_json::from_slice(&bytes).with_context(|| format!("sessions/{name}"))?);
        }
        sessions.sort_by(|a, b| a.started_at.cmp(&b.started_at));
        let mut files = Vec::new();
        for table in ["steps", "episodes"] {
            files.push((table, store.file_names(table).await?.len()));
        }
        anyhow::Ok((sessions, files))
    })?;
    println!("run {}", store.url());
    println!("invocations of `pipeline run`:");
    println!(
        "  {:<22} {:>8} {:>9} {:>10} {:>7} {:>12} {:>13}",
        "started", "episodes", "wall s", "episodes/s", "workers", "peak RSS GB", "task compiles"
    );
    for s in &sessions {
        println!(
            "  {:<22} {:>8} {:>9.1} {:>10.2} {:>7} {:>12.2} {:>8} / {:<4}",
            s.started_at,
            s.episodes,
            s.wall_s,
            s.episodes as f64 / s.wall_s,
            s.workers,
            s.peak_rss_bytes.unwrap_or(0) as f64 / 1e9,
            s.task_compiles,
            s.tasks
        );
        if let Some(renders) = s.renders() {
            println!("    cameras: {renders}");
        }
    }
    if sessions.is_empty() {
        println!("  (none recorded: the run predates session records)");
    }
    for (table, n) in &files {
        println!("files in {table}/: {n}");
    }
    let rate = print_step_timing(&runtime, &args.run)?;
    if let Some(lengths) = &args.lengths {
        match rate {
            Some(rate) if rate > 0.0 => print_projection(&runtime, lengths, rate, args.success_rate)?,
            _ => bail!("--lengths needs the policy steps per second of --run, and {} has no step timings", args.run),
        }
    }
    if args.no_rescoring {
        return Ok(());
    }
    let exe = std::env::current_exe()?;
    let out = std::env::temp_dir().join(format!("libero-bench-run-{}", std::process::id()));
    let cap = args.cap.to_string();
    let out_s = out.to_str().context("temp dir")?.to_string();
    let commands: Vec<(String, Vec<&str>)> = vec![
        ("results, any-step".into(), vec!["results", "--run", &args.run, "--out", &out_s]),
        ("results, last-step".into(), vec!["results", "--run", &args.run, "--success", "last-step", "--out", &out_s]),
        (format!("results, any-step, cap {cap}"), vec!["results", "--run", &args.run, "--cap", &cap, "--out", &out_s]),
        (
            format!("results, last-step, cap {cap}"),
            vec!["results", "--run", &args.run, "--success", "last-step", "--cap", &cap, "--out", &out_s],
        ),
        ("report (no videos)".into(), vec!["report", "--run", &args.run, "--out", &out_s]),
    ];
    println!("re-scoring, wall time of a fresh process (median of {}):", args.repeats);
    for (what, cmd) in &commands {
        let mut times = Vec::new();
        for _ in 0..args.repeats.max(1) {
            let t0 = Instant::now();
            let o = Command::new(&exe).args(cmd).output()?;
            if !o.status.success() {
                bail!("`pipeline {}` failed:\n{}", cmd.join(" "), String::from_utf8_lossy(&o.stderr));
            }
            times.push(t0.elapsed().as_secs_f64());
        }
        times.sort_by(f64::total_cmp);
        println!("  {what:<32} {:>7.2} s", times[times.len() / 2]);
    }
    let _ = std::fs::remove_dir_all(&out);
    Ok(())
}

/// `queries/step_timing.sql` over the run, as labelled lines (one row: the run's figures); returns
/// the run's policy steps per second.
fn print_step_timing(runtime: &tokio::runtime::Runtime, run: &str) -> Result<Option<f64>> {
    let batches = runtime.block_on(async {
        let (ctx, _) = crate::session::open(run, crate::session::SuccessDefinition::AnyStep, None).await?;
        crate::session::queries::run(&ctx, crate::session::queries::STEP_TIMING).await
    })?;
    let Some(batch) = batches.iter().find(|b| b.num_rows() > 0) else { return Ok(None) };
    let value = |name: &str| f64_at(batch, name, 0);
    println!("where the time goes (queries/step_timing.sql; stored per-step timings):");
    let Some(span) = value("span_s") else {
        println!("  (no timings: the run predates tables v5)");
        return Ok(None);
    };
    println!(
        "  {} episodes, {} policy steps over {span:.1} s: {} episodes/h, {} policy steps/s",
        show(value("episodes"), 0),
        show(value("policy_steps"), 0),
        show(value("episodes_per_hour"), 0),
        show(value("policy_steps_per_s"), 1)
    );
    println!(
        "  per policy step, one worker (ms): render {} (an episode's first step {}, later steps {}), policy {} \
         (preparation {}, queue {}, forward {}, other {}), env step {}",
        show(value("render_ms"), 2),
        show(value("first_step_render_ms"), 1),
        show(value("later_steps_render_ms"), 2),
        show(value("policy_ms"), 2),
        show(value("prepare_ms"), 2),
        show(value("queue_ms"), 2),
        show(value("forward_ms"), 2),
        show(value("policy_other_ms"), 2),
        show(value("sim_ms"), 2)
    );
    if value("forwards").unwrap_or(0.0) > 0.0 {
        println!(
            "  model: {} forwards, {} episodes per forward (at most {}), {} ms per forward; busy {}% of the span",
            show(value("forwards"), 0),
            show(value("episodes_per_forward"), 1),
            show(value("max_episodes_per_forward"), 0),
            show(value("forward_ms_mean"), 1),
            show(value("model_busy_fraction").map(|f| f * 100.0), 1)
        );
    }
    println!(
        "  canonical protocol at the caps (660,000 policy steps) at this rate: {} h on one such machine, {} h on 8 (linear scaling assumed)",
        show(value("canonical_hours_1_replica"), 2),
        show(value("canonical_hours_8_replicas"), 2)
    );
    Ok(value("policy_steps_per_s"))
}

/// `queries/protocol_projection.sql` over the `lengths` run's episodes at `rate` policy steps/s.
fn print_projection(runtime: &tokio::runtime::Runtime, lengths: &str, rate: f64, success_rate: f64) -> Result<()> {
    let sql = crate::session::queries::text(crate::session::queries::PROTOCOL_PROJECTION)?
        .replace("{{success_rate}}", &format!("{success_rate:?}"))
        .replace("{{policy_steps_per_s}}", &format!("{rate:?}"));
    let batches = runtime.block_on(async {
        let (ctx, _) = crate::session::open(lengths, crate::session::SuccessDefinition::AnyStep, None).await?;
        anyhow::Ok(ctx.sql(&sql).await.context("queries/protocol_projection.sql")?.collect().await?)
    })?;
    println!(
        "canonical protocol at {:.0}% success with the lengths of {lengths}'s successes (queries/protocol_projection.sql), at {rate:.1} policy steps/s:",
        success_rate * 100.0
    );
    println!(
        "  {:<16} {:>9} {:>10} {:>22} {:>5} {:>13} {:>9}",
        "suite", "episodes", "successes", "mean success length", "cap", "policy steps", "minutes"
    );
    let Some(first) = batches.first() else { bail!("queries/protocol_projection.sql returned nothing") };
    let table = arrow::compute::concat_batches(&first.schema(), &batches)?;
    let text = |c: &str, r: usize| -> Result<String> {
        use arrow::array::Array;
        let column = table.column_by_name(c).with_context(|| format!("protocol_projection.sql has no {c}"))?;
        Ok(if column.is_null(r) { "-".into() } else { arrow::util::display::array_value_to_string(column, r)? })
    };
    let number = |c: &str, r: usize, digits: usize| show(f64_at(&table, c, r), digits);
    let mut missing = Vec::new();
    for r in 0..table.num_rows() {
        let suite = text("suite", r)?;
        if f64_at(&table, "policy_steps", r).is_none() && suite.starts_with("libero") {
            missing.push(suite.clone());
        }
        println!(
            "  {suite:<16} {:>9} {:>10} {:>22} {:>5} {:>13} {:>9}",
            text("episodes", r)?,
            text("successes", r)?,
            number("mean_success_steps", r, 1),
            text("cap", r)?,
            number("policy_steps", r, 0),
            number("minutes", r, 1)
        );
    }
    if !missing.is_empty() {
        println!(
            "  no projection: {lengths} has no successful episode of {} (run the policy over every suite, e.g. \
             `pipeline specs --suites libero_spatial,libero_object,libero_goal,libero_10 --trials 5`)",
            missing.join(", ")
        );
    }
    Ok(())
}

/// Column `name` of `batch` at `row`, cast to f64; `None` for a null or a column the query lacks.
fn f64_at(batch: &arrow::array::RecordBatch, name: &str, row: usize) -> Option<f64> {
    use arrow::array::{Array, AsArray};
    let column = arrow::compute::cast(batch.column_by_name(name)?, &arrow::datatypes::DataType::Float64).ok()?;
    let column = column.as_primitive::<arrow::datatypes::Float64Type>();
    (!column.is_null(row)).then(|| column.value(row))
}

/// A figure with `digits` decimals, or `-` for none.
fn show(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".to_string(), |v| format!("{v:.digits$}"))
}
