//! `pipeline sample-size --p0 0.8 --delta 0.1`: how many trials per task a run needs to detect a
//! difference in success rate, before spending the compute (`queries/sample_size.sql`, the UDF
//! `sample_size_two_proportions`: two independent proportions, normal approximation with the
//! pooled variance under the null, Fleiss et al. eq. 4.14 without continuity correction).

use crate::session;
use anyhow::{Context, Result};
use datafusion::prelude::SessionContext;

pub const EXAMPLES: &str = "\
Examples:
  pipeline sample-size --p0 0.8 --delta 0.1             # detect 80% -> 90%
  pipeline sample-size --p0 0.95 --delta -0.05 --power 0.9";

#[derive(clap::Args)]
pub struct Args {
    /// Success rate of the reference policy.
    #[arg(long)]
    p0: f64,
    /// Difference to detect (p1 = p0 + delta; negative for a drop).
    #[arg(long, allow_hyphen_values = true)]
    delta: f64,
    /// Two-sided significance level.
    #[arg(long, default_value_t = libero_udfs::sample_size::DEFAULT_ALPHA)]
    alpha: f64,
    /// Power (probability of detecting the difference when it is real).
    #[arg(long, default_value_t = libero_udfs::sample_size::DEFAULT_POWER)]
    power: f64,
    /// Tasks per suite (LIBERO suites have 10).
    #[arg(long, default_value_t = 10)]
    tasks: u32,
}

pub fn run(args: Args) -> Result<()> {
    let p1 = ((args.p0 + args.delta) * 1e12).round() / 1e12;
    let unit = |x: f64| (0.0..=1.0).contains(&x);
    let open = |x: f64| x > 0.0 && x < 1.0;
    if !unit(args.p0) || !unit(p1) || args.delta == 0.0 {
        anyhow::bail!(
            "--p0 {} --delta {} gives p1 = {p1}: both rates must lie in [0, 1] and delta must not be 0",
            args.p0,
            args.delta
        );
    }
    if !open(args.alpha) || !open(args.power) || args.tasks == 0 {
        anyhow::bail!("--alpha and --power must lie in (0, 1) and --tasks be at least 1");
    }
    let sql = session::queries::text(session::queries::SAMPLE_SIZE)?
        .replace("{{p0}}", &format!("{:?}", args.p0))
        .replace("{{p1}}", &format!("{p1:?}"))
        .replace("{{alpha}}", &format!("{:?}", args.alpha))
        .replace("{{power}}", &format!("{:?}", args.power))
        .replace("{{tasks}}", &args.tasks.to_string());
    tokio::runtime::Runtime::new()?.block_on(async {
        let ctx = SessionContext::new();
        libero_udfs::register_analysis_functions(&ctx);
        let batches = ctx.sql(&sql).await.context("queries/sample_size.sql")?.collect().await?;
        println!(
            "trials per policy to detect {} → {p1} (two-sided α = {}, power {}; two independent proportions, normal approximation, pooled null variance):",
            args.p0, args.alpha, args.power
        );
        println!("{}", arrow::util::pretty::pretty_format_batches(&batches)?);
        println!("runs paired on the same episode keys (pipeline compare) usually need fewer: an upper bound for them");
        Ok(())
    })
}
