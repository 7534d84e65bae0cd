//! `pipeline sql "<query>" --run RUN`: ad-hoc SQL over a stored run.
//!
//! Tables: `specs`, `steps`, `episodes`, `manifest`, and the view `scored` (episode outcomes under
//! `--success` / `--cap`, from `queries/score.sql`); `published` (published LIBERO numbers).
//! Functions: `wilson(success [, level])`, `wilson_lo(k, n [, level])`, `wilson_hi(k, n [, level])`,
//! `mcnemar_exact_p(b, c)`, `newcombe_paired_lo/hi(n11, n10, n01, n00 [, level])`,
//! `sample_size_two_proportions(p1, p2 [, alpha [, power]])` and DataFusion's built-ins.

use crate::session::RunScoring;
use anyhow::Result;

#[derive(clap::Args)]
pub struct Args {
    /// The SQL query, e.g. "SELECT suite, wilson(success) FROM episodes GROUP BY suite".
    query: String,
    #[command(flatten)]
    scoring: RunScoring,
    /// Print CSV instead of a table.
    #[arg(long)]
    csv: bool,
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, _) = args.scoring.open().await?;
        let batches = ctx.sql(&args.query).await?.collect().await?;
        if args.csv {
            let mut w = arrow::csv::WriterBuilder::new().with_header(true).build(std::io::stdout());
            for b in &batches {
                w.write(b)?;
            }
        } else {
            println!("{}", arrow::util::pretty::pretty_format_batches(&batches)?);
        }
        Ok(())
    })
}
