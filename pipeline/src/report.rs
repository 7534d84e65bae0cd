//! `pipeline report --run RUN [--run RUN2 ..]`: the tables and one self-contained HTML page.
//!
//! Every number on the page comes from a query over the stored rows (`queries/results.sql`,
//! `results_by_task.sql`, `failure_summary.sql`, `published_comparison.sql`,
//! `video_selection.sql`, `generalisation.sql`/`generalisation_summary.sql` for a run with LIBERO-Plus
//! rows, and `robustness.sql`/`robustness_summary.sql` for a run with LIBERO-PRO
//! suites); this module only lays them out. The page needs nothing beside it:
//! plots are inline SVG, pictures and videos are embedded as data URLs, and its one script (a
//! filter on the comparison table) is inline. The first run is the subject (its failure videos are
//! shown); further runs (baselines, another checkpoint) are shown beside it.

mod html;

use crate::results::write_csv;
use crate::session::{self, Scoring, queries};
use anyhow::{Context, Result};
use arrow::record_batch::RecordBatch;
use html::Page;
use libero_schema::RunManifest;
use std::path::{Path, PathBuf};

pub const EXAMPLES: &str = "\
Examples:
  pipeline report --run runs/pi05                             # outputs/report.html
  pipeline report --run runs/pi05 --run runs/random --videos  # beside a baseline, with videos";

#[derive(clap::Args)]
pub struct Args {
    /// The run(s); the first is the subject of the report, the others are shown beside it.
    #[arg(long = "run", required = true)]
    runs: Vec<String>,
    #[command(flatten)]
    scoring: Scoring,
    /// Folder for the CSVs and report.html; smoke pictures are read from <out>/smoke and failure
    /// videos from <out>/failures (`pipeline smoke`, `pipeline videos`).
    #[arg(long, default_value = "outputs")]
    out: PathBuf,
    /// Render the first run's selected failure videos first (`pipeline videos`), into <out>/failures.
    #[arg(long)]
    videos: bool,
    /// Largest video set embedded in the page (MB); beyond it videos are linked, not embedded.
    #[arg(long, default_value_t = 40)]
    embed_videos_mb: u64,
}

/// The query results of one run, as the page and the CSVs need them.
pub struct RunTables {
    pub location: String,
    pub manifest: RunManifest,
    pub suites: Vec<RecordBatch>,
    pub tasks: Vec<RecordBatch>,
    pub failure_summary: Vec<RecordBatch>,
    pub failure_modes: Vec<RecordBatch>,
    pub published: Vec<RecordBatch>,
    pub selection: Vec<RecordBatch>,
    /// LIBERO-PRO beside the base suites (`queries/robustness*.sql`): empty when the run holds no
    /// perturbed suite.
    pub robustness: Vec<RecordBatch>,
    pub robustness_summary: Vec<RecordBatch>,
    /// LIBERO-Plus by category (`queries/generalisation*.sql`): empty when the run holds no
    /// LIBERO-Plus rows.
    pub generalisation: Vec<RecordBatch>,
    pub generalisation_summary: Vec<RecordBatch>,
    /// LIBERO-PRO's robustness cases (`queries/pro_robustness_cases.sql`): empty when the run holds
    /// none of their rows.
    pub pro_robustness_cases: Vec<RecordBatch>,
}

pub fn run(bundles: &Path, args: Args) -> Result<()> {
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    if args.videos {
        crate::video::render_selection(bundles, &args.runs[0], args.scoring.clone(), &args.out.join("failures"))?;
    }
    let runtime = tokio::runtime::Runtime::new()?;
    let tables: Vec<RunTables> =
        args.runs.iter().map(|location| runtime.block_on(query_run(location, &args.scoring))).collect::<Result<_>>()?;

    let all =
        |f: fn(&RunTables) -> &Vec<RecordBatch>| tables.iter().flat_map(|t| f(t).iter().cloned()).collect::<Vec<_>>();
    write_csv(&args.out.join("results.csv"), &all(|t| &t.suites))?;
    write_csv(&args.out.join("results_by_task.csv"), &all(|t| &t.tasks))?;
    write_csv(&args.out.join("failure_modes.csv"), &all(|t| &t.failure_modes))?;
    write_csv(&args.out.join("failure_summary.csv"), &all(|t| &t.failure_summary))?;
    write_csv(&args.out.join("published_comparison.csv"), &all(|t| &t.published))?;
    if tables.iter().any(|t| !t.robustness.is_empty()) {
        write_csv(&args.out.join("robustness.csv"), &all(|t| &t.robustness))?;
        write_csv(&args.out.join("robustness_summary.csv"), &all(|t| &t.robustness_summary))?;
    }
    if tables.iter().any(|t| !t.generalisation.is_empty()) {
        write_csv(&args.out.join("generalisation.csv"), &all(|t| &t.generalisation))?;
        write_csv(&args.out.join("generalisation_summary.csv"), &all(|t| &t.generalisation_summary))?;
    }
    if tables.iter().any(|t| !t.pro_robustness_cases.is_empty()) {
        write_csv(&args.out.join("pro_robustness_cases.csv"), &all(|t| &t.pro_robustness_cases))?;
    }

    let page = Page::build(&tables, &args.scoring.describe(), &args.out, args.embed_videos_mb * 1_000_000)?;
    let path = args.out.join("report.html");
    std::fs::write(&path, page.html).with_context(|| format!("writing {}", path.display()))?;
    println!("success definition: {}", args.scoring.describe());
    println!("{}", arrow::util::pretty::pretty_format_batches(&all(|t| &t.suites))?);
    for w in &page.warnings {
        eprintln!("!!! {w}");
    }
    println!(
        "wrote {0}/report.html ({1} KB), results.csv, results_by_task.csv, failure_modes.csv, failure_summary.csv, published_comparison.csv",
        args.out.display(),
        std::fs::metadata(&path)?.len() / 1000
    );
    Ok(())
}

async fn query_run(location: &str, scoring: &Scoring) -> Result<RunTables> {
    let (ctx, store) = scoring.open_run(location).await?;
    let manifest = store.read_manifest().await?.context("the run has no manifest")?;
    session::materialize(&ctx, "failure_modes").await.context("queries/failure_modes.sql")?;
    let failure_modes =
        ctx.sql("SELECT * FROM failure_modes ORDER BY suite, task_id, init_state_id, seed").await?.collect().await?;
    let (robustness, robustness_summary) = if crate::robustness::has_perturbations(&ctx).await? {
        crate::robustness::tables(&ctx).await?
    } else {
        (vec![], vec![])
    };
    let (generalisation, generalisation_summary) = if crate::generalisation::has_plus_rows(&ctx).await? {
        crate::generalisation::tables(&ctx).await?
    } else {
        (vec![], vec![])
    };
    let pro_robustness_cases = if crate::generalisation::has_pro_robustness_rows(&ctx).await? {
        crate::generalisation::pro_robustness_cases(&ctx).await?
    } else {
        vec![]
    };
    Ok(RunTables {
        pro_robustness_cases,
        generalisation,
        generalisation_summary,
        location: location.to_string(),
        manifest,
        suites: queries::run(&ctx, queries::RESULTS).await?,
        tasks: queries::run(&ctx, queries::RESULTS_BY_TASK).await?,
        failure_summary: queries::run(&ctx, queries::FAILURE_SUMMARY).await?,
        failure_modes,
        published: queries::run(&ctx, queries::PUBLISHED_COMPARISON).await?,
        selection: queries::run(&ctx, queries::VIDEO_SELECTION).await?,
        robustness,
        robustness_summary,
    })
}
