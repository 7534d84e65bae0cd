//! `pipeline results --run RUN`: the per-suite and per-task tables (`queries/results.sql`,
//! `queries/results_by_task.sql`) under a chosen success definition and cap, printed and written
//! as CSV. Re-scoring never re-runs anything: it is the same stored steps, another query.

use crate::session::{self, RunScoring};
use anyhow::{Context, Result};
use arrow::array::{AsArray, RecordBatch};
use arrow::datatypes::Float64Type;
use libero_policies::PolicySpec;
use std::path::{Path, PathBuf};

/// A baseline scoring above this is a broken success check or protocol, not a result.
pub const BASELINE_MAX_SUCCESS: f64 = 0.05;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    scoring: RunScoring,
    /// Folder for results.csv and results_by_task.csv.
    #[arg(long, default_value = "outputs")]
    out: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, store) = args.scoring.open().await?;
        let manifest = store.read_manifest().await?.context("the run has no manifest")?;
        let suites = ctx.sql(session::queries::RESULTS).await?.collect().await?;
        let tasks = ctx.sql(session::queries::RESULTS_BY_TASK).await?.collect().await?;
        std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
        write_csv(&args.out.join("results.csv"), &suites)?;
        write_csv(&args.out.join("results_by_task.csv"), &tasks)?;
        println!(
            "success definition: {}{}",
            args.scoring.success.sql_name(),
            args.scoring.cap.map_or(String::new(), |c| format!(", cap {c} policy steps"))
        );
        println!("{}", arrow::util::pretty::pretty_format_batches(&suites)?);
        println!("wrote {}/results.csv and results_by_task.csv", args.out.display());
        if let Ok(policy) = manifest.policy.parse::<PolicySpec>() {
            warn_on_baseline(&policy, &suites);
        }
        Ok(())
    })
}

pub fn write_csv(path: &Path, batches: &[RecordBatch]) -> Result<()> {
    let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut w = arrow::csv::WriterBuilder::new().with_header(true).build(file);
    for b in batches {
        w.write(b)?;
    }
    Ok(())
}

/// Warn loudly when a baseline policy scores above [`BASELINE_MAX_SUCCESS`] on any suite.
/// Returns the offending (suite, rate) pairs.
pub fn warn_on_baseline(policy: &PolicySpec, suites: &[RecordBatch]) -> Vec<(String, f64)> {
    if !policy.is_baseline() {
        return vec![];
    }
    let mut bad = vec![];
    for b in suites {
        let (Some(suite), Some(rate)) = (b.column_by_name("suite"), b.column_by_name("success_rate")) else {
            continue;
        };
        let (suite, rate) = (suite.as_string::<i32>(), rate.as_primitive::<Float64Type>());
        for i in 0..b.num_rows() {
            if rate.value(i) > BASELINE_MAX_SUCCESS {
                bad.push((suite.value(i).to_string(), rate.value(i)));
            }
        }
    }
    for (suite, rate) in &bad {
        eprintln!(
            "\n!!! WARNING: the baseline policy `{policy}` scored {:.1}% on {suite} (> {:.0}%).\n!!! A baseline must fail: the success check, the protocol or the bundles are broken. Do not trust this run's numbers.\n",
            rate * 100.0,
            BASELINE_MAX_SUCCESS * 100.0
        );
    }
    bad
}
