//! `mcnemar_exact_p`, `newcombe_paired_lo` / `_hi` and `sample_size_two_proportions` in SQL,
//! against values computed independently in Python (`scripts/reference/stats_fixtures.py`, printed
//! into `tests/fixtures/`: statsmodels' exact McNemar and sample size, Newcombe's formula on
//! statsmodels' Wilson intervals), and against a published worked example.

use arrow::array::{Array, AsArray};
use arrow::datatypes::{Float64Type, Int64Type};
use datafusion::prelude::SessionContext;

/// Rows of a fixture CSV (comments and the header skipped), parsed as f64.
fn fixture(name: &str) -> Vec<Vec<f64>> {
    let path = libero_e2e::repo_root().join("tests/fixtures").join(name);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let rows: Vec<Vec<f64>> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap_or_else(|e| panic!("{name}: {l}: {e}"))).collect())
        .collect();
    assert!(rows.len() >= 40, "{name}: only {} rows", rows.len());
    rows
}

fn session() -> SessionContext {
    let ctx = SessionContext::new();
    libero_udfs::register_analysis_functions(&ctx);
    ctx
}

/// One row, one Float64 column per expression.
async fn floats(ctx: &SessionContext, sql: &str) -> Vec<Option<f64>> {
    let batches = ctx.sql(sql).await.unwrap_or_else(|e| panic!("{sql}: {e}")).collect().await.unwrap();
    let b = &batches[0];
    (0..b.num_columns())
        .map(|c| {
            let col = b.column(c).as_primitive::<Float64Type>();
            (!col.is_null(0)).then(|| col.value(0))
        })
        .collect()
}

#[tokio::test]
async fn mcnemar_exact_p_matches_statsmodels() {
    let ctx = session();
    let (mut max_abs, mut max_rel) = (0.0f64, 0.0f64);
    for r in fixture("mcnemar_statsmodels.csv") {
        let (b, c, expect) = (r[0] as i64, r[1] as i64, r[2]);
        let p = floats(&ctx, &format!("SELECT mcnemar_exact_p({b}, {c})")).await[0].unwrap();
        let (abs, rel) = ((p - expect).abs(), (p - expect).abs() / expect);
        (max_abs, max_rel) = (max_abs.max(abs), max_rel.max(rel));
        assert!(rel <= 1e-9, "b={b} c={c}: ours {p}, statsmodels {expect}");
    }
    println!("mcnemar_exact_p vs statsmodels: max abs diff {max_abs:e}, max rel diff {max_rel:e}");
    assert_eq!(floats(&ctx, "SELECT mcnemar_exact_p(NULL, 3), mcnemar_exact_p(-1, 3)").await, vec![None, None]);
}

#[tokio::test]
async fn newcombe_paired_matches_the_formula_computed_in_python() {
    let ctx = session();
    let mut max_abs = 0.0f64;
    for r in fixture("newcombe_paired.csv") {
        let [n11, n10, n01, n00] = [r[0], r[1], r[2], r[3]].map(|x| x as i64);
        let (level, lo, hi) = (r[4], r[5], r[6]);
        let args = if level == 0.95 {
            format!("{n11}, {n10}, {n01}, {n00}")
        } else {
            format!("{n11}, {n10}, {n01}, {n00}, {level}")
        };
        let got = floats(&ctx, &format!("SELECT newcombe_paired_lo({args}), newcombe_paired_hi({args})")).await;
        let (glo, ghi) = (got[0].unwrap(), got[1].unwrap());
        max_abs = max_abs.max((glo - lo).abs()).max((ghi - hi).abs());
        assert!(
            (glo - lo).abs() <= 1e-12 && (ghi - hi).abs() <= 1e-12,
            "({n11}, {n10}, {n01}, {n00}) at {level}: ours ({glo}, {ghi}), python ({lo}, {hi})"
        );
        let theta = (n10 - n01) as f64 / (n11 + n10 + n01 + n00) as f64;
        assert!(glo <= theta && theta <= ghi && glo >= -1.0 && ghi <= 1.0);
    }
    println!("newcombe_paired vs python: max abs diff {max_abs:e}");
    assert_eq!(floats(&ctx, "SELECT newcombe_paired_lo(0, 0, 0, 0)").await, vec![None], "n = 0 has no interval");
}

/// The worked example of Fagerland, Lydersen & Laake, *Statistical Analysis of Contingency
/// Tables* (2017), ch. 8 (Cavo et al. 2012, complete response before/after consolidation, as in
/// the R package `contingencytables`' tests): table 59, 6, 16, 80 gives the estimate −0.0621,
/// Newcombe's square-and-add 95% interval (−0.1186, −0.0046) and the exact conditional McNemar
/// P = 0.052479.
#[tokio::test]
async fn the_published_worked_example() {
    let ctx = session();
    let got = floats(
        &ctx,
        "SELECT newcombe_paired_lo(59, 6, 16, 80), newcombe_paired_hi(59, 6, 16, 80), mcnemar_exact_p(6, 16)",
    )
    .await;
    let [lo, hi, p] = [0, 1, 2].map(|i| got[i].unwrap());
    assert_eq!((format!("{lo:.4}"), format!("{hi:.4}")), ("-0.1186".to_string(), "-0.0046".to_string()));
    assert_eq!(format!("{p:.6}"), "0.052479");
}

#[tokio::test]
async fn sample_size_matches_statsmodels() {
    let ctx = session();
    let mut max_rel = 0.0f64;
    for r in fixture("sample_size_statsmodels.csv") {
        let (p1, p2, alpha, power, n) = (r[0], r[1], r[2], r[3], r[4]);
        let ours = libero_udfs::sample_size::two_proportions_n(p1, p2, alpha, power).unwrap();
        max_rel = max_rel.max((ours - n).abs() / n);
        assert!((ours - n).abs() <= 1e-9 * n, "p1={p1} p2={p2} α={alpha} power={power}: ours {ours}, statsmodels {n}");
        let sql = format!("SELECT sample_size_two_proportions({p1}, {p2}, {alpha}, {power})");
        let batches = ctx.sql(&sql).await.unwrap().collect().await.unwrap();
        let got = batches[0].column(0).as_primitive::<Int64Type>().value(0);
        assert_eq!(got, n.ceil() as i64, "{sql}");
    }
    println!("sample size vs statsmodels: max rel diff {max_rel:e}");
    // the defaults are alpha 0.05, power 0.8
    let batches = ctx
        .sql("SELECT sample_size_two_proportions(0.8, 0.9), sample_size_two_proportions(0.8, 0.8)")
        .await
        .unwrap()
        .collect()
        .await
        .unwrap();
    let col = |i: usize| batches[0].column(i).as_primitive::<Int64Type>().clone();
    assert_eq!(col(0).value(0), 199);
    assert!(col(1).is_null(0), "no difference to detect: NULL");
}
