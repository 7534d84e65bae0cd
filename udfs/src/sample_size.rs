//! Trials needed to detect a difference between two success rates, as the SQL function
//! `sample_size_two_proportions(p1, p2 [, alpha [, power]])`.
//!
//! Before spending GPU hours it is worth knowing whether a run can resolve the difference one
//! cares about: at 10 trials per task a 10-point gap is noise. This is the normal-approximation
//! sample size per arm for a two-sided test of two **independent** proportions, with the pooled
//! variance under the null and the unpooled one under the alternative (Fleiss, Levin & Paik,
//! *Statistical Methods for Rates and Proportions*, 3rd ed., eq. 4.14, without continuity
//! correction; the far tail is ignored):
//!
//! ```text
//! n = ( z(1−α/2)·√(2·p̄(1−p̄)) + z(power)·√(p1(1−p1) + p2(1−p2)) )² / (p1 − p2)²,   p̄ = (p1+p2)/2
//! ```
//!
//! It is what `statsmodels.stats.proportion.samplesize_proportions_2indep_onetail` computes.
//! Paired runs (same episode keys, McNemar) usually need fewer trials, so for them it is an upper
//! bound. Defaults: α = 0.05, power = 0.8. The SQL function returns the size rounded up.

use arrow::array::{Array, AsArray, Int64Array};
use arrow::datatypes::{DataType, Float64Type};
use datafusion::common::{Result, plan_err};
use datafusion::logical_expr::{ColumnarValue, ScalarFunctionArgs, ScalarUDF, ScalarUDFImpl, Signature, Volatility};
use std::sync::Arc;

pub const DEFAULT_ALPHA: f64 = 0.05;
pub const DEFAULT_POWER: f64 = 0.8;

/// The (unrounded) trials per arm; `None` unless 0 ≤ p1, p2 ≤ 1, p1 ≠ p2, 0 < α < 1, 0 < power < 1.
pub fn two_proportions_n(p1: f64, p2: f64, alpha: f64, power: f64) -> Option<f64> {
    use statrs::distribution::{ContinuousCDF, Normal};
    let unit = |x: f64| (0.0..=1.0).contains(&x);
    let open = |x: f64| x > 0.0 && x < 1.0;
    if !(unit(p1) && unit(p2) && p1 != p2 && open(alpha) && open(power)) {
        return None;
    }
    let normal = Normal::standard();
    let z_alpha = normal.inverse_cdf(1.0 - alpha / 2.0);
    let z_power = normal.inverse_cdf(power);
    let pbar = (p1 + p2) / 2.0;
    let sd_null = (2.0 * pbar * (1.0 - pbar)).sqrt();
    let sd_alt = (p1 * (1.0 - p1) + p2 * (1.0 - p2)).sqrt();
    let top = (z_alpha * sd_null + z_power * sd_alt).max(0.0);
    Some((top / (p1 - p2)).powi(2))
}

/// `sample_size_two_proportions(p1, p2 [, alpha [, power]]) -> BIGINT` (trials per arm, rounded up).
#[derive(Debug, PartialEq, Eq, Hash)]
pub struct SampleSizeTwoProportions {
    signature: Signature,
}

impl Default for SampleSizeTwoProportions {
    fn default() -> Self {
        SampleSizeTwoProportions { signature: Signature::user_defined(Volatility::Immutable) }
    }
}

impl ScalarUDFImpl for SampleSizeTwoProportions {
    fn name(&self) -> &str {
        "sample_size_two_proportions"
    }
    fn signature(&self) -> &Signature {
        &self.signature
    }
    fn return_type(&self, _arg_types: &[DataType]) -> Result<DataType> {
        Ok(DataType::Int64)
    }
    fn coerce_types(&self, arg_types: &[DataType]) -> Result<Vec<DataType>> {
        if (2..=4).contains(&arg_types.len()) && arg_types.iter().all(|t| t.is_numeric() || t.is_null()) {
            Ok(vec![DataType::Float64; arg_types.len()])
        } else {
            plan_err!("sample_size_two_proportions(p1, p2 [, alpha [, power]] DOUBLE) got {arg_types:?}")
        }
    }
    fn invoke_with_args(&self, args: ScalarFunctionArgs) -> Result<ColumnarValue> {
        let arrays = ColumnarValue::values_to_arrays(&args.args)?;
        let cols: Vec<_> = arrays.iter().map(|a| a.as_primitive::<Float64Type>()).collect();
        let out: Int64Array = (0..cols[0].len())
            .map(|i| {
                if cols.iter().any(|c| c.is_null(i)) {
                    return None;
                }
                let get = |j: usize, default: f64| cols.get(j).map_or(default, |c| c.value(i));
                two_proportions_n(get(0, 0.0), get(1, 0.0), get(2, DEFAULT_ALPHA), get(3, DEFAULT_POWER))
                    .map(|n| n.ceil() as i64)
            })
            .collect();
        Ok(ColumnarValue::Array(Arc::new(out)))
    }
}

pub fn sample_size_two_proportions_udf() -> ScalarUDF {
    ScalarUDF::from(SampleSizeTwoProportions::default())
}
