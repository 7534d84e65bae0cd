//! `pipeline compact RUN`: merge a run's one-episode parts into a few large Parquet files per
//! table (`libero_udfs::compaction`: atomic, resumable, idempotent, contents checked).

use anyhow::Result;
use libero_udfs::compaction;
use libero_udfs::run_store::RunStore;

pub const EXAMPLES: &str = "\
Examples:
  pipeline compact runs/pi05
  pipeline compact s3://bucket/runs/pi05";

#[derive(clap::Args)]
pub struct Args {
    /// The run (folder or object-store URL); finished or partly finished, not being written.
    run: String,
}

pub fn run(args: Args) -> Result<()> {
    tokio::runtime::Runtime::new()?.block_on(async {
        let store = RunStore::connect(&args.run).await?;
        let t0 = std::time::Instant::now();
        let r = compaction::compact(&store).await?;
        println!(
            "compacted {}: {} episodes; steps/ {} -> {} files, episodes/ {} -> {} files; {} step rows and {} episode rows, \
             contents equal before and after; {:.1} s",
            store.url(),
            r.episodes,
            r.files_before[0],
            r.files_after[0],
            r.files_before[1],
            r.files_after[1],
            r.digests[0].rows,
            r.digests[1].rows,
            t0.elapsed().as_secs_f64()
        );
        Ok(())
    })
}
