//! `pipeline results --run RUN`: the per-suite and per-task tables (`queries/results.sql`,
//! `queries/results_by_task.sql`) under a chosen success definition and cap, printed and written
//! as CSV. Re-scoring never re-runs anything: it is the same stored steps, another query.

use crate::session::{self, Scoring};
use anyhow::{Context, Result};
use arrow::array::{AsArray, RecordBatch};
use arrow::datatypes::Float64Type;
use libero_policies::PolicySpec;
use std::path::{Path, PathBuf};

/// A baseline scoring above this is a broken success check or protocol, not a result.
pub const BASELINE_MAX_SUCCESS: f64 = 0.05;

pub const EXAMPLES: &str = "\
Examples:
  pipeline results --run runs/expert
  pipeline results --run runs/pi05 --run runs/random                # a policy beside a baseline
  pipeline results --run runs/pi05 --success last-step --cap 200    # re-scored, nothing re-run";

#[derive(clap::Args)]
pub struct Args {
    /// The run (folder or object-store URL). Repeat it to put several runs side by side (e.g. a
    /// policy and its baselines): one table, one row per (suite, run), each from its own steps.
    #[arg(long, required = true)]
    run: Vec<String>,
    #[command(flatten)]
    scoring: Scoring,
    /// Folder for results.csv and results_by_task.csv.
    #[arg(long, default_value = "outputs")]
    out: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let (mut suites, mut tasks, mut warnings) = (vec![], vec![], vec![]);
        for location in &args.run {
            let (ctx, store) = args.scoring.open_run(location).await?;
            let manifest = store.read_manifest().await?.context("the run has no manifest")?;
            let run_suites = session::queries::run(&ctx, session::queries::RESULTS).await?;
            tasks.extend(session::queries::run(&ctx, session::queries::RESULTS_BY_TASK).await?);
            if let Ok(policy) = manifest.policy.parse::<PolicySpec>() {
                warnings.push((policy, run_suites.clone()));
            }
            suites.extend(run_suites);
        }
        std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
        write_csv(&args.out.join("results.csv"), &suites)?;
        write_csv(&args.out.join("results_by_task.csv"), &tasks)?;
        println!("success definition: {}", args.scoring.describe());
        println!("{}", arrow::util::pretty::pretty_format_batches(&suites)?);
        println!("wrote {}/results.csv and results_by_task.csv", args.out.display());
        for (policy, run_suites) in &warnings {
            warn_on_baseline(policy, run_suites);
        }
        for location in &args.run {
            let (ctx, store) = args.scoring.open_run(location).await?;
            note_perturbed(&ctx).await?;
            if let Some(manifest) = store.read_manifest().await? {
                print_real_time(&ctx, location, &manifest).await?;
            }
        }
        Ok(())
    })
}

/// Say so when a suite's rate pools perturbed episodes (spec perturbation columns): a LIBERO-Plus
/// run's per-suite rate mixes every category with the base rows, and `pipeline generalisation`
/// is the table that separates them.
pub async fn note_perturbed(ctx: &datafusion::prelude::SessionContext) -> Result<()> {
    let rows = ctx
        .sql(
            "SELECT suite, count(*) FILTER (WHERE variant_hash IS NOT NULL) AS perturbed, count(*) AS n \
             FROM episodes GROUP BY suite HAVING count(*) FILTER (WHERE variant_hash IS NOT NULL) > 0 ORDER BY suite",
        )
        .await?
        .collect()
        .await?;
    for b in &rows {
        use arrow::array::AsArray;
        use arrow::datatypes::Int64Type;
        for i in 0..b.num_rows() {
            eprintln!(
                "note: {} pools {} perturbed episodes (spec perturbation columns) of {} in its rate; `pipeline generalisation` (LIBERO-Plus) or a query on perturbation_params separates them",
                b.column(0).as_string::<i32>().value(i),
                b.column(1).as_primitive::<Int64Type>().value(i),
                b.column(2).as_primitive::<Int64Type>().value(i)
            );
        }
    }
    Ok(())
}

/// For a real-time run: its setting and how much of its policy time held (`queries/real_time.sql`).
pub async fn print_real_time(
    ctx: &datafusion::prelude::SessionContext,
    location: &str,
    manifest: &libero_schema::RunManifest,
) -> Result<()> {
    let Some(rt) = manifest.realtime else { return Ok(()) };
    let latency = match rt.latency {
        libero_schema::real_time::Latency::Fixed { ms } => format!("{ms} ms per model query"),
        libero_schema::real_time::Latency::Measured => "each policy call's measured time".to_string(),
    };
    println!(
        "{location} is a real-time run: {} Hz, latency {latency}, hold {} (pipeline compare against its closed-loop run gives the drop)",
        manifest.control_freq_hz,
        rt.hold.name()
    );
    let rows = session::queries::run(ctx, session::queries::REAL_TIME).await?;
    println!("{}", arrow::util::pretty::pretty_format_batches(&rows)?);
    Ok(())
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
