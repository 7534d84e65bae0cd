//! `pipeline failures --run RUN`: one primary failure mode per failed episode
//! (`queries/failure_modes.sql`) and their counts per suite (`queries/failure_summary.sql`), to
//! `outputs/failure_modes.csv` and `outputs/failure_summary.csv`.

use crate::results::write_csv;
use crate::session::{self, RunScoring};
use anyhow::{Context, Result};
use std::path::PathBuf;

pub const EXAMPLES: &str = "\
Examples:
  pipeline failures --run runs/pi05
  pipeline failures --run runs/pi05 --success last-step --out outputs/last-step";

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scoring: RunScoring,
    /// Folder for failure_modes.csv and failure_summary.csv.
    #[arg(long, default_value = "outputs")]
    out: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, _) = args.scoring.open().await?;
        session::materialize(&ctx, "failure_modes").await.context("queries/failure_modes.sql")?;
        let episodes = ctx.sql("SELECT * FROM failure_modes ORDER BY suite, task_id, init_state_id, seed").await?.collect().await?;
        let summary = session::queries::run(&ctx, session::queries::FAILURE_SUMMARY).await?;
        std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
        write_csv(&args.out.join("failure_modes.csv"), &episodes)?;
        write_csv(&args.out.join("failure_summary.csv"), &summary)?;
        println!("success definition: {}", args.scoring.scoring.describe());
        println!("{}", arrow::util::pretty::pretty_format_batches(&summary)?);
        let n: usize = episodes.iter().map(|b| b.num_rows()).sum();
        println!(
            "{n} failed episodes; wrote {0}/failure_modes.csv (one row per failed episode, with its evidence) and {0}/failure_summary.csv",
            args.out.display()
        );
        Ok(())
    })
}
