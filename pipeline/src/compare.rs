//! `pipeline compare RUN_A RUN_B`: a paired comparison of two runs on their common episode keys.
//!
//! Two policies (or two configurations) run on the same spec rows see the same init states and
//! fixture poses, so their outcomes are paired and the right test is McNemar's on the discordant
//! episodes, with a paired interval for the difference (Newcombe). Both runs are scored by the
//! same `queries/score.sql` (one `--success` and `--cap` for both); the outcomes meet in the
//! `pairs` view (`queries/compare_pairs.sql`), and `queries/compare.sql` /
//! `queries/compare_by_task.sql` derive every number. Episodes of one run only are counted
//! (`n_only_in_a`, `n_only_in_b`), never silently dropped.
//!
//! Beside the outcomes, the paired episodes' first actions (`queries/compare_first_actions.sql`):
//! policy step 0 sees the same observation in both runs, so runs of one checkpoint computed two
//! ways (quantised, on another device, batched) show there how far the two computations are apart.

use crate::results::write_csv;
use crate::session::{self, Scoring};
use anyhow::{Context, Result};
use arrow::array::{Array, AsArray, RecordBatch};
use arrow::datatypes::Int64Type;
use datafusion::datasource::MemTable;
use datafusion::prelude::SessionContext;
use std::path::PathBuf;
use std::sync::Arc;

pub const EXAMPLES: &str = "\
Examples:
  pipeline compare runs/pi05 runs/pi05-int8         # B - A on the episodes both ran
  pipeline compare runs/a runs/b --success last-step --cap 200";

#[derive(clap::Args)]
pub struct Args {
    /// Run A, the reference (folder or object-store URL).
    run_a: String,
    /// Run B, compared with A: differences are B − A.
    run_b: String,
    /// Applied to both runs' stored steps alike.
    #[command(flatten)]
    scoring: Scoring,
    /// Folder for compare.csv, compare_by_task.csv and compare_first_actions.csv.
    #[arg(long, default_value = "outputs")]
    out: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let ctx = SessionContext::new();
        libero_udfs::register_analysis_functions(&ctx);
        for (suffix, location) in [("a", &args.run_a), ("b", &args.run_b)] {
            let (scored, first_actions) = run_rows(location, &args.scoring).await?;
            ctx.register_table(format!("scored_{suffix}"), Arc::new(scored))?;
            ctx.register_table(format!("first_actions_{suffix}"), Arc::new(first_actions))?;
        }
        session::queries::run(&ctx, session::queries::COMPARE_PAIRS).await?;
        let suites = session::queries::run(&ctx, session::queries::COMPARE).await?;
        let tasks =
            session::queries::run(&ctx, session::queries::COMPARE_BY_TASK).await?;
        let all = overall(&suites);
        if all.n_paired == 0 {
            anyhow::bail!(
                "runs A ({}) and B ({}) share no episode key (suite/task_id/init_state_id/seed): A has {} episodes, B has {}. \
                 A paired comparison needs both runs made from the same spec rows: run both policies on one spec table \
                 (`pipeline specs ... -o specs.parquet`, then `pipeline run specs.parquet --out RUN --policy P` for each).",
                args.run_a,
                args.run_b,
                all.n_only_in_a,
                all.n_only_in_b
            );
        }
        std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
        write_csv(&args.out.join("compare.csv"), &suites)?;
        write_csv(&args.out.join("compare_by_task.csv"), &tasks)?;
        let first_actions = session::queries::run(&ctx, session::queries::COMPARE_FIRST_ACTIONS).await?;
        write_csv(&args.out.join("compare_first_actions.csv"), &first_actions)?;
        let policies = policy_names(&suites);
        println!("A = {} ({})\nB = {} ({})", args.run_a, policies.0, args.run_b, policies.1);
        println!(
            "success definition: {} (both runs); differences are B − A, 95% interval Newcombe (paired), p exact McNemar",
            args.scoring.describe()
        );
        println!("{}", arrow::util::pretty::pretty_format_batches(&display_columns(&suites)?)?);
        if all.n_only_in_a + all.n_only_in_b > 0 {
            eprintln!(
                "note: {} episodes only in A and {} only in B are not paired; they are counted in n_only_in_a / n_only_in_b and in no other number",
                all.n_only_in_a, all.n_only_in_b
            );
        }
        if let Some(line) = first_actions_line(&first_actions) {
            println!("{line}");
        }
        println!("wrote {}/compare.csv, compare_by_task.csv and compare_first_actions.csv", args.out.display());
        Ok(())
    })
}

/// A run's `scored` view (`queries/score.sql`) under the given definition, and its episodes'
/// first actions (`episode_key`, `action` at policy step 0), as in-memory tables (of this
/// process: the paired comparison runs here, whichever engine read the runs).
async fn run_rows(location: &str, scoring: &Scoring) -> Result<(MemTable, MemTable)> {
    let (run_ctx, _) = scoring.open_run(location).await.with_context(|| format!("opening run {location}"))?;
    let mut tables = Vec::new();
    for (what, frame) in [
        ("scoring", run_ctx.table("scored").await?),
        (
            "reading the first actions of",
            run_ctx.sql("SELECT episode_key, action FROM steps WHERE policy_step = 0").await?,
        ),
    ] {
        let schema = Arc::new(frame.schema().as_arrow().clone());
        let batches = frame.collect().await.with_context(|| format!("{what} run {location}"))?;
        tables.push(MemTable::try_new(schema, vec![batches])?);
    }
    let first_actions = tables.pop().expect("two tables");
    Ok((tables.pop().expect("two tables"), first_actions))
}

/// `first actions (policy step 0, the same observation in both runs): 38 of 40 episodes equal in
/// every dimension, 278 of 280 dimensions; largest |B − A| 0.0123, mean 0.0001`, from the one row
/// of `queries/compare_first_actions.sql`; None without paired first actions.
fn first_actions_line(batches: &[RecordBatch]) -> Option<String> {
    let b = batches.iter().find(|b| b.num_rows() > 0)?;
    let int = |name: &str| -> Option<i64> {
        let c = arrow::compute::cast(b.column_by_name(name)?, &arrow::datatypes::DataType::Int64).ok()?;
        Some(c.as_primitive::<Int64Type>().value(0))
    };
    let float = |name: &str| -> Option<f64> {
        let c = arrow::compute::cast(b.column_by_name(name)?, &arrow::datatypes::DataType::Float64).ok()?;
        let c = c.as_primitive::<arrow::datatypes::Float64Type>();
        c.is_valid(0).then(|| c.value(0))
    };
    let (n, all_equal, dims_equal, dims): (i64, i64, i64, i64) =
        (int("n_episodes")?, int("n_episodes_all_equal")?, int("n_dims_equal")?, int("n_dims")?);
    if n == 0 {
        return None;
    }
    Some(format!(
        "first actions (policy step 0, the same observation in both runs): {all_equal} of {n} episodes equal in every \
         dimension, {dims_equal} of {dims} dimensions; largest |B - A| {:.4}, mean {:.4}",
        float("max_abs_diff")?,
        float("mean_abs_diff")?
    ))
}

/// The columns printed to the terminal (the CSV has them all).
fn display_columns(batches: &[RecordBatch]) -> Result<Vec<RecordBatch>> {
    const SHOWN: [&str; 12] = [
        "suite",
        "n_paired",
        "success_rate_a",
        "success_rate_b",
        "n_a_only",
        "n_b_only",
        "diff_b_minus_a",
        "diff_ci_lo",
        "diff_ci_hi",
        "mcnemar_p",
        "n_only_in_a",
        "n_only_in_b",
    ];
    batches
        .iter()
        .map(|b| {
            let indices = SHOWN.map(|name| b.schema().index_of(name)).into_iter().collect::<Result<Vec<_>, _>>()?;
            Ok(b.project(&indices)?)
        })
        .collect()
}

/// The policies of runs A and B, as the `all` row of `queries/compare.sql` names them.
fn policy_names(suites: &[RecordBatch]) -> (String, String) {
    let mut names = (String::new(), String::new());
    for b in suites {
        let col = |n: &str| b.column_by_name(n).expect("compare.sql column").as_string::<i32>().clone();
        let (suite, a, bb) = (col("suite"), col("policy_a"), col("policy_b"));
        for i in (0..b.num_rows()).filter(|&i| suite.value(i) == "all") {
            names = (a.value(i).to_string(), bb.value(i).to_string());
        }
    }
    names
}

/// The counts of the `all` row of `queries/compare.sql`.
struct Overall {
    n_paired: i64,
    n_only_in_a: i64,
    n_only_in_b: i64,
}

fn overall(suites: &[RecordBatch]) -> Overall {
    let mut o = Overall { n_paired: 0, n_only_in_a: 0, n_only_in_b: 0 };
    for b in suites {
        let suite = b.column_by_name("suite").expect("compare.sql has suite").as_string::<i32>();
        let col = |n: &str| b.column_by_name(n).expect("compare.sql column").as_primitive::<Int64Type>().clone();
        let (paired, only_a, only_b) = (col("n_paired"), col("n_only_in_a"), col("n_only_in_b"));
        for i in (0..b.num_rows()).filter(|&i| suite.value(i) == "all") {
            o = Overall { n_paired: paired.value(i), n_only_in_a: only_a.value(i), n_only_in_b: only_b.value(i) };
        }
    }
    o
}
