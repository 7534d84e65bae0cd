//! `pipeline generalisation --run RUN`: LIBERO-Plus scored by category. Per base suite × category
//! (and per category × difficulty, suites pooled, when the spec has the authors' labels) the success rate with its Wilson interval
//! and the drop from the same policy's base rate with an interval for the difference
//! (`queries/generalisation.sql`: paired with each variant's unperturbed twin when the run has
//! them); then this run's categories beside the published leaderboard with
//! its three totals, labelled (`queries/generalisation_summary.sql`). The run holds a LIBERO-Plus
//! spec table's rows (`pipeline specs --benchmark libero-plus`): the variants and the base rows.
//!
//! A run of LIBERO-PRO's robustness cases (`pipeline specs --benchmark libero-pro-robustness`) is
//! scored the same way, per suite × case with the drop paired to each row's unperturbed twin
//! (`queries/pro_robustness_cases.sql`). A run may hold both.

use crate::results::write_csv;
use crate::session::{self, Scoring};
use anyhow::{Result, bail};
use arrow::array::RecordBatch;
use std::path::PathBuf;

pub const EXAMPLES: &str = "\
Examples:
  pipeline specs --benchmark libero-plus --suites libero_spatial --per-category 20 -o plus.parquet
  pipeline run plus.parquet --out runs/plus --policy openpi:ws://localhost:8000
  pipeline generalisation --run runs/plus";

#[derive(clap::Args)]
pub struct Args {
    /// The run (folder or object-store URL) of a LIBERO-Plus spec table.
    #[arg(long)]
    run: String,
    #[command(flatten)]
    scoring: Scoring,
    /// Folder for generalisation.csv and generalisation_summary.csv.
    #[arg(long, default_value = "outputs")]
    out: PathBuf,
}

/// Does the session's run hold rows of spec benchmark `benchmark` (the specs' `benchmark` column)?
async fn has_benchmark_rows(ctx: &datafusion::prelude::SessionContext, benchmark: &str) -> Result<bool> {
    let episodes = ctx.table("episodes").await?;
    let schema = episodes.schema();
    if !schema.has_column_with_unqualified_name("benchmark") || !schema.has_column_with_unqualified_name("category") {
        return Ok(false);
    }
    session::counts_any(ctx, &format!("SELECT count(*) FROM episodes WHERE benchmark = '{benchmark}'")).await
}

/// Does the session's run hold LIBERO-Plus rows?
pub async fn has_plus_rows(ctx: &datafusion::prelude::SessionContext) -> Result<bool> {
    has_benchmark_rows(ctx, "libero_plus").await
}

/// Does the session's run hold LIBERO-PRO robustness-case rows?
pub async fn has_pro_robustness_rows(ctx: &datafusion::prelude::SessionContext) -> Result<bool> {
    has_benchmark_rows(ctx, "libero_pro_robustness").await
}

/// The named columns of a query's batches, as a printable table.
fn columns_table(batches: &[RecordBatch], columns: &[&str]) -> Result<String> {
    let all = arrow::compute::concat_batches(&batches[0].schema(), batches)?;
    let project: Vec<usize> = columns.iter().map(|c| all.schema().index_of(c)).collect::<Result<_, _>>()?;
    Ok(arrow::util::pretty::pretty_format_batches(&[all.project(&project)?])?.to_string())
}

/// LIBERO-PRO's robustness cases, per suite × case.
pub async fn pro_robustness_cases(ctx: &datafusion::prelude::SessionContext) -> Result<Vec<RecordBatch>> {
    session::queries::run(ctx, session::queries::PRO_ROBUSTNESS_CASES).await
}

/// The two tables of a run's session (the `generalisation` view stays defined on it).
pub async fn tables(ctx: &datafusion::prelude::SessionContext) -> Result<(Vec<RecordBatch>, Vec<RecordBatch>)> {
    let cells = session::queries::run(ctx, session::queries::GENERALISATION).await?;
    let summary = session::queries::run(ctx, session::queries::GENERALISATION_SUMMARY).await?;
    Ok((cells, summary))
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, _) = args.scoring.open_run(&args.run).await?;
        let (plus, pro) = (has_plus_rows(&ctx).await?, has_pro_robustness_rows(&ctx).await?);
        if !plus && !pro {
            bail!(
                "{} holds neither LIBERO-Plus rows (benchmark = 'libero_plus') nor LIBERO-PRO robustness-case rows (benchmark = 'libero_pro_robustness'); make a spec table with `pipeline specs --benchmark libero-plus` or `--benchmark libero-pro-robustness` and run it",
                args.run
            );
        }
        std::fs::create_dir_all(&args.out)?;
        if pro {
            let cases = pro_robustness_cases(&ctx).await?;
            write_csv(&args.out.join("pro_robustness_cases.csv"), &cases)?;
            let table = columns_table(
                &cases,
                &[
                    "base_suite",
                    "robustness_case",
                    "n_total",
                    "n_errors",
                    "success_rate",
                    "ci_lo",
                    "ci_hi",
                    "paired",
                    "base_rate",
                    "drop_from_base",
                    "drop_lo",
                    "drop_hi",
                    "mcnemar_p",
                ],
            )?;
            println!("LIBERO-PRO robustness cases (success definition: {})", args.scoring.describe());
            println!("{table}");
            println!("wrote {}/pro_robustness_cases.csv", args.out.display());
            if !plus {
                return Ok(());
            }
        }
        let (cells, summary) = tables(&ctx).await?;
        write_csv(&args.out.join("generalisation.csv"), &cells)?;
        write_csv(&args.out.join("generalisation_summary.csv"), &summary)?;
        println!("success definition: {}", args.scoring.describe());
        let table = columns_table(
            &cells,
            &[
                "base_suite",
                "category",
                "difficulty",
                "n_total",
                "n_errors",
                "success_rate",
                "ci_lo",
                "ci_hi",
                "paired",
                "base_rate",
                "base_n_errors",
                "drop_from_base",
                "drop_lo",
                "drop_hi",
                "suite_base_rate",
            ],
        )?;
        println!("{table}");
        println!("{}", arrow::util::pretty::pretty_format_batches(&summary)?);
        println!("(n_errors, base_n_errors: episodes that ended in an error row, counted as failures in the rates)");
        println!(
            "wrote {0}/generalisation.csv (per suite × category, with intervals) and {0}/generalisation_summary.csv",
            args.out.display()
        );
        Ok(())
    })
}
