//! `pipeline sql "<query>" --run RUN`: ad-hoc SQL over a stored run.
//!
//! Tables: `specs`, `steps`, `episodes`, `manifest`, and the view `scored` (episode outcomes under
//! `--success` / `--cap`, from `queries/score.sql`). Functions: `wilson(success [, level])`,
//! `wilson_lo(k, n [, level])`, `wilson_hi(k, n [, level])` and DataFusion's built-ins.

use crate::session::{self, SuccessDefinition};
use anyhow::Result;

#[derive(clap::Args)]
pub struct Args {
    /// The SQL query, e.g. "SELECT suite, wilson(success) FROM episodes GROUP BY suite".
    query: String,
    /// The run (folder or object-store URL).
    #[arg(long)]
    run: String,
    /// Success definition of the `scored` view.
    #[arg(long, value_enum, default_value_t = SuccessDefinition::AnyStep)]
    success: SuccessDefinition,
    /// Episode cap of the `scored` view, in policy steps.
    #[arg(long)]
    cap: Option<u32>,
    /// Print CSV instead of a table.
    #[arg(long)]
    csv: bool,
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let (ctx, _) = session::open(&args.run, args.success, args.cap).await?;
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
