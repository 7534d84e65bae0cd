//! `wilson`, `wilson_lo`, `wilson_hi` in SQL against intervals computed independently by
//! statsmodels (`proportion_confint(method="wilson")`, printed into
//! `tests/fixtures/wilson_statsmodels.csv`), k = 0 and k = n included.

use arrow::array::{AsArray, RecordBatch};
use arrow::datatypes::{Float64Type, Int64Type};
use datafusion::prelude::SessionContext;

struct Case {
    k: i64,
    n: i64,
    level: f64,
    lo: f64,
    hi: f64,
}

fn cases() -> Vec<Case> {
    let text = std::fs::read_to_string(libero_e2e::repo_root().join("tests/fixtures/wilson_statsmodels.csv")).unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with('k'))
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            Case {
                k: v[0].parse().unwrap(),
                n: v[1].parse().unwrap(),
                level: v[2].parse().unwrap(),
                lo: v[3].parse().unwrap(),
                hi: v[4].parse().unwrap(),
            }
        })
        .collect()
}

async fn query(ctx: &SessionContext, sql: &str) -> Vec<RecordBatch> {
    ctx.sql(sql).await.unwrap_or_else(|e| panic!("{sql}: {e}")).collect().await.unwrap()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12
}

#[tokio::test]
async fn scalar_bounds_match_statsmodels() {
    let ctx = SessionContext::new();
    libero_udfs::register_analysis_functions(&ctx);
    let cases = cases();
    assert!(cases.len() >= 40 && cases.iter().any(|c| c.k == 0) && cases.iter().any(|c| c.k == c.n));
    for c in &cases {
        let sql = if c.level == 0.95 {
            format!("SELECT wilson_lo({k}, {n}) AS lo, wilson_hi({k}, {n}) AS hi", k = c.k, n = c.n)
        } else {
            format!(
                "SELECT wilson_lo({k}, {n}, {l}) AS lo, wilson_hi({k}, {n}, {l}) AS hi",
                k = c.k,
                n = c.n,
                l = c.level
            )
        };
        let b = &query(&ctx, &sql).await[0];
        let lo = b.column(0).as_primitive::<Float64Type>().value(0);
        let hi = b.column(1).as_primitive::<Float64Type>().value(0);
        assert!(
            close(lo, c.lo) && close(hi, c.hi),
            "k={} n={} level={}: ours ({lo}, {hi}) statsmodels ({}, {})",
            c.k,
            c.n,
            c.level,
            c.lo,
            c.hi
        );
    }
    let b = &query(&ctx, "SELECT wilson_lo(0, 0) AS lo").await[0];
    assert!(b.column(0).is_null(0), "n = 0 has no interval");
}

#[tokio::test]
async fn the_aggregate_returns_n_k_rate_and_the_bounds() {
    let ctx = SessionContext::new();
    libero_udfs::register_analysis_functions(&ctx);
    for c in cases().iter().filter(|c| c.n <= 500) {
        // n rows of which k are true, in 3 partitions' worth of batches, plus a NULL that is skipped
        let sql = format!(
            "SELECT wilson(v < {k}, {l}) AS w FROM (SELECT value AS v FROM generate_series(0, {last}) UNION ALL SELECT NULL) t",
            k = c.k,
            l = c.level,
            last = c.n - 1
        );
        let b = &query(&ctx, &sql).await[0];
        let w = b.column(0).as_struct();
        let get = |name: &str| w.column_by_name(name).unwrap().clone();
        assert_eq!(get("n").as_primitive::<Int64Type>().value(0), c.n);
        assert_eq!(get("k").as_primitive::<Int64Type>().value(0), c.k);
        let rate = get("rate").as_primitive::<Float64Type>().value(0);
        assert!(close(rate, c.k as f64 / c.n as f64));
        let (lo, hi) =
            (get("lo").as_primitive::<Float64Type>().value(0), get("hi").as_primitive::<Float64Type>().value(0));
        assert!(close(lo, c.lo) && close(hi, c.hi), "k={} n={}: ({lo}, {hi}) vs ({}, {})", c.k, c.n, c.lo, c.hi);
    }
}

#[tokio::test]
async fn grouped_wilson_over_a_table() {
    let ctx = SessionContext::new();
    libero_udfs::register_analysis_functions(&ctx);
    let sql = "SELECT g, wilson(s)['k'] AS k, wilson(s)['n'] AS n FROM (VALUES ('a', true), ('a', false), ('b', true)) t(g, s) GROUP BY g ORDER BY g";
    let b = &query(&ctx, sql).await[0];
    assert_eq!(b.column(1).as_primitive::<Int64Type>().values(), &[1, 1]);
    assert_eq!(b.column(2).as_primitive::<Int64Type>().values(), &[2, 1]);
}
