//! `pipeline sql "<query>" [--run RUN]`: ad-hoc SQL over a stored run.
//!
//! Tables: `specs`, `steps`, `episodes`, `manifest`, and the views `scored` (episode outcomes under
//! `--success` / `--cap`, from `queries/score.sql`), `failure_modes` and `robustness` (LIBERO-PRO
//! cells beside their base suites, `queries/robustness.sql`); `published` (published LIBERO numbers).
//! Functions: `wilson(success [, level])`, `wilson_lo(k, n [, level])`, `wilson_hi(k, n [, level])`,
//! `mcnemar_exact_p(b, c)`, `newcombe_paired_lo/hi(n11, n10, n01, n00 [, level])`,
//! `sample_size_two_proportions(p1, p2 [, alpha [, power]])` and DataFusion's built-ins.
//! Without `--run`, the functions and the `published` table alone (`SELECT wilson_lo(3, 10)`).

use crate::session::Scoring;
use anyhow::Result;

pub const EXAMPLES: &str = "\
Examples:
  pipeline sql \"SELECT suite, wilson(scored_success) FROM scored GROUP BY suite\" --run runs/pi05
  pipeline sql \"SELECT suite, task_id, n_policy_steps FROM episodes\" --run runs/pi05 --csv
  pipeline sql \"SELECT wilson_lo(45, 50), wilson_hi(45, 50)\"          # no run: functions only";

#[derive(clap::Args)]
pub struct Args {
    /// The SQL query, e.g. "SELECT suite, wilson(success) FROM episodes GROUP BY suite".
    query: String,
    /// The run (folder or object-store URL); without it, only the functions and `published`.
    #[arg(long)]
    run: Option<String>,
    #[command(flatten)]
    scoring: Scoring,
    /// Print CSV instead of a table.
    #[arg(long)]
    csv: bool,
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let ctx = match &args.run {
            Some(run) => args.scoring.open_run(run).await?.0,
            None => crate::session::functions_only()?,
        };
        let batches = ctx.sql(&args.query).await?.collect().await?;
        if args.csv {
            let mut w = arrow::csv::WriterBuilder::new().with_header(true).build(std::io::stdout());
            for b in &batches {
                w.write(&nested_as_text(b)?)?;
            }
        } else {
            println!("{}", arrow::util::pretty::pretty_format_batches(&batches)?);
        }
        Ok(())
    })
}

/// CSV has no nested values: list and struct columns (`action`, `eef_pos`, `wilson(..)`) are written
/// as their text, as the table output shows them (`[0.1, 0.2, ...]`, `{n: 10, ...}`).
fn nested_as_text(batch: &arrow::record_batch::RecordBatch) -> Result<arrow::record_batch::RecordBatch> {
    use arrow::array::{ArrayRef, StringArray};
    use arrow::datatypes::{DataType, Field, Schema};
    use arrow::util::display::{ArrayFormatter, FormatOptions};
    use std::sync::Arc;
    let schema = batch.schema();
    let mut fields = Vec::new();
    let mut columns: Vec<ArrayRef> = Vec::new();
    for (field, column) in schema.fields().iter().zip(batch.columns()) {
        if field.data_type().is_nested() {
            let options = FormatOptions::default();
            let formatter = ArrayFormatter::try_new(column.as_ref(), &options)?;
            let text: StringArray =
                (0..column.len()).map(|i| column.is_valid(i).then(|| formatter.value(i).to_string())).collect();
            fields.push(Field::new(field.name(), DataType::Utf8, true));
            columns.push(Arc::new(text));
        } else {
            fields.push(field.as_ref().clone());
            columns.push(column.clone());
        }
    }
    Ok(arrow::record_batch::RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)?)
}
