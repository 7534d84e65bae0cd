//! The random draws of the corruptions, behind a seam that mirrors numpy's global-RNG calls.
//!
//! The reference draws from numpy's global `RandomState`, seeded once by the eval script, so its
//! exact stream cannot be reproduced per episode (spec §0.5). Instead every corruption asks a
//! [`NoiseDraws`] for its numbers, call for call as the reference calls `np.random.uniform` /
//! `np.random.randint`: production uses [`SeededDraws`] (a stream per episode and step), and the
//! parity test wraps it in [`RecordingDraws`], whose log the Python oracle replays into the
//! reference code (`scripts/reference/noise_oracle.py`).

use serde::Serialize;

/// A source of random numbers with the granularity of the reference's numpy calls, so that a
/// log of the calls (see [`RecordingDraws`]) can stand in for numpy's RNG, one call for one call.
pub trait NoiseDraws {
    /// `np.random.uniform(low, high)`: one scalar draw in `[low, high)`.
    fn uniform(&mut self, low: f64, high: f64) -> f64;
    /// `np.random.uniform(low, high, size)` with `out.len()` elements: one call, in C order.
    fn uniform_batch(&mut self, low: f64, high: f64, out: &mut [f64]);
    /// `out.len() / per_call` successive calls `np.random.randint(low, high, size=per_call)`
    /// (integers in `[low, high)`). One method for many calls only to spare a virtual call per
    /// pixel in glass blur; a log still counts them as that many calls.
    fn randint_calls(&mut self, low: i64, high: i64, per_call: usize, out: &mut [i64]);
}

/// The production draws: a deterministic stream from a `u64` seed, no global state. The caller
/// derives the seed from the episode key and the step, so a run is reproducible and two policies
/// see the same noise on the same episode (paired comparisons).
///
/// The generator is SplitMix64 (Steele, Lea & Flood 2014; the seeder of the xoshiro family):
/// 64-bit state, period 2^64, passes BigCrush; a frame needs at most ~200k draws. It is written
/// here, a dozen lines, rather than taken from a crate so that the noise of a stored run depends
/// on its seed alone: no dependency upgrade can change the stream.
#[derive(Debug, Clone)]
pub struct SeededDraws {
    state: u64,
}

impl SeededDraws {
    pub fn new(seed: u64) -> Self {
        SeededDraws { state: seed }
    }

    fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// numpy's `uniform`: `low + (high - low) * u`, u a 53-bit double in [0, 1).
    fn next_uniform(&mut self, low: f64, high: f64) -> f64 {
        let u = (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        low + (high - low) * u
    }

    /// An unbiased integer in `[low, low + range)` (Lemire's multiply-and-reject; `threshold`
    /// is `2^64 mod range`, computed once per batch: a 64-bit division costs more than a draw).
    fn next_int(&mut self, low: i64, range: u64, threshold: u64) -> i64 {
        loop {
            let m = self.next_u64() as u128 * range as u128;
            if (m as u64) >= threshold {
                return low.wrapping_add((m >> 64) as i64);
            }
        }
    }
}

impl NoiseDraws for SeededDraws {
    fn uniform(&mut self, low: f64, high: f64) -> f64 {
        self.next_uniform(low, high)
    }

    fn uniform_batch(&mut self, low: f64, high: f64, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = self.next_uniform(low, high));
    }

    fn randint_calls(&mut self, low: i64, high: i64, _per_call: usize, out: &mut [i64]) {
        assert!(low < high, "randint: empty range [{low}, {high})");
        let range = high.wrapping_sub(low) as u64;
        let threshold = range.wrapping_neg() % range;
        out.iter_mut().for_each(|v| *v = self.next_int(low, range, threshold));
    }
}

/// A run of identical numpy calls (same function and arguments) as the reference would make
/// them, with the values they returned in order: `calls` calls of `size` values each (`size` is
/// None for scalar `uniform` calls, one value each). Serialized as `{"fn": "uniform"|"randint",
/// "low", "high", "size", "calls", "values"}`: a frame of glass blur is ~150k calls, one run.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "fn", rename_all = "snake_case")]
pub enum DrawRun {
    Uniform { low: f64, high: f64, size: Option<usize>, calls: usize, values: Vec<f64> },
    Randint { low: i64, high: i64, size: usize, calls: usize, values: Vec<i64> },
}

/// Draws from `D`, logging every call: the evidence the oracle replays into the reference code.
#[derive(Debug, Clone)]
pub struct RecordingDraws<D> {
    inner: D,
    runs: Vec<DrawRun>,
}

impl<D: NoiseDraws> RecordingDraws<D> {
    pub fn new(inner: D) -> Self {
        RecordingDraws { inner, runs: Vec::new() }
    }

    /// The calls so far, in order, as runs of identical calls.
    pub fn runs(&self) -> &[DrawRun] {
        &self.runs
    }

    /// How many numpy calls were made.
    pub fn call_count(&self) -> usize {
        self.runs
            .iter()
            .map(|r| match r {
                DrawRun::Uniform { calls, .. } | DrawRun::Randint { calls, .. } => calls,
            })
            .sum()
    }

    /// The log as JSON (a list of [`DrawRun`]s), the format `noise_oracle.py` reads. Floats are
    /// written in their shortest exact form, so Python reads back the very values drawn.
    pub fn to_json(&self) -> String {
        serde_json::to_string(&self.runs).expect("draw runs serialize")
    }

    fn record_uniform(&mut self, low: f64, high: f64, size: Option<usize>, drawn: &[f64]) {
        if let Some(DrawRun::Uniform { low: l, high: h, size: s, calls, values }) = self.runs.last_mut()
            && (*l, *h, *s) == (low, high, size)
        {
            *calls += 1;
            values.extend_from_slice(drawn);
        } else {
            self.runs.push(DrawRun::Uniform { low, high, size, calls: 1, values: drawn.to_vec() });
        }
    }
}

impl<D: NoiseDraws> NoiseDraws for RecordingDraws<D> {
    fn uniform(&mut self, low: f64, high: f64) -> f64 {
        let v = self.inner.uniform(low, high);
        self.record_uniform(low, high, None, &[v]);
        v
    }

    fn uniform_batch(&mut self, low: f64, high: f64, out: &mut [f64]) {
        self.inner.uniform_batch(low, high, out);
        self.record_uniform(low, high, Some(out.len()), out);
    }

    fn randint_calls(&mut self, low: i64, high: i64, per_call: usize, out: &mut [i64]) {
        self.inner.randint_calls(low, high, per_call, out);
        let n = out.len() / per_call;
        if let Some(DrawRun::Randint { low: l, high: h, size, calls, values }) = self.runs.last_mut()
            && (*l, *h, *size) == (low, high, per_call)
        {
            *calls += n;
            values.extend_from_slice(out);
        } else {
            self.runs.push(DrawRun::Randint { low, high, size: per_call, calls: n, values: out.to_vec() });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeded_draws_repeat_for_a_seed_and_stay_in_range() {
        let (mut a, mut b, mut c) = (SeededDraws::new(7), SeededDraws::new(7), SeededDraws::new(8));
        let (mut xa, mut xb, mut xc) = (vec![0.0; 1000], vec![0.0; 1000], vec![0.0; 1000]);
        a.uniform_batch(-45.0, 45.0, &mut xa);
        b.uniform_batch(-45.0, 45.0, &mut xb);
        c.uniform_batch(-45.0, 45.0, &mut xc);
        assert_eq!(xa, xb);
        assert_ne!(xa, xc);
        assert!(xa.iter().all(|v| (-45.0..45.0).contains(v)));
        let mut ints = vec![0i64; 10_000];
        a.randint_calls(-5, 5, 2, &mut ints);
        assert!(ints.iter().all(|v| (-5..5).contains(v)));
        assert!((-5..5).all(|k| ints.contains(&k)), "every value of the range is drawn");
    }

    #[test]
    fn a_recording_logs_each_numpy_call_and_passes_the_values_on() {
        let mut rec = RecordingDraws::new(SeededDraws::new(1));
        let angle = rec.uniform(-45.0, 45.0);
        let mut field = [0.0; 4];
        rec.uniform_batch(-100.0, 100.0, &mut field);
        let (mut row1, mut row2) = ([0i64; 6], [0i64; 4]);
        rec.randint_calls(-1, 1, 2, &mut row1);
        rec.randint_calls(-1, 1, 2, &mut row2);
        assert_eq!(rec.call_count(), 1 + 1 + 5, "five randint(size=2) calls");
        let runs = rec.runs();
        assert_eq!(runs[0], DrawRun::Uniform { low: -45.0, high: 45.0, size: None, calls: 1, values: vec![angle] });
        assert_eq!(
            runs[1],
            DrawRun::Uniform { low: -100.0, high: 100.0, size: Some(4), calls: 1, values: field.into() }
        );
        let values = [row1.as_slice(), &row2].concat();
        assert_eq!(runs[2], DrawRun::Randint { low: -1, high: 1, size: 2, calls: 5, values });
        assert_eq!(runs.len(), 3, "identical calls share a run");
        let json: serde_json::Value = serde_json::from_str(&rec.to_json()).unwrap();
        assert_eq!(json[0]["fn"], "uniform");
        assert_eq!(json[0]["size"], serde_json::Value::Null);
        assert_eq!(json[0]["values"][0].as_f64(), Some(angle));
        assert_eq!((json[2]["fn"].as_str(), json[2]["calls"].as_u64()), (Some("randint"), Some(5)));
    }
}
