//! `pipeline robustness --run RUN`: LIBERO-PRO scored beside the base suites. Per base suite ×
//! perturbation the success rate with its Wilson interval and the drop from the base suite with
//! an interval for the difference (`queries/robustness.sql`), then per suite the worst
//! perturbation, which suite falls most, and the LIBERO-PRO total as the authors compute it
//! beside theirs (`queries/robustness_summary.sql`). The run holds the base suites and their
//! perturbed copies (`pipeline specs --suites libero_goal,libero_goal_swap,...`, or the four
//! suites and `libero_pro`).

use crate::results::write_csv;
use crate::session::{self, Scoring};
use anyhow::{Result, bail};
use arrow::array::RecordBatch;
use std::path::PathBuf;

pub const EXAMPLES: &str = "\
Examples:
  pipeline specs --suites libero_goal,libero_goal_swap,libero_goal_object -o pro.parquet
  pipeline run pro.parquet --out runs/pro --policy openpi:ws://localhost:8000
  pipeline robustness --run runs/pro";

#[derive(clap::Args)]
pub struct Args {
    /// The run (folder or object-store URL), holding base suites and their LIBERO-PRO copies.
    #[arg(long)]
    run: String,
    #[command(flatten)]
    scoring: Scoring,
    /// Folder for robustness.csv and robustness_summary.csv.
    #[arg(long, default_value = "outputs")]
    out: PathBuf,
}

/// The two tables of a run's session (the `robustness` view stays defined on it).
pub async fn tables(ctx: &datafusion::prelude::SessionContext) -> Result<(Vec<RecordBatch>, Vec<RecordBatch>)> {
    let cells = session::queries::run(ctx, session::queries::ROBUSTNESS).await?;
    let summary = session::queries::run(ctx, session::queries::ROBUSTNESS_SUMMARY).await?;
    Ok((cells, summary))
}

/// Does the session's run hold any LIBERO-PRO suite? (LIBERO-Plus's `plus_layout` suites are
/// `generalisation`'s.)
pub async fn has_perturbations(ctx: &datafusion::prelude::SessionContext) -> Result<bool> {
    session::counts_any(ctx, "SELECT count(*) AS n FROM scored WHERE perturbation NOT IN ('none', 'plus_layout')").await
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, _) = args.scoring.open_run(&args.run).await?;
        if !has_perturbations(&ctx).await? {
            bail!(
                "{} holds no LIBERO-PRO suite; run one beside its base suite (e.g. `pipeline specs --suites libero_goal,libero_goal_swap`; bundles: ./setup.sh --suites libero_goal_swap)",
                args.run
            );
        }
        let (cells, summary) = tables(&ctx).await?;
        std::fs::create_dir_all(&args.out)?;
        write_csv(&args.out.join("robustness.csv"), &cells)?;
        write_csv(&args.out.join("robustness_summary.csv"), &summary)?;
        println!("success definition: {}", args.scoring.describe());
        println!("{}", arrow::util::pretty::pretty_format_batches(&summary)?);
        println!("wrote {0}/robustness.csv (per cell, with intervals) and {0}/robustness_summary.csv", args.out.display());
        Ok(())
    })
}
