//! Newcombe's interval for the difference of two paired proportions, as the SQL functions
//! `newcombe_paired_lo(n11, n10, n01, n00 [, level])` / `newcombe_paired_hi(...)`.
//!
//! Two runs on the same episode keys are paired, so the difference of their success rates has a
//! smaller variance than two independent samples would: the interval must use the pairing. This is
//! method 10 of Newcombe (1998), "Improved confidence intervals for the difference between
//! binomial proportions based on paired data", *Statistics in Medicine* 17:2635–2650: the
//! square-and-add combination of the two Wilson score intervals, corrected by the correlation of
//! the paired outcomes. Fagerland, Lydersen & Laake (2014, 2017) recommend it for paired data.
//!
//! With the table `n11` (both succeed), `n10` (first only), `n01` (second only), `n00` (neither),
//! n their sum, p1 = (n11 + n10)/n, p2 = (n11 + n01)/n, θ = p1 − p2, and (l1, u1), (l2, u2) the
//! Wilson intervals of p1 and p2 ([`crate::wilson::wilson_interval`]):
//!
//! ```text
//! A = n11·n00 − n10·n01,   D = (n11+n10)(n01+n00)(n11+n01)(n10+n00)
//! φ = 0                    if D = 0, or 0 ≤ A ≤ n/2
//!     (A − n/2)/√D         if A > n/2
//!     A/√D                 if A < 0
//! lo = θ − √((p1−l1)² − 2φ(p1−l1)(u2−p2) + (u2−p2)²)
//! hi = θ + √((u1−p1)² − 2φ(u1−p1)(p2−l2) + (p2−l2)²)
//! ```
//!
//! The interval is for **first − second**: `pipeline compare` passes run B first, so it bounds
//! B − A. n = 0 or a level outside (0, 1) gives NULL.

use crate::wilson::{DEFAULT_LEVEL, wilson_interval};
use arrow::array::{Array, AsArray, Float64Array};
use arrow::datatypes::{DataType, Float64Type, Int64Type};
use datafusion::common::{Result, plan_err};
use datafusion::logical_expr::{ColumnarValue, ScalarFunctionArgs, ScalarUDF, ScalarUDFImpl, Signature, Volatility};
use std::sync::Arc;

/// Newcombe's method-10 interval for p1 − p2 from the paired table, at `level` (e.g. 0.95).
pub fn newcombe_paired_interval(n11: u64, n10: u64, n01: u64, n00: u64, level: f64) -> Option<(f64, f64)> {
    let n = n11 + n10 + n01 + n00;
    let (l1, u1) = wilson_interval(n11 + n10, n, level)?;
    let (l2, u2) = wilson_interval(n11 + n01, n, level)?;
    let nf = n as f64;
    let p1 = (n11 + n10) as f64 / nf;
    let p2 = (n11 + n01) as f64 / nf;
    let theta = p1 - p2;
    let d = ((n11 + n10) as f64) * ((n01 + n00) as f64) * ((n11 + n01) as f64) * ((n10 + n00) as f64);
    let a = (n11 as f64) * (n00 as f64) - (n10 as f64) * (n01 as f64);
    let phi = if d == 0.0 || (0.0..=nf / 2.0).contains(&a) {
        0.0
    } else if a > nf / 2.0 {
        (a - nf / 2.0) / d.sqrt()
    } else {
        a / d.sqrt()
    };
    let root = |x: f64, y: f64| (x * x - 2.0 * phi * x * y + y * y).max(0.0).sqrt();
    Some((theta - root(p1 - l1, u2 - p2), theta + root(u1 - p1, p2 - l2)))
}

/// `newcombe_paired_lo` / `newcombe_paired_hi`.
#[derive(Debug, PartialEq, Eq, Hash)]
pub struct NewcombePairedBound {
    upper: bool,
    signature: Signature,
}

impl NewcombePairedBound {
    pub fn new(upper: bool) -> Self {
        NewcombePairedBound { upper, signature: Signature::user_defined(Volatility::Immutable) }
    }
}

impl ScalarUDFImpl for NewcombePairedBound {
    fn name(&self) -> &str {
        if self.upper { "newcombe_paired_hi" } else { "newcombe_paired_lo" }
    }
    fn signature(&self) -> &Signature {
        &self.signature
    }
    fn return_type(&self, _arg_types: &[DataType]) -> Result<DataType> {
        Ok(DataType::Float64)
    }
    fn coerce_types(&self, arg_types: &[DataType]) -> Result<Vec<DataType>> {
        let int = |t: &DataType| t.is_integer() || t.is_null();
        match arg_types {
            [a, b, c, d] if [a, b, c, d].into_iter().all(int) => Ok(vec![DataType::Int64; 4]),
            [a, b, c, d, l] if [a, b, c, d].into_iter().all(int) && (l.is_numeric() || l.is_null()) => {
                Ok(vec![DataType::Int64, DataType::Int64, DataType::Int64, DataType::Int64, DataType::Float64])
            }
            _ => plan_err!(
                "{}(n11, n10, n01, n00 INTEGER [, level DOUBLE]): the paired table (both, first only, second only, neither), got {arg_types:?}",
                self.name()
            ),
        }
    }
    fn invoke_with_args(&self, args: ScalarFunctionArgs) -> Result<ColumnarValue> {
        let arrays = ColumnarValue::values_to_arrays(&args.args)?;
        let counts: Vec<_> = arrays[..4].iter().map(|a| a.as_primitive::<Int64Type>()).collect();
        let level = arrays.get(4).map(|a| a.as_primitive::<Float64Type>());
        let out: Float64Array = (0..counts[0].len())
            .map(|i| {
                if counts.iter().any(|c| c.is_null(i) || c.value(i) < 0) || level.is_some_and(|l| l.is_null(i)) {
                    return None;
                }
                let [n11, n10, n01, n00] = [0, 1, 2, 3].map(|j| counts[j].value(i) as u64);
                let lvl = level.map_or(DEFAULT_LEVEL, |l| l.value(i));
                newcombe_paired_interval(n11, n10, n01, n00, lvl).map(|(lo, hi)| if self.upper { hi } else { lo })
            })
            .collect();
        Ok(ColumnarValue::Array(Arc::new(out)))
    }
}

pub fn newcombe_paired_lo_udf() -> ScalarUDF {
    ScalarUDF::from(NewcombePairedBound::new(false))
}

pub fn newcombe_paired_hi_udf() -> ScalarUDF {
    ScalarUDF::from(NewcombePairedBound::new(true))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contains_the_estimate_and_flips_with_the_order() {
        let (lo, hi) = newcombe_paired_interval(40, 3, 9, 48, 0.95).unwrap();
        let theta = (3.0 - 9.0) / 100.0;
        assert!(lo < theta && theta < hi && lo >= -1.0 && hi <= 1.0);
        let (lo2, hi2) = newcombe_paired_interval(40, 9, 3, 48, 0.95).unwrap();
        assert!((lo2 + hi).abs() < 1e-15 && (hi2 + lo).abs() < 1e-15, "swapping the runs negates the interval");
        assert!(newcombe_paired_interval(0, 0, 0, 0, 0.95).is_none());
    }
}
