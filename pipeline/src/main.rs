//! # pipeline
//!
//! The command-line entry point of the LIBERO evaluation pipeline. Each subcommand lives in its
//! own module; this file only parses arguments and dispatches.

mod bench;
mod bench_perturbation;
mod bench_run;
mod bundles_location;
mod cli_reference;
mod compact;
mod compare;
#[cfg(feature = "distributed")]
mod distributed;
mod doctor;
mod engine;
mod export;
mod failures;
mod generalisation;
mod lerobot_dataset;
mod libero_plus;
mod libero_pro_robustness;
mod media;
mod processes;
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

/// Evaluate VLA policies on LIBERO and ALOHA-sim: task bundles, the MuJoCo environment, runs and
/// results.
#[derive(Parser)]
#[command(name = "pipeline", version, after_help = EXAMPLES)]
struct Cli {
    /// Folder of task bundles (built by ./setup.sh). Default: data/bundles here, else that of the
    /// checkout this binary was built in, else the newest in the set-up's cache.
    #[arg(long, global = true, env = "LIBERO_BUNDLES")]
    bundles: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

const EXAMPLES: &str = "\
Examples:
  pipeline tasks                                                   # what the bundles hold
  pipeline specs --suites libero_goal --trials 5 -o specs.parquet
  pipeline run specs.parquet --out runs/expert --policy expert && pipeline report --run runs/expert

Each command's --help says what it does and writes, with examples.";

#[derive(Subcommand)]
enum Command {
    /// List suites, tasks and instructions (LIBERO's bundles, then ALOHA-sim's).
    ///
    /// Prints one row per task: suite, task id, init states and the instruction the published
    /// evaluation gives the policy (`--json`: one JSON object per line, with the BDDL and file-name
    /// texts too). LIBERO's tasks come from the task bundles (--bundles); ALOHA-sim's two tasks
    /// (suite aloha_sim) from its bundle (data/aloha), listed after them: they have no init states
    /// (an episode's seed places the objects). Writes nothing.
    #[command(after_help = tasks::EXAMPLES)]
    Tasks(tasks::Args),
    /// Write a spec table (one row per episode) of a benchmark's protocol.
    ///
    /// LIBERO's canonical protocol by default; --benchmark picks LIBERO-Plus, LIBERO-PRO's
    /// robustness cases or ALOHA-sim. Writes a Parquet file (-o, default specs.parquet) with one
    /// row per episode: suite, task_id, init_state_id, seed, and for the perturbation benchmarks
    /// the columns that perturb it. `pipeline run` runs it; any Parquet file with these columns is
    /// a spec table too.
    #[command(after_help = specs::EXAMPLES)]
    Specs(specs::Args),
    /// Run every episode of a spec table (resumes a killed run on the same --out).
    ///
    /// Validates the spec table, then runs each episode with the policy and writes the run
    /// (--out: a folder or an object-store URL): the manifest, the spec table, one steps part and
    /// one episode part per episode (the episode part last, so a finished episode is one that has
    /// it), and the invocation's figures under sessions/. Prints per-suite success rates at the
    /// end. Running the same command again skips finished episodes; a different configuration on
    /// the same --out is refused.
    #[command(after_help = run::EXAMPLES)]
    Run(run::Args),
    /// Per-suite and per-task success rates with Wilson 95% intervals, re-scorable.
    ///
    /// Scores the stored steps of one or more runs (queries/results.sql, results_by_task.sql)
    /// under a success definition (--success) and an optional shorter cap (--cap), without
    /// re-running anything; prints the tables and writes results.csv and results_by_task.csv to
    /// --out.
    #[command(after_help = results::EXAMPLES)]
    Results(results::Args),
    /// LIBERO-PRO beside the base suites: rates, drops with intervals, the worst suite.
    ///
    /// For a run holding base suites and their LIBERO-PRO copies: per suite and perturbation the
    /// success rate and the drop from the base suite with intervals, then the worst perturbation
    /// per suite and the LIBERO-PRO total. Prints them and writes robustness.csv and
    /// robustness_summary.csv to --out.
    #[command(after_help = robustness::EXAMPLES)]
    Robustness(robustness::Args),
    /// LIBERO-Plus scored by category: rates, drops from the base rate, the leaderboard.
    ///
    /// For a run of a LIBERO-Plus spec table: per suite and category the success rate and the
    /// drop from the base rate (paired with each variant's unperturbed twin), then the categories
    /// beside the published leaderboard. Writes generalisation.csv and generalisation_summary.csv
    /// to --out; a run of LIBERO-PRO's robustness cases also gets pro_robustness_cases.csv.
    #[command(after_help = generalisation::EXAMPLES)]
    Generalisation(generalisation::Args),
    /// One primary failure mode per failed episode, and their counts per suite.
    ///
    /// Classifies each failed episode by queries/failure_modes.sql; prints the counts per suite and
    /// writes failure_modes.csv (one row per failed episode, with its evidence) and
    /// failure_summary.csv to --out.
    #[command(after_help = failures::EXAMPLES)]
    Failures(failures::Args),
    /// Tables and a self-contained report.html for one or more runs.
    ///
    /// The first --run is the subject; further runs are shown beside it. Writes to --out the
    /// CSVs (results, results_by_task, failure_modes, failure_summary, published_comparison, and
    /// the robustness and generalisation tables when the run has those suites) and report.html,
    /// which embeds the smoke pictures (<out>/smoke) and failure videos (<out>/failures, made
    /// first with --videos) and needs nothing beside it.
    #[command(after_help = report::EXAMPLES)]
    Report(report::Args),
    /// Merge a run's one-episode parts into a few large Parquet files per table.
    ///
    /// Rewrites the run's steps and episodes parts in place (atomic, resumable, idempotent,
    /// contents checked), which makes re-scoring a large run much faster. `pipeline run` does it
    /// by itself at the end of a run of at least --compact-at episodes.
    #[command(after_help = compact::EXAMPLES)]
    Compact(compact::Args),
    /// Ad-hoc SQL over a run (specs, steps, episodes, manifest, scored, published).
    ///
    /// Prints the query's result as a table (--csv: CSV). Views: scored (episode outcomes under
    /// --success and --cap), failure_modes, robustness; table published (published LIBERO
    /// numbers). Functions: wilson(success [, level]), wilson_lo/wilson_hi(k, n [, level]),
    /// mcnemar_exact_p(b, c), newcombe_paired_lo/hi(n11, n10, n01, n00 [, level]),
    /// sample_size_two_proportions(p1, p2 [, alpha [, power]]) and DataFusion's built-ins. Without
    /// --run, only the functions and published.
    #[command(after_help = sql::EXAMPLES)]
    Sql(sql::Args),
    /// Paired comparison of two runs on their common episodes (McNemar, Newcombe).
    ///
    /// Both runs are scored alike; per suite and per task it prints the rates, the difference B −
    /// A with a paired interval and McNemar's exact p, and the episodes of one run only. Writes
    /// compare.csv, compare_by_task.csv and compare_first_actions.csv (how far the two runs'
    /// first actions are apart on the same observation) to --out.
    #[command(after_help = compare::EXAMPLES)]
    Compare(compare::Args),
    /// Trials per task needed to detect a difference in success rate.
    ///
    /// Prints the trials per task and the episodes per policy, for one task and for a suite of
    /// --tasks tasks, to tell a reference rate --p0 from --p0 + --delta at the given significance
    /// level and power (two independent proportions, normal approximation; runs paired on the same
    /// episodes, `pipeline compare`, usually need fewer). Writes nothing.
    #[command(after_help = sample_size::EXAMPLES)]
    SampleSize(sample_size::Args),
    /// One picture per suite (agentview | eye-in-hand, task 0, init 0) to look at first.
    ///
    /// Renders a task's init state as the policy's cameras see it, upright, with the suite, task
    /// and instruction as a caption: one PNG per suite, <out>/<suite>.png. Look at them before
    /// trusting anything else; `pipeline report` embeds them.
    #[command(after_help = smoke::EXAMPLES)]
    Smoke(smoke::Args),
    /// MP4s of stored episodes, made by replaying their actions (checks determinism).
    ///
    /// Resets the env to each episode's init state and seed and replays its stored actions (no
    /// policy needed); every replayed step must reproduce the stored goal and end-effector
    /// position (ALOHA-sim: the reward and joints), else it fails naming the first step that
    /// differs. Writes one MP4 per --episode to --out, named {suite}_task{i}_init{j}.mp4.
    #[command(after_help = video::VIDEO_EXAMPLES)]
    Video(video::Args),
    /// MP4s of selected failures (per suite: the first, and one per failure mode).
    ///
    /// The episodes queries/video_selection.sql picks: per suite, the first failed episode and the
    /// first episode of each failure mode, replayed as `pipeline video` does. Writes the MP4s and
    /// selection.csv (the selected rows and their file names) to --out, which `pipeline report`
    /// embeds.
    #[command(after_help = video::VIDEOS_EXAMPLES)]
    Videos(video::SelectedArgs),
    /// A run's episodes (its failures by default) as a LeRobotDataset training code reads.
    ///
    /// Replays each chosen episode's stored actions as `pipeline video` does (checking every step
    /// against the stored one) and writes lerobot 0.6.1's dataset layout (v3.0) to --out: Parquet
    /// frames (state, action, next.success, next.done), an MP4 per camera and episode, meta/info.json,
    /// stats.json, tasks and episodes, and meta/libero_eval.json (which run and episode each came
    /// from). Nothing is written unless every episode replays.
    #[command(after_help = export::EXAMPLES)]
    Export(export::Args),
    /// Ballista scheduler with our functions (for `--engine ballista://HOST:PORT`).
    ///
    /// Runs until stopped. Executors (`pipeline executor`) register with it and commands given
    /// `--engine ballista://HOST:PORT` submit their queries to it; it plans, the executors run
    /// the episodes and queries. Writes nothing itself.
    #[cfg(feature = "distributed")]
    #[command(after_help = distributed::scheduler::EXAMPLES)]
    Scheduler(distributed::scheduler::Args),
    /// Ballista executor with our functions: runs distributed runs' episodes here.
    ///
    /// Runs until stopped. Registers with the scheduler, runs the episodes it is given with this
    /// machine's bundles and cores, and writes their parts to the run's location (which every
    /// executor must reach: an object store, or a shared folder).
    #[cfg(feature = "distributed")]
    #[command(after_help = distributed::executor::EXAMPLES)]
    Executor(distributed::executor::Args),
    /// Benchmarks that print figures (e.g. `pipeline bench sim`).
    ///
    /// Speed figures live here, not in the tests. Each benchmark prints its figures and writes
    /// nothing.
    #[command(subcommand, after_help = bench::EXAMPLES)]
    Bench(bench::Bench),
    /// What a run on this machine would use and why; each problem with its fix.
    ///
    /// Checks libtorch (its version, whether its CUDA backend loaded and from where), the GPUs
    /// (driver, devices, what libtorch sees), the EGL renderer a run's cameras get (NVIDIA or
    /// Mesa's software renderer; MUJOCO_EGL_DEVICE_ID), the linked MuJoCo, which suites have task
    /// bundles and whether their files are intact, the ALOHA-sim bundle, the reference venv and
    /// the free disk space. Exits with status 1 when a check fails. Writes nothing.
    #[command(after_help = doctor::EXAMPLES)]
    Doctor(doctor::Args),
    /// Print this command line's reference as Markdown (docs/src/cli.md), from its own --help.
    #[command(hide = true)]
    CliReference,
}

fn main() -> anyhow::Result<()> {
    // libtorch's CUDA backend beside the CPU libraries this binary links, before any tch call
    // (libero_policies::cuda_backend); the outcome is recorded, and a model never falls back to
    // the CPU silently because of it (models::cpu_fallback)
    libero_policies::cuda_backend::load();
    // before any thread: libtorch reads it at its first attention call (see the function)
    libero_policies::placement::keep_cudnn_attention_last();
    let cli = Cli::parse();
    let bundles = || bundles_location::resolve(cli.bundles.as_deref());
    match cli.command {
        Command::Tasks(args) => tasks::run(bundles, args),
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
        Command::Export(args) => export::run(&bundles()?, args),
        #[cfg(feature = "distributed")]
        Command::Scheduler(args) => distributed::scheduler::run(args),
        #[cfg(feature = "distributed")]
        Command::Executor(args) => distributed::executor::run(&bundles()?, args),
        Command::Bench(bench::Bench::Run(args)) => bench_run::run(args),
        Command::Doctor(args) => doctor::run(cli.bundles.as_deref(), args),
        Command::CliReference => {
            print!("{}", cli_reference::markdown(<Cli as clap::CommandFactory>::command()));
            Ok(())
        }
        Command::Bench(b) => bench::run(&bundles()?, b),
    }
}
