//! The published LIBERO numbers as the SQL table `published` (`data/published_libero.csv`).
//!
//! A success rate measured here means something only next to the published ones *and* their
//! protocols (trials per task, episode caps, success check), which differ between papers. The
//! CSV keeps one row per (model, variant, reporter, suite[, perturbation]) with those protocol
//! columns, transcribed from `shared/reference/field.md` §1–2 (never estimated: an unknown cell is
//! empty and the `note` says so). `benchmark` is `libero` (the four suites; rows reported by the
//! authors, by ports, and independent re-runs), `libero-pro` (per suite × perturbation dimension,
//! plus `total`) or `libero-plus` (per perturbation dimension over all suites, `suite` empty).
//! Rates are fractions in [0, 1]. The file is compiled into the binary, so every session has it:
//!
//! ```sql
//! SELECT model, variant, suite, success_rate, trials_per_task, episode_cap
//! FROM published WHERE benchmark = 'libero' AND reported_by = 'authors' ORDER BY model, suite
//! ```

use anyhow::{Context, Result};
use arrow::array::RecordBatch;
use arrow::datatypes::{DataType, Field, Schema, SchemaRef};
use datafusion::catalog::view::ViewTable;
use datafusion::datasource::MemTable;
use datafusion::prelude::SessionContext;
use std::sync::Arc;

/// The CSV as committed (`data/published_libero.csv`).
pub const CSV: &str = include_str!("../../data/published_libero.csv");

/// The table's columns, in file order.
pub fn schema() -> SchemaRef {
    let f = |name: &str, t: DataType, nullable: bool| Field::new(name, t, nullable);
    Arc::new(Schema::new(vec![
        f("benchmark", DataType::Utf8, false),
        f("model", DataType::Utf8, false),
        f("variant", DataType::Utf8, true),
        f("reported_by", DataType::Utf8, false),
        f("suite", DataType::Utf8, true),
        f("perturbation", DataType::Utf8, true),
        f("success_rate", DataType::Float64, false),
        f("reported_pm", DataType::Float64, true),
        f("trials_per_task", DataType::Int32, true),
        f("seeds_averaged", DataType::Int32, true),
        f("episode_cap", DataType::Int32, true),
        f("wait_steps", DataType::Int32, true),
        f("success_definition", DataType::Utf8, true),
        f("stop_on_success", DataType::Boolean, true),
        f("source", DataType::Utf8, false),
        f("note", DataType::Utf8, true),
    ]))
}

/// Parse the CSV (empty cells are NULL).
pub fn batches() -> Result<Vec<RecordBatch>> {
    let reader = arrow::csv::ReaderBuilder::new(schema())
        .with_header(true)
        .build(std::io::Cursor::new(CSV))
        .context("data/published_libero.csv")?;
    reader.collect::<Result<Vec<_>, _>>().context("parsing data/published_libero.csv")
}

/// Register the table `published` on a session: in memory, or, on a cluster (whose plans cannot
/// carry in-memory tables), as a view over its rows as literals, the same rows and types.
pub fn register(ctx: &SessionContext) -> Result<()> {
    if crate::session::is_distributed(ctx) {
        ctx.register_table("published", Arc::new(ViewTable::new(values_plan()?, None)))?;
        return Ok(());
    }
    let table = MemTable::try_new(schema(), vec![batches()?])?;
    ctx.register_table("published", Arc::new(table))?;
    Ok(())
}

/// The rows as a `VALUES` plan of typed literals, with the table's column names.
fn values_plan() -> Result<datafusion::logical_expr::LogicalPlan> {
    use datafusion::common::ScalarValue;
    use datafusion::logical_expr::{LogicalPlanBuilder, col, lit};
    let mut rows = vec![];
    for batch in batches()? {
        for r in 0..batch.num_rows() {
            let row = batch
                .columns()
                .iter()
                .map(|c| Ok(lit(ScalarValue::try_from_array(c, r)?)))
                .collect::<Result<Vec<_>>>()?;
            rows.push(row);
        }
    }
    let names = schema()
        .fields()
        .iter()
        .enumerate()
        .map(|(i, f)| col(format!("column{}", i + 1)).alias(f.name()))
        .collect::<Vec<_>>();
    Ok(LogicalPlanBuilder::values(rows)?.project(names)?.build()?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow::array::{Array, AsArray};
    use arrow::datatypes::{Float64Type, Int32Type};
    use libero_schema::Suite;
    use std::collections::{BTreeMap, BTreeSet};

    #[test]
    fn the_csv_parses_with_canonical_suites_rates_in_the_unit_interval_and_notes_for_gaps() {
        let batches = batches().unwrap();
        let rows: usize = batches.iter().map(|b| b.num_rows()).sum();
        assert!(rows >= 100, "{rows} rows");
        let canonical: BTreeSet<String> = Suite::CANONICAL.iter().map(|s| s.name()).collect();
        // suites reported per (benchmark, model, variant, reported_by) of the `libero` rows
        let mut libero: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for b in &batches {
            let s = |n: &str| b.column_by_name(n).unwrap().as_string::<i32>().clone();
            let (bench, model, variant, by, suite, note) =
                (s("benchmark"), s("model"), s("variant"), s("reported_by"), s("suite"), s("note"));
            let rate = b.column_by_name("success_rate").unwrap().as_primitive::<Float64Type>().clone();
            let trials = b.column_by_name("trials_per_task").unwrap().as_primitive::<Int32Type>().clone();
            let cap = b.column_by_name("episode_cap").unwrap().as_primitive::<Int32Type>().clone();
            for i in 0..b.num_rows() {
                let what = format!("row {} {} {}", bench.value(i), model.value(i), suite.value(i));
                assert!((0.0..=1.0).contains(&rate.value(i)), "{what}: rate {}", rate.value(i));
                assert!(!rate.is_null(i) && !b.column_by_name("source").unwrap().is_null(i), "{what}");
                if !suite.is_null(i) {
                    assert!(canonical.contains(suite.value(i)), "{what}: suite {:?}", suite.value(i));
                }
                if trials.is_null(i) || cap.is_null(i) {
                    assert!(!note.is_null(i) && note.value(i).contains("not"), "{what}: a gap without a note");
                }
                match bench.value(i) {
                    "libero" => {
                        assert!(!suite.is_null(i), "{what}: a libero row needs its suite");
                        let key = format!("{} | {} | {}", model.value(i), variant.value(i), by.value(i));
                        assert!(libero.entry(key).or_default().insert(suite.value(i).to_string()), "{what}: twice");
                    }
                    "libero-pro" | "libero-plus" => {}
                    other => panic!("{what}: unknown benchmark {other}"),
                }
            }
        }
        for (key, suites) in &libero {
            assert_eq!(suites.iter().cloned().collect::<BTreeSet<_>>(), canonical, "{key}");
        }
        let models: BTreeSet<&str> = libero.keys().map(|k| k.split(" | ").next().unwrap()).collect();
        for m in ["OpenVLA", "OpenVLA-OFT", "pi0", "pi0-FAST", "pi0.5", "Octo", "Diffusion Policy"] {
            assert!(models.contains(m), "no LIBERO rows for {m}");
        }
    }

    #[tokio::test]
    async fn published_is_a_table_in_sql() {
        let ctx = SessionContext::new();
        register(&ctx).unwrap();
        let sql = "SELECT success_rate, episode_cap, trials_per_task FROM published \
                   WHERE benchmark = 'libero' AND model = 'OpenVLA' AND reported_by = 'authors' AND suite = 'libero_10'";
        let b = &ctx.sql(sql).await.unwrap().collect().await.unwrap()[0];
        assert_eq!(b.num_rows(), 1);
        assert_eq!(b.column(0).as_primitive::<Float64Type>().value(0), 0.537);
        assert_eq!(b.column(1).as_primitive::<Int32Type>().value(0), 520);
        assert_eq!(b.column(2).as_primitive::<Int32Type>().value(0), 50);
        let plus = "SELECT count(*) FROM published WHERE benchmark = 'libero-plus' AND suite IS NULL";
        let b = &ctx.sql(plus).await.unwrap().collect().await.unwrap()[0];
        assert!(b.column(0).as_primitive::<arrow::datatypes::Int64Type>().value(0) >= 88, "Plus rows have no suite");
    }
}
