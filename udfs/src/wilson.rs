//! Wilson score intervals for success rates, as SQL functions.
//!
//! - `wilson(success [, level])`: aggregate over a boolean column, returning the struct
//!   `{n, k, rate, lo, hi}` (nulls are skipped, as every SQL aggregate does);
//! - `wilson_lo(k, n [, level])` / `wilson_hi(k, n [, level])`: the bounds from counts.
//!
//! `level` defaults to 0.95; the normal quantile comes from statrs. n = 0 gives NULL bounds.
//! The interval is the score interval of Wilson (1927), the one `statsmodels`'
//! `proportion_confint(method="wilson")` computes: with p = k/n and z the two-sided quantile,
//! centre (p + z²/2n) / (1 + z²/n), half-width z·√(p(1−p)/n + z²/4n²) / (1 + z²/n).

use arrow::array::{Array, ArrayRef, AsArray, BooleanArray, Float64Array, Int64Array, StructArray};
use arrow::datatypes::{DataType, Field, Fields, Float64Type, Int64Type};
use datafusion::common::{Result, ScalarValue, exec_err, plan_err};
use datafusion::logical_expr::function::{AccumulatorArgs, StateFieldsArgs};
use datafusion::logical_expr::{
    Accumulator, AggregateUDF, AggregateUDFImpl, ColumnarValue, ScalarFunctionArgs, ScalarUDF, ScalarUDFImpl,
    Signature, Volatility,
};
use std::sync::Arc;

/// Default confidence level.
pub const DEFAULT_LEVEL: f64 = 0.95;

/// The Wilson score interval for k successes in n trials at `level` (e.g. 0.95).
/// `None` when n = 0 or the level is not in (0, 1).
pub fn wilson_interval(k: u64, n: u64, level: f64) -> Option<(f64, f64)> {
    if n == 0 || k > n || !(level > 0.0 && level < 1.0) {
        return None;
    }
    use statrs::distribution::{ContinuousCDF, Normal};
    let z = Normal::standard().inverse_cdf(1.0 - (1.0 - level) / 2.0);
    let (k, n) = (k as f64, n as f64);
    let p = k / n;
    let z2 = z * z;
    let denom = 1.0 + z2 / n;
    let centre = (p + z2 / (2.0 * n)) / denom;
    let half = z * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt() / denom;
    // k = 0 and k = n give exactly 0 and 1 in exact arithmetic; floating point leaves ~1e-17.
    let lo = if k == 0.0 { 0.0 } else { (centre - half).max(0.0) };
    let hi = if k == n { 1.0 } else { (centre + half).min(1.0) };
    Some((lo, hi))
}

/// The fields of the struct `wilson(...)` returns.
pub fn wilson_fields() -> Fields {
    Fields::from(vec![
        Field::new("n", DataType::Int64, false),
        Field::new("k", DataType::Int64, false),
        Field::new("rate", DataType::Float64, true),
        Field::new("lo", DataType::Float64, true),
        Field::new("hi", DataType::Float64, true),
    ])
}

/// `wilson_lo` / `wilson_hi`.
#[derive(Debug, PartialEq, Eq, Hash)]
pub struct WilsonBound {
    upper: bool,
    signature: Signature,
}

impl WilsonBound {
    pub fn new(upper: bool) -> Self {
        WilsonBound { upper, signature: Signature::user_defined(Volatility::Immutable) }
    }
}

impl ScalarUDFImpl for WilsonBound {
    fn name(&self) -> &str {
        if self.upper { "wilson_hi" } else { "wilson_lo" }
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
            [k, n] if int(k) && int(n) => Ok(vec![DataType::Int64, DataType::Int64]),
            [k, n, l] if int(k) && int(n) && (l.is_numeric() || l.is_null()) => {
                Ok(vec![DataType::Int64, DataType::Int64, DataType::Float64])
            }
            _ => plan_err!("{}(k INTEGER, n INTEGER [, level DOUBLE]) got {arg_types:?}", self.name()),
        }
    }
    fn invoke_with_args(&self, args: ScalarFunctionArgs) -> Result<ColumnarValue> {
        let arrays = ColumnarValue::values_to_arrays(&args.args)?;
        let k = arrays[0].as_primitive::<Int64Type>();
        let n = arrays[1].as_primitive::<Int64Type>();
        let level = arrays.get(2).map(|a| a.as_primitive::<Float64Type>());
        let out: Float64Array = (0..k.len())
            .map(|i| {
                if k.is_null(i) || n.is_null(i) || level.is_some_and(|l| l.is_null(i)) {
                    return None;
                }
                let (k, n) = (k.value(i), n.value(i));
                if k < 0 || n < 0 {
                    return None;
                }
                let lvl = level.map_or(DEFAULT_LEVEL, |l| l.value(i));
                wilson_interval(k as u64, n as u64, lvl).map(|(lo, hi)| if self.upper { hi } else { lo })
            })
            .collect();
        Ok(ColumnarValue::Array(Arc::new(out)))
    }
}

/// The `wilson(bool [, level])` aggregate.
#[derive(Debug, PartialEq, Eq, Hash)]
pub struct WilsonAggregate {
    signature: Signature,
}

impl Default for WilsonAggregate {
    fn default() -> Self {
        WilsonAggregate { signature: Signature::user_defined(Volatility::Immutable) }
    }
}

impl AggregateUDFImpl for WilsonAggregate {
    fn name(&self) -> &str {
        "wilson"
    }
    fn signature(&self) -> &Signature {
        &self.signature
    }
    fn return_type(&self, _arg_types: &[DataType]) -> Result<DataType> {
        Ok(DataType::Struct(wilson_fields()))
    }
    fn coerce_types(&self, arg_types: &[DataType]) -> Result<Vec<DataType>> {
        match arg_types {
            [DataType::Boolean] => Ok(vec![DataType::Boolean]),
            [DataType::Boolean, t] if t.is_numeric() => Ok(vec![DataType::Boolean, DataType::Float64]),
            _ => plan_err!("wilson(success BOOLEAN [, level DOUBLE]) got {arg_types:?}"),
        }
    }
    fn state_fields(&self, args: StateFieldsArgs) -> Result<Vec<Arc<Field>>> {
        Ok(vec![
            Arc::new(Field::new(format!("{}[n]", args.name), DataType::Int64, false)),
            Arc::new(Field::new(format!("{}[k]", args.name), DataType::Int64, false)),
            Arc::new(Field::new(format!("{}[level]", args.name), DataType::Float64, true)),
        ])
    }
    fn accumulator(&self, _acc_args: AccumulatorArgs) -> Result<Box<dyn Accumulator>> {
        Ok(Box::new(WilsonAccumulator::default()))
    }
}

#[derive(Debug, Default)]
struct WilsonAccumulator {
    n: i64,
    k: i64,
    level: Option<f64>,
}

impl WilsonAccumulator {
    fn set_level(&mut self, level: f64) -> Result<()> {
        match self.level {
            Some(l) if l != level => {
                exec_err!("wilson(): the level must be the same for every row ({l} vs {level})")
            }
            _ => {
                self.level = Some(level);
                Ok(())
            }
        }
    }
}

impl Accumulator for WilsonAccumulator {
    fn update_batch(&mut self, values: &[ArrayRef]) -> Result<()> {
        let b: &BooleanArray = values[0].as_boolean();
        self.n += (b.len() - b.null_count()) as i64;
        self.k += b.true_count() as i64;
        if let Some(levels) = values.get(1) {
            for l in levels.as_primitive::<Float64Type>().iter().flatten() {
                self.set_level(l)?;
            }
        }
        Ok(())
    }
    fn evaluate(&mut self) -> Result<ScalarValue> {
        let level = self.level.unwrap_or(DEFAULT_LEVEL);
        let (lo, hi) = match wilson_interval(self.k as u64, self.n as u64, level) {
            Some((lo, hi)) => (Some(lo), Some(hi)),
            None => (None, None),
        };
        let rate = (self.n > 0).then(|| self.k as f64 / self.n as f64);
        let arrays: Vec<ArrayRef> = vec![
            Arc::new(Int64Array::from(vec![self.n])),
            Arc::new(Int64Array::from(vec![self.k])),
            Arc::new(Float64Array::from(vec![rate])),
            Arc::new(Float64Array::from(vec![lo])),
            Arc::new(Float64Array::from(vec![hi])),
        ];
        Ok(ScalarValue::Struct(Arc::new(StructArray::new(wilson_fields(), arrays, None))))
    }
    fn size(&self) -> usize {
        std::mem::size_of_val(self)
    }
    fn state(&mut self) -> Result<Vec<ScalarValue>> {
        Ok(vec![ScalarValue::Int64(Some(self.n)), ScalarValue::Int64(Some(self.k)), ScalarValue::Float64(self.level)])
    }
    fn merge_batch(&mut self, states: &[ArrayRef]) -> Result<()> {
        self.n += states[0].as_primitive::<Int64Type>().iter().flatten().sum::<i64>();
        self.k += states[1].as_primitive::<Int64Type>().iter().flatten().sum::<i64>();
        for l in states[2].as_primitive::<Float64Type>().iter().flatten() {
            self.set_level(l)?;
        }
        Ok(())
    }
}

pub fn wilson_udaf() -> AggregateUDF {
    AggregateUDF::from(WilsonAggregate::default())
}

pub fn wilson_lo_udf() -> ScalarUDF {
    ScalarUDF::from(WilsonBound::new(false))
}

pub fn wilson_hi_udf() -> ScalarUDF {
    ScalarUDF::from(WilsonBound::new(true))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interval_edges() {
        let (lo, hi) = wilson_interval(0, 10, 0.95).unwrap();
        assert_eq!(lo, 0.0);
        assert!((hi - 0.2775327998628892).abs() < 1e-12, "{hi}");
        let (lo, hi) = wilson_interval(10, 10, 0.95).unwrap();
        assert_eq!(hi, 1.0);
        assert!((lo - 0.7224672001371108).abs() < 1e-12, "{lo}");
        assert!(wilson_interval(0, 0, 0.95).is_none());
        assert!(wilson_interval(1, 2, 1.0).is_none());
    }
}
