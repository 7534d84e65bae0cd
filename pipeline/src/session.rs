//! A DataFusion session over a stored run: the tables `specs`, `steps`, `episodes`, `manifest`,
//! the view `scored` (episode outcomes under a success definition), and our UDFs; plus the table
//! `published` (the published LIBERO numbers, [`crate::published`]).

use crate::engine::Engine;
use anyhow::{Context, Result};
use datafusion::datasource::file_format::parquet::ParquetFormat;
use datafusion::datasource::listing::{ListingOptions, ListingTable, ListingTableConfig, ListingTableUrl};
use datafusion::prelude::{ParquetReadOptions, SessionConfig, SessionContext};
use libero_schema::tables;
use libero_udfs::run_store::RunStore;
use std::sync::Arc;

/// How episodes are scored from their goal evidence (`queries/score.sql`).
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
/// `scored` view; shared by `results`, `sql` and `compare`), and the engine that runs the queries.
#[derive(clap::Args, Clone)]
pub struct Scoring {
    /// Success definition used to score the stored steps (the `scored` view).
    #[arg(long, value_enum, default_value_t = SuccessDefinition::AnyStep)]
    pub success: SuccessDefinition,
    /// Score as if episodes were capped at this many policy steps (never longer than they ran).
    #[arg(long)]
    pub cap: Option<u32>,
    #[command(flatten)]
    pub engine: crate::engine::EngineArg,
}

impl Scoring {
    /// Open a session on the run at `location`, scored this way, on this engine.
    pub async fn open_run(&self, location: &str) -> Result<(SessionContext, RunStore)> {
        open_on(&self.engine.engine, location, self.success, self.cap).await
    }

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
        self.scoring.open_run(&self.run).await
    }
}

/// The SQL that derives every reported number, compiled in so the binary runs anywhere; the
/// files in `queries/` are the source. With `LIBERO_QUERIES=<dir>` the files are read from that
/// folder instead, so a user's edited selection or threshold takes effect without a rebuild.
pub mod queries {
    use anyhow::{Context, Result};

    pub const SCORE: &str = "score";
    pub const SCORE_FROM_STEPS: &str = "score_from_steps";
    pub const RESULTS: &str = "results";
    pub const RESULTS_BY_TASK: &str = "results_by_task";
    pub const COMPARE_PAIRS: &str = "compare_pairs";
    pub const COMPARE: &str = "compare";
    pub const COMPARE_BY_TASK: &str = "compare_by_task";
    pub const COMPARE_FIRST_ACTIONS: &str = "compare_first_actions";
    pub const SAMPLE_SIZE: &str = "sample_size";
    pub const FAILURE_MODES: &str = "failure_modes";
    /// ALOHA-sim's `failure_modes` (from the reward stages), defined in an ALOHA-sim run's session.
    pub const ALOHA_FAILURE_MODES: &str = "aloha_failure_modes";
    pub const FAILURE_SUMMARY: &str = "failure_summary";
    pub const VIDEO_SELECTION: &str = "video_selection";
    pub const PUBLISHED_COMPARISON: &str = "published_comparison";
    pub const ROBUSTNESS: &str = "robustness";
    pub const ROBUSTNESS_SUMMARY: &str = "robustness_summary";
    pub const STEP_TIMING: &str = "step_timing";
    pub const PROTOCOL_PROJECTION: &str = "protocol_projection";
    pub const GENERALISATION: &str = "generalisation";
    pub const GENERALISATION_SUMMARY: &str = "generalisation_summary";
    pub const PRO_ROBUSTNESS_CASES: &str = "pro_robustness_cases";
    pub const REAL_TIME: &str = "real_time";

    const COMPILED: &[(&str, &str)] = &[
        (SCORE, include_str!("../../queries/score.sql")),
        (SCORE_FROM_STEPS, include_str!("../../queries/score_from_steps.sql")),
        (RESULTS, include_str!("../../queries/results.sql")),
        (RESULTS_BY_TASK, include_str!("../../queries/results_by_task.sql")),
        (COMPARE_PAIRS, include_str!("../../queries/compare_pairs.sql")),
        (COMPARE, include_str!("../../queries/compare.sql")),
        (COMPARE_BY_TASK, include_str!("../../queries/compare_by_task.sql")),
        (COMPARE_FIRST_ACTIONS, include_str!("../../queries/compare_first_actions.sql")),
        (SAMPLE_SIZE, include_str!("../../queries/sample_size.sql")),
        (FAILURE_MODES, include_str!("../../queries/failure_modes.sql")),
        (ALOHA_FAILURE_MODES, include_str!("../../queries/aloha_failure_modes.sql")),
        (FAILURE_SUMMARY, include_str!("../../queries/failure_summary.sql")),
        (VIDEO_SELECTION, include_str!("../../queries/video_selection.sql")),
        (PUBLISHED_COMPARISON, include_str!("../../queries/published_comparison.sql")),
        (ROBUSTNESS, include_str!("../../queries/robustness.sql")),
        (ROBUSTNESS_SUMMARY, include_str!("../../queries/robustness_summary.sql")),
        (STEP_TIMING, include_str!("../../queries/step_timing.sql")),
        (PROTOCOL_PROJECTION, include_str!("../../queries/protocol_projection.sql")),
        (GENERALISATION, include_str!("../../queries/generalisation.sql")),
        (GENERALISATION_SUMMARY, include_str!("../../queries/generalisation_summary.sql")),
        (PRO_ROBUSTNESS_CASES, include_str!("../../queries/pro_robustness_cases.sql")),
        (REAL_TIME, include_str!("../../queries/real_time.sql")),
    ];

    /// The text of `queries/<name>.sql`: from `$LIBERO_QUERIES` when set, else compiled in.
    pub fn text(name: &str) -> Result<String> {
        if let Some(dir) = std::env::var_os("LIBERO_QUERIES") {
            let path = std::path::Path::new(&dir).join(format!("{name}.sql"));
            return std::fs::read_to_string(&path)
                .with_context(|| format!("LIBERO_QUERIES is set but {} cannot be read", path.display()));
        }
        COMPILED
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| t.to_string())
            .with_context(|| format!("no query named {name}"))
    }

    /// The statements of a query file that holds several (each ends with `;` at the end of a
    /// line, before any `--` comment), for files that define views one after another.
    pub fn statements(text: &str) -> Vec<String> {
        let mut out = vec![];
        let mut current = String::new();
        for line in text.lines() {
            current.push_str(line);
            current.push('\n');
            let code = line.split("--").next().unwrap_or("");
            if code.trim_end().ends_with(';') {
                out.push(std::mem::take(&mut current));
            }
        }
        if current.lines().any(|l| !l.trim().is_empty() && !l.trim_start().starts_with("--")) {
            out.push(current);
        }
        out
    }

    /// Run a query file: every statement but the last for its effect (views), the last's batches.
    pub async fn run(
        ctx: &datafusion::prelude::SessionContext,
        name: &str,
    ) -> Result<Vec<arrow::record_batch::RecordBatch>> {
        let mut last = vec![];
        for statement in statements(&text(name)?) {
            last = ctx
                .sql(&statement)
                .await
                .with_context(|| format!("queries/{name}.sql"))?
                .collect()
                .await
                .with_context(|| format!("queries/{name}.sql"))?;
        }
        Ok(last)
    }

    /// Define the views of a query file (every statement but the last), computing nothing.
    pub async fn define_views(ctx: &datafusion::prelude::SessionContext, name: &str) -> Result<()> {
        let statements = statements(&text(name)?);
        for statement in &statements[..statements.len().saturating_sub(1)] {
            ctx.sql(statement).await.with_context(|| format!("queries/{name}.sql"))?.collect().await?;
        }
        Ok(())
    }

    #[cfg(test)]
    mod tests {
        #[test]
        fn statements_split_at_semicolons_that_end_a_line_outside_comments() {
            let text = "-- a; comment;\nCREATE VIEW a AS SELECT 1; -- one\nSELECT ';' AS x\nFROM a;\n-- trailing\n";
            let s = super::statements(text);
            assert_eq!(s.len(), 2, "{s:?}");
            assert!(s[0].contains("CREATE VIEW a"));
            assert!(s[1].starts_with("SELECT"));
        }
    }
}

/// Open a session on the run at `location`, with `scored` defined by `success` and `cap`.
/// A session with our functions and the `published` table but no run: for SQL that needs none.
pub fn functions_only() -> Result<SessionContext> {
    let ctx = SessionContext::new_with_config(SessionConfig::new().with_information_schema(true));
    libero_udfs::register_analysis_functions(&ctx);
    crate::published::register(&ctx)?;
    Ok(ctx)
}

pub async fn open(location: &str, success: SuccessDefinition, cap: Option<u32>) -> Result<(SessionContext, RunStore)> {
    open_on(&Engine::Local, location, success, cap).await
}

/// [`open`] on an engine: this process, or a Ballista cluster (whose nodes read the run's files
/// themselves, so the location must be one they reach).
pub async fn open_on(
    engine: &Engine,
    location: &str,
    success: SuccessDefinition,
    cap: Option<u32>,
) -> Result<(SessionContext, RunStore)> {
    let store = RunStore::connect(location).await?;
    // A compaction killed after its commit is finished first, so no row is seen twice.
    libero_udfs::compaction::recover(&store).await?;
    let Some(manifest) = store.read_manifest().await? else {
        anyhow::bail!("{} holds no run (no manifest.json); start one with `pipeline run`", store.url());
    };
    let ctx = match engine {
        Engine::Local => SessionContext::new_with_config(SessionConfig::new().with_information_schema(true)),
        #[cfg(feature = "distributed")]
        Engine::Ballista { host, port } => {
            if store.url().scheme() == "memory" {
                anyhow::bail!("a memory:// run cannot be read by a cluster's executors");
            }
            crate::distributed::client::remote_session(host, *port).await?
        }
        #[cfg(not(feature = "distributed"))]
        Engine::Ballista { .. } => {
            engine.check().await?;
            unreachable!("Engine::check refuses a Ballista engine in this build")
        }
    };
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
        // the spec's extra columns, carried through; its keys and `protocol` are stored columns
        let stored = tables::episodes();
        episode_fields
            .extend(spec_schema.fields().iter().filter(|f| stored.field_with_name(f.name()).is_err()).cloned());
    }
    // Damaged parts (see RunStore::damaged_parts) are skipped, with both parts of their episode,
    // and named: the numbers then cover the other episodes, and `pipeline run` re-runs these.
    let damaged = store.damaged_parts().await?;
    let skip: std::collections::BTreeSet<String> = damaged.iter().map(|d| d.name.clone()).collect();
    for d in &damaged {
        eprintln!(
            "warning: {} has a damaged part {d}; its episode is left out of every table here              (`pipeline run` with the same spec table sets it aside and runs the episode again)",
            store.url()
        );
    }
    let steps_schema = match manifest.env {
        libero_schema::Benchmark::Libero => tables::steps(),
        libero_schema::Benchmark::AlohaSim => tables::aloha_steps(),
    };
    register_listing(&ctx, &store, "steps", steps_schema, &skip).await?;
    register_listing(&ctx, &store, "episodes", Arc::new(arrow::datatypes::Schema::new(episode_fields)), &skip).await?;
    if store.get("manifest.parquet").await?.is_some() {
        ctx.register_parquet("manifest", store.table_url("manifest.parquet"), ParquetReadOptions::default()).await?;
    }
    let evidence = if manifest.tables_version >= 3 { Evidence::GoalChanges } else { Evidence::Steps };
    define_scored(&ctx, success, cap, evidence).await?;
    // Views only: nothing is computed until a query reads them.
    // each benchmark's failure modes read its own steps table (LIBERO's: the end-effector,
    // contacts and goal terms; ALOHA-sim's: the reward stages)
    queries::run(
        &ctx,
        match manifest.env {
            libero_schema::Benchmark::Libero => queries::FAILURE_MODES,
            libero_schema::Benchmark::AlohaSim => queries::ALOHA_FAILURE_MODES,
        },
    )
    .await?;
    queries::define_views(&ctx, queries::ROBUSTNESS).await?;
    Ok((ctx, store))
}

/// Register a table folder of the run (`steps/`, `episodes/`): the whole folder, or, when some
/// parts must be skipped, the list of the others.
async fn register_listing(
    ctx: &SessionContext,
    store: &RunStore,
    name: &str,
    schema: arrow::datatypes::SchemaRef,
    skip: &std::collections::BTreeSet<String>,
) -> Result<()> {
    let options = ListingOptions::new(Arc::new(ParquetFormat::default())).with_file_extension(".parquet");
    let config = if skip.is_empty() {
        ListingTableConfig::new(ListingTableUrl::parse(store.table_url(&format!("{name}/")))?)
    } else {
        let urls = store
            .part_names(name)
            .await?
            .into_iter()
            .filter(|p| !skip.contains(p))
            .map(|p| ListingTableUrl::parse(store.table_url(&format!("{name}/{p}"))))
            .collect::<Result<Vec<_>, _>>()?;
        ListingTableConfig::new_with_multi_paths(urls)
    };
    let config = config.with_listing_options(options).with_schema(schema);
    ctx.register_table(name, Arc::new(ListingTable::try_new(config)?))?;
    Ok(())
}

/// Compute a view once and put its rows in its place, so later queries that read it (a summary,
/// a selection) do not derive it again; returns the rows.
/// Whether a `SELECT count(*) ...` query counts any row.
pub async fn counts_any(ctx: &SessionContext, count_query: &str) -> Result<bool> {
    let n = ctx.sql(count_query).await?.collect().await?;
    Ok(n.first()
        .is_some_and(|b| arrow::array::AsArray::as_primitive::<arrow::datatypes::Int64Type>(b.column(0)).value(0) > 0))
}

pub async fn materialize(ctx: &SessionContext, view: &str) -> Result<Vec<arrow::record_batch::RecordBatch>> {
    let df = ctx.table(view).await.with_context(|| format!("no view {view}"))?;
    if is_distributed(ctx) {
        // A cluster's plans cannot carry in-memory tables: the view stays, and is derived again
        // by the queries that read it.
        return df.collect().await.with_context(|| format!("computing {view}"));
    }
    let schema = Arc::new(df.schema().as_arrow().clone());
    let batches = df.collect().await.with_context(|| format!("computing {view}"))?;
    ctx.deregister_table(view)?;
    let table = datafusion::datasource::MemTable::try_new(schema, vec![batches.clone()])?;
    ctx.register_table(view, Arc::new(table))?;
    Ok(batches)
}

/// Whether a session runs its queries on a cluster.
pub fn is_distributed(ctx: &SessionContext) -> bool {
    #[cfg(feature = "distributed")]
    return crate::distributed::run_config::is_distributed(ctx);
    #[cfg(not(feature = "distributed"))]
    {
        let _ = ctx;
        false
    }
}

/// What the `scored` view reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Evidence {
    /// `episodes.goal_changes` (`queries/score.sql`): one row per episode, tables v3 on.
    GoalChanges,
    /// The step rows (`queries/score_from_steps.sql`): runs written before tables v3.
    Steps,
}

/// (Re)define the `scored` view with validated parameters.
pub async fn define_scored(
    ctx: &SessionContext,
    success: SuccessDefinition,
    cap: Option<u32>,
    evidence: Evidence,
) -> Result<()> {
    let query = match evidence {
        Evidence::GoalChanges => queries::SCORE,
        Evidence::Steps => queries::SCORE_FROM_STEPS,
    };
    let sql = queries::text(query)?
        .replace("{{success}}", success.sql_name())
        .replace("{{cap}}", &cap.map_or("NULL".to_string(), |c| c.to_string()));
    ctx.sql(&sql).await.with_context(|| format!("queries/{query}.sql"))?.collect().await?;
    Ok(())
}
