//! McNemar's exact test for paired binary outcomes, as the SQL function
//! `mcnemar_exact_p(b, c)`.
//!
//! Two policies run on the same episode keys give a paired 2×2 table; only the discordant pairs
//! carry information about which policy is better: `b` episodes succeeded under A only, `c` under
//! B only. Under "no difference" each discordant pair is a fair coin, so `b ~ Binomial(b + c, ½)`.
//! The p-value is the two-sided exact binomial test, doubled from the smaller tail and capped at
//! 1, which is what `statsmodels.stats.contingency_tables.mcnemar(table, exact=True)` computes
//! (and `b = c = 0` gives 1). The binomial comes from statrs.

use arrow::array::{AsArray, Float64Array};
use arrow::datatypes::{DataType, Int64Type};
use datafusion::common::{Result, plan_err};
use datafusion::logical_expr::{ColumnarValue, ScalarFunctionArgs, ScalarUDF, ScalarUDFImpl, Signature, Volatility};
use std::sync::Arc;

/// The two-sided exact McNemar p-value from the discordant counts `b` (A only) and `c` (B only).
pub fn mcnemar_exact_p(b: u64, c: u64) -> f64 {
    use statrs::distribution::{Binomial, DiscreteCDF};
    let n = b + c;
    if n == 0 {
        return 1.0;
    }
    let tail = Binomial::new(0.5, n).expect("p = 0.5 is a valid probability").cdf(b.min(c));
    (2.0 * tail).min(1.0)
}

/// `mcnemar_exact_p(b BIGINT, c BIGINT) -> DOUBLE`; NULL when an argument is NULL or negative.
#[derive(Debug, PartialEq, Eq, Hash)]
pub struct McNemarExactP {
    signature: Signature,
}

impl Default for McNemarExactP {
    fn default() -> Self {
        McNemarExactP { signature: Signature::user_defined(Volatility::Immutable) }
    }
}

impl ScalarUDFImpl for McNemarExactP {
    fn name(&self) -> &str {
        "mcnemar_exact_p"
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
            [b, c] if int(b) && int(c) => Ok(vec![DataType::Int64, DataType::Int64]),
            _ => plan_err!("mcnemar_exact_p(b INTEGER, c INTEGER) takes the two discordant counts, got {arg_types:?}"),
        }
    }
    fn invoke_with_args(&self, args: ScalarFunctionArgs) -> Result<ColumnarValue> {
        let arrays = ColumnarValue::values_to_arrays(&args.args)?;
        let (b, c) = (arrays[0].as_primitive::<Int64Type>(), arrays[1].as_primitive::<Int64Type>());
        let out: Float64Array = b
            .iter()
            .zip(c.iter())
            .map(|(b, c)| match (b, c) {
                (Some(b), Some(c)) if b >= 0 && c >= 0 => Some(mcnemar_exact_p(b as u64, c as u64)),
                _ => None,
            })
            .collect();
        Ok(ColumnarValue::Array(Arc::new(out)))
    }
}

pub fn mcnemar_exact_p_udf() -> ScalarUDF {
    ScalarUDF::from(McNemarExactP::default())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symmetric_and_bounded() {
        assert_eq!(mcnemar_exact_p(0, 0), 1.0);
        assert_eq!(mcnemar_exact_p(3, 3), 1.0);
        assert_eq!(mcnemar_exact_p(2, 9), mcnemar_exact_p(9, 2));
        // b = 0, c = 5: 2 · 0.5⁵
        assert!((mcnemar_exact_p(0, 5) - 0.0625).abs() < 1e-15);
    }
}
