//! # pipeline
//!
//! The command-line entry point of the LIBERO evaluation pipeline. Each subcommand lives in its
//! own module; this file only parses arguments and dispatches.

mod bench;
mod bench_perturbation;
mod bench_run;
mod bundles_location;
mod compact;
mod compare;
#[cfg(feature = "distributed")]
mod distributed;
mod engine;
mod failures;
mod generalisation;
mod libero_plus;
mod libero_pro_robustness;
mod media;
mod published;
mod report;
mod results;
mod robustness;
mod run;
mod sample_size;
mod session;
mod smoke;
mod specs;
mod sql;
mod tasks;
mod video;

use clap::{Parser, Subcommand};
use std::path::PathBuf;

/// Evaluate VLA policies on LIBERO: task bundles, the MuJoCo environment, runs and results.
#[derive(Parser)]
#[command(name = "pipeline", version, about)]
struct Cli {
    /// Folder of task bundles (built by ./setup.sh). Default: data/bundles here, else that of the
    /// checkout this binary was built in, else the newest in the set-up's cache.
    #[arg(long, global = true, env = "LIBERO_BUNDLES")]
    bundles: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List suites, tasks and instructions from the task bundles.
    Tasks(tasks::Args),
    /// Write a spec table (one row per episode) for the canonical protocol.
    Specs(specs::Args),
    /// Run every episode of a spec table (resumes a killed run on the same --out).
    Run(run::Args),
    /// Per-suite and per-task success rates with Wilson 95% intervals, re-scorable.
    Results(results::Args),
    /// LIBERO-PRO beside the base suites: rates, drops with intervals, the suite that falls most.
    Robustness(robustness::Args),
    /// LIBERO-Plus scored by category: rates with Wilson intervals, drops from the base rate, the
    /// published leaderboard beside this run (outputs/generalisation*.csv).
    Generalisation(generalisation::Args),
    /// One primary failure mode per failed episode, and counts per suite (queries/failure_modes.sql).
    Failures(failures::Args),
    /// results.csv, per-task and failure tables and a self-contained report.html for one or more runs.
    Report(report::Args),
    /// Merge a run's one-episode parts into a few large Parquet files per table (atomic, resumable).
    Compact(compact::Args),
    /// Ad-hoc SQL over a run (tables specs, steps, episodes, manifest, scored, published).
    Sql(sql::Args),
    /// Paired comparison of two runs on their common episode keys (McNemar, Newcombe interval).
    Compare(compare::Args),
    /// Trials per task needed to detect a difference in success rate between two policies.
    SampleSize(sample_size::Args),
    /// One picture per suite (agentview | eye-in-hand, task 0, init 0) to outputs/smoke/.
    Smoke(smoke::Args),
    /// MP4s of stored episodes, made by replaying their actions (checks determinism).
    Video(video::Args),
    /// MP4s of the episodes queries/video_selection.sql picks (first failure, one per failure mode).
    Videos(video::SelectedArgs),
    /// Ballista scheduler with our functions (for `--engine ballista://HOST:PORT`).
    #[cfg(feature = "distributed")]
    Scheduler(distributed::scheduler::Args),
    /// Ballista executor with our functions: runs episodes of distributed runs with this machine's bundles.
    #[cfg(feature = "distributed")]
    Executor(distributed::executor::Args),
    /// Benchmarks that print figures (e.g. `pipeline bench sim`).
    #[command(subcommand)]
    Bench(bench::Bench),
}

fn main() -> anyhow::Result<()> {
    // before any thread: libtorch reads it at its first attention call (see the function)
    libero_policies::placement::keep_cudnn_attention_last();
    let cli = Cli::parse();
    let bundles = || bundles_location::resolve(cli.bundles.as_deref());
    match cli.command {
        Command::Tasks(args) => tasks::run(&bundles()?, args),
        Command::Specs(args) => specs::run(&bundles()?, args),
        Command::Run(args) => run::run(&bundles()?, args),
        Command::Results(args) => results::run(args),
        Command::Robustness(args) => robustness::run(args),
        Command::Generalisation(args) => generalisation::run(args),
        Command::Failures(args) => failures::run(args),
        Command::Report(args) => report::run(&bundles()?, args),
        Command::Sql(args) => sql::run(args),
        Command::Compact(args) => compact::run(args),
        Command::Compare(args) => compare::run(args),
        Command::SampleSize(args) => sample_size::run(args),
        Command::Smoke(args) => smoke::run(&bundles()?, args),
        Command::Video(args) => video::run(&bundles()?, args),
        Command::Videos(args) => video::run_selected(&bundles()?, args),
        #[cfg(feature = "distributed")]
        Command::Scheduler(args) => distributed::scheduler::run(args),
        #[cfg(feature = "distributed")]
        Command::Executor(args) => distributed::executor::run(&bundles()?, args),
        Command::Bench(bench::Bench::Run(args)) => bench_run::run(args),
        Command::Bench(b) => bench::run(&bundles()?, b),
    }
}
