//! A DataFusion session over a stored run: the tables `specs`, `steps`, `episodes`, `manifest`,
//! the view `scored` (episode outcomes under a success definition), and our UDFs; plus the table
//! `published` (the published LIBERO numbers, [`crate::published`]).

use anyhow::{Context, Result};
use datafusion::datasource::file_format::parquet::ParquetFormat;
use datafusion::datasource::listing::{ListingOptions, ListingTable, ListingTableConfig, ListingTableUrl};
use datafusion::prelude::{ParquetReadOptions, SessionConfig, SessionContext};
use libero_schema::tables;
use libero_udfs::run_store::RunStore;
use std::sync::Arc;

/// How episodes are scored from their steps (`queries/score.sql`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SuccessDefinition {
    /// Success if the goal held at any policy step within the cap (the published scripts stop at
    /// the first success, so this is what they report).
    AnyStep,
    /// Success if the goal held at the last policy step within the cap (the episode's end state).
    LastStep,
}

impl SuccessDefinition {
    pub fn sql_name(self) -> &'static str {
        match self {
            SuccessDefinition::AnyStep => "any-step",
            SuccessDefinition::LastStep => "last-step",
        }
    }
}

/// How stored steps are scored: the success definition and an optional shorter cap (the
/// `scored` view; shared by `results`, `sql` and `compare`).
#[derive(clap::Args, Clone, Copy)]
pub struct Scoring {
    /// Success definition used to score the stored steps (the `scored` view).
    #[arg(long, value_enum, default_value_t = SuccessDefinition::AnyStep)]
    pub success: SuccessDefinition,
    /// Score as if episodes were capped at this many policy steps (never longer than they ran).
    #[arg(long)]
    pub cap: Option<u32>,
}

impl Scoring {
    /// "any-step" or "last-step, cap 40 policy steps": how tables printed under it were scored.
    pub fn describe(&self) -> String {
        format!("{}{}", self.success.sql_name(), self.cap.map_or(String::new(), |c| format!(", cap {c} policy steps")))
    }
}

/// Which run to open and how its `scored` view scores episodes (shared by `results` and `sql`).
#[derive(clap::Args)]
pub struct RunScoring {
    /// The run (folder or object-store URL).
    #[arg(long)]
    pub run: String,
    #[command(flatten)]
    pub scoring: Scoring,
}

impl RunScoring {
    pub async fn open(&self) -> Result<(SessionContext, RunStore)> {
        open(&self.run, self.scoring.success, self.scoring.cap).await
    }
}

/// The SQL that derives every reported number, compiled in so the binary runs anywhere; the
/// files in `queries/` are the source.
pub mod queries {
    pub const SCORE: &str = include_str!("../../queries/score.sql");
    pub const RESULTS: &str = include_str!("../../queries/results.sql");
    pub const RESULTS_BY_TASK: &str = include_str!("../../queries/results_by_task.sql");
    pub const COMPARE_PAIRS: &str = include_str!("../../queries/compare_pairs.sql");
    pub const COMPARE: &str = include_str!("../../queries/compare.sql");
    pub const COMPARE_BY_TASK: &str = include_str!("../../queries/compare_by_task.sql");
    pub const SAMPLE_SIZE: &str = include_str!("../../queries/sample_size.sql");
}

/// Open a session on the run at `location`, with `scored` defined by `success` and `cap`.
pub async fn open(location: &str, success: SuccessDefinition, cap: Option<u32>) -> Result<(SessionContext, RunStore)> {
    let store = RunStore::open(location)?;
    if store.read_manifest().await?.is_none() {
        anyhow::bail!("{} holds no run (no manifest.json); start one with `pipeline run`", store.url());
    }
    let ctx = SessionContext::new_with_config(SessionConfig::new().with_information_schema(true));
    if store.base_url().scheme() != "file" {
        ctx.register_object_store(store.base_url(), store.object_store());
    }
    libero_udfs::register_analysis_functions(&ctx);
    crate::published::register(&ctx)?;

    let has_specs = store.get("specs.parquet").await?.is_some();
    let mut episode_fields: Vec<_> = tables::episodes().fields().iter().cloned().collect();
    if has_specs {
        ctx.register_parquet("specs", store.table_url("specs.parquet"), ParquetReadOptions::default()).await?;
        let spec_schema = ctx.table("specs").await?.schema().as_arrow().clone();
        episode_fields.extend(
            spec_schema.fields().iter().filter(|f| !tables::SPEC_COLUMNS.iter().any(|(n, _)| n == f.name())).cloned(),
        );
    }
    register_listing(&ctx, &store, "steps", tables::steps()).await?;
    register_listing(&ctx, &store, "episodes", Arc::new(arrow::datatypes::Schema::new(episode_fields))).await?;
    if store.get("manifest.parquet").await?.is_some() {
        ctx.register_parquet("manifest", store.table_url("manifest.parquet"), ParquetReadOptions::default()).await?;
    }
    define_scored(&ctx, success, cap).await?;
    Ok((ctx, store))
}

async fn register_listing(
    ctx: &SessionContext,
    store: &RunStore,
    name: &str,
    schema: arrow::datatypes::SchemaRef,
) -> Result<()> {
    let url = ListingTableUrl::parse(store.table_url(&format!("{name}/")))?;
    let options = ListingOptions::new(Arc::new(ParquetFormat::default())).with_file_extension(".parquet");
    let config = ListingTableConfig::new(url).with_listing_options(options).with_schema(schema);
    ctx.register_table(name, Arc::new(ListingTable::try_new(config)?))?;
    Ok(())
}

/// (Re)define the `scored` view from `queries/score.sql` with validated parameters.
pub async fn define_scored(ctx: &SessionContext, success: SuccessDefinition, cap: Option<u32>) -> Result<()> {
    let sql = queries::SCORE
        .replace("{{success}}", success.sql_name())
        .replace("{{cap}}", &cap.map_or("NULL".to_string(), |c| c.to_string()));
    ctx.sql(&sql).await.context("queries/score.sql")?.collect().await?;
    Ok(())
}
