//! # pipeline
//!
//! The command-line entry point of the LIBERO evaluation pipeline. Each subcommand lives in its
//! own module under `commands/`; this file only parses arguments and dispatches.

mod bench;
mod tasks;

use clap::{Parser, Subcommand};
use std::path::PathBuf;

/// Evaluate VLA policies on LIBERO: task bundles, the MuJoCo environment, runs and results.
#[derive(Parser)]
#[command(name = "pipeline", version, about)]
struct Cli {
    /// Folder of task bundles (built by ./setup.sh).
    #[arg(long, global = true, default_value = "data/bundles", env = "LIBERO_BUNDLES")]
    bundles: PathBuf,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List suites, tasks and instructions from the task bundles.
    Tasks(tasks::Args),
    /// Benchmarks that print figures (e.g. `pipeline bench sim`).
    #[command(subcommand)]
    Bench(bench::Bench),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Tasks(args) => tasks::run(&cli.bundles, args),
        Command::Bench(b) => bench::run(&cli.bundles, b),
    }
}
