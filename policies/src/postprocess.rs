//! Action post-processing: from a model's normalized action to the 7-dim env action.
//!
//! 1. **Un-normalisation** with the checkpoint's dataset statistics, selected by the `unnorm_key`
//!    (OpenVLA's `norm_stats[unnorm_key]["action"]`, read from `dataset_statistics.json` or the
//!    HF config's `norm_stats`): where `mask` is true (the default), `0.5·(a + 1)·(q99 − q01) +
//!    q01`; where false (the gripper), `a` unchanged. This is `predict_action` in prismatic's
//!    `modeling_prismatic.py`, in f64 as numpy computes it.
//! 2. **Gripper**: the RLDS datasets store the gripper in [0, 1] with 0 = close; LIBERO wants
//!    -1 = open, +1 = close. OpenVLA's loops map `2·g − 1`, binarize with `np.sign` (0 stays 0),
//!    then flip the sign ([`Gripper::OPENVLA`]); openpi's models emit the env's convention
//!    ([`Gripper::AS_IS`]).
//!
//! A wrong or missing `unnorm_key` is an error that lists the keys the checkpoint has (a wrong
//! key does not fail in Python when the dimensions agree: it saturates the actions, the
//! `saturated_actions` failure mode).

use std::collections::BTreeMap;

/// Why an action could not be post-processed, or the statistics not read.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PostprocessError {
    #[error("unnorm_key {key:?} is not in the checkpoint's dataset statistics; it has: {}", .available.join(", "))]
    UnknownKey { key: String, available: Vec<String> },
    #[error("the checkpoint has statistics for several datasets; pass an unnorm_key, one of: {}", .available.join(", "))]
    KeyRequired { available: Vec<String> },
    #[error("dataset statistics: {0}")]
    Parse(String),
    #[error("action has {got} dimensions, the statistics have {expected} (LIBERO actions have 7)")]
    Dimension { expected: usize, got: usize },
}

/// The action statistics of one dataset (`norm_stats[key]["action"]`); other fields (mean, std,
/// min, max) are not used by the q01/q99 bounds normalisation.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionStats {
    pub q01: Vec<f64>,
    pub q99: Vec<f64>,
    /// Which dimensions are normalized; all when the statistics have no mask.
    pub mask: Vec<bool>,
}

impl ActionStats {
    /// `np.where(mask, 0.5 * (a + 1) * (q99 - q01) + q01, a)`.
    pub fn unnormalize(&self, normalized: &[f64]) -> Vec<f64> {
        normalized
            .iter()
            .enumerate()
            .map(|(i, &a)| if self.mask[i] { 0.5 * (a + 1.0) * (self.q99[i] - self.q01[i]) + self.q01[i] } else { a })
            .collect()
    }

    pub fn dim(&self) -> usize {
        self.q01.len()
    }
}

/// A checkpoint's dataset statistics: `{unnorm_key: {"action": {"q01", "q99", "mask", ...},
/// "proprio": {...}, ...}}`.
#[derive(Debug, Clone, PartialEq)]
pub struct NormStats {
    datasets: BTreeMap<String, ActionStats>,
}

impl NormStats {
    /// Parse `dataset_statistics.json` (or the `norm_stats` object of an OpenVLA HF config).
    pub fn from_json(text: &str) -> Result<Self, PostprocessError> {
        let v: serde_json::Value = serde_json::from_str(text).map_err(|e| PostprocessError::Parse(e.to_string()))?;
        Self::from_value(&v)
    }

    pub fn from_value(v: &serde_json::Value) -> Result<Self, PostprocessError> {
        let parse = |m: String| PostprocessError::Parse(m);
        let obj = v.as_object().ok_or_else(|| parse("not a JSON object of unnorm keys".into()))?;
        let mut datasets = BTreeMap::new();
        for (key, entry) in obj {
            let action = entry.get("action").ok_or_else(|| parse(format!("{key:?} has no \"action\" statistics")))?;
            let floats = |field: &str| -> Result<Vec<f64>, PostprocessError> {
                let arr = action
                    .get(field)
                    .and_then(|x| x.as_array())
                    .ok_or_else(|| parse(format!("{key:?}: action.{field} is missing or not an array")))?;
                arr.iter()
                    .map(|x| x.as_f64().ok_or_else(|| parse(format!("{key:?}: action.{field} has a non-number"))))
                    .collect()
            };
            let (q01, q99) = (floats("q01")?, floats("q99")?);
            let mask = match action.get("mask") {
                None | Some(serde_json::Value::Null) => vec![true; q01.len()],
                Some(m) => m
                    .as_array()
                    .ok_or_else(|| parse(format!("{key:?}: action.mask is not an array")))?
                    .iter()
                    .map(|x| x.as_bool().ok_or_else(|| parse(format!("{key:?}: action.mask has a non-boolean"))))
                    .collect::<Result<_, _>>()?,
            };
            if q99.len() != q01.len() || mask.len() != q01.len() {
                return Err(parse(format!(
                    "{key:?}: q01, q99 and mask differ in length ({}, {}, {})",
                    q01.len(),
                    q99.len(),
                    mask.len()
                )));
            }
            datasets.insert(key.clone(), ActionStats { q01, q99, mask });
        }
        Ok(NormStats { datasets })
    }

    /// The unnorm keys, sorted.
    pub fn keys(&self) -> Vec<String> {
        self.datasets.keys().cloned().collect()
    }

    /// The action statistics of `unnorm_key`; with `None`, those of the only dataset (prismatic's
    /// `_check_unnorm_key`).
    pub fn action(&self, unnorm_key: Option<&str>) -> Result<&ActionStats, PostprocessError> {
        match unnorm_key {
            Some(key) => self
                .datasets
                .get(key)
                .ok_or_else(|| PostprocessError::UnknownKey { key: key.to_string(), available: self.keys() }),
            None if self.datasets.len() == 1 => Ok(self.datasets.values().next().unwrap()),
            None => Err(PostprocessError::KeyRequired { available: self.keys() }),
        }
    }

    /// The key OpenVLA's LIBERO loop uses for a suite: the suite name, else `<suite>_no_noops`
    /// (the fine-tuned checkpoints were trained on the no-op-filtered datasets).
    pub fn libero_unnorm_key(&self, suite: &str) -> Result<String, PostprocessError> {
        let no_noops = format!("{suite}_no_noops");
        if self.datasets.contains_key(suite) {
            Ok(suite.to_string())
        } else if self.datasets.contains_key(&no_noops) {
            Ok(no_noops)
        } else {
            Err(PostprocessError::UnknownKey { key: suite.to_string(), available: self.keys() })
        }
    }
}

/// How the gripper dimension (the last) goes from the dataset's convention to the env's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Gripper {
    /// [0, 1] → [-1, 1] (`2·g − 1`), as `normalize_gripper_action`.
    pub to_symmetric: bool,
    /// Then `np.sign` (`binarize=True`; exactly 0 stays 0).
    pub binarize: bool,
    /// Then flip the sign (`invert_gripper_action`: datasets have 0 = close, LIBERO +1 = close).
    pub invert: bool,
}

impl Gripper {
    /// OpenVLA and OpenVLA-OFT on LIBERO.
    pub const OPENVLA: Gripper = Gripper { to_symmetric: true, binarize: true, invert: true };
    /// The model already emits the env's convention (openpi).
    pub const AS_IS: Gripper = Gripper { to_symmetric: false, binarize: false, invert: false };

    pub fn apply(&self, g: f64) -> f64 {
        let mut g = g;
        if self.to_symmetric {
            g = 2.0 * (g - 0.0) / (1.0 - 0.0) - 1.0;
        }
        if self.binarize {
            g = np_sign(g);
        }
        if self.invert {
            g *= -1.0;
        }
        g
    }
}

/// `np.sign`: -1, 0 or 1, NaN for NaN.
fn np_sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        x * 0.0
    }
}

/// Un-normalize with `stats`, then map the gripper: the env action. `normalized` must have the
/// statistics' dimension (7 for LIBERO).
pub fn postprocess_action(
    normalized: &[f64],
    stats: &ActionStats,
    gripper: Gripper,
) -> Result<crate::Action, PostprocessError> {
    if normalized.len() != stats.dim() || normalized.len() != 7 {
        return Err(PostprocessError::Dimension { expected: stats.dim(), got: normalized.len() });
    }
    let mut a = stats.unnormalize(normalized);
    a[6] = gripper.apply(a[6]);
    Ok(std::array::from_fn(|i| a[i] as f32))
}

#[cfg(test)]
mod tests {
    use super::*;

    const STATS: &str = r#"{
        "libero_goal_no_noops": {"action": {"q01": [-1, -2, 0, 0, 0, 0, 0], "q99": [1, 2, 4, 1, 1, 1, 1],
                                            "mask": [true, true, true, true, true, true, false], "mean": [0,0,0,0,0,0,0]},
                                 "proprio": {"q01": [0]}},
        "libero_spatial": {"action": {"q01": [0, 0, 0, 0, 0, 0, 0], "q99": [2, 2, 2, 2, 2, 2, 2]}}
    }"#;

    #[test]
    fn unnormalize_respects_the_mask() {
        let s = NormStats::from_json(STATS).unwrap();
        let a = s.action(Some("libero_goal_no_noops")).unwrap();
        assert_eq!(a.unnormalize(&[0.0, 1.0, -1.0, 0.5, 0.0, 0.0, 0.3]), vec![0.0, 2.0, 0.0, 0.75, 0.5, 0.5, 0.3]);
        // No mask: every dimension is normalized.
        let b = s.action(Some("libero_spatial")).unwrap();
        assert_eq!(b.mask, vec![true; 7]);
        assert_eq!(b.unnormalize(&[0.0; 7]), vec![1.0; 7]);
    }

    #[test]
    fn gripper_conventions() {
        let g = Gripper::OPENVLA;
        assert_eq!(g.apply(1.0), -1.0); // open in the dataset → -1 (open) in LIBERO
        assert_eq!(g.apply(0.0), 1.0);
        assert_eq!(g.apply(0.9), -1.0);
        assert_eq!(g.apply(0.5), 0.0); // np.sign(0) = 0: neither
        assert!(g.apply(f64::NAN).is_nan());
        assert_eq!(Gripper::AS_IS.apply(0.37), 0.37);
    }

    #[test]
    fn wrong_key_lists_the_keys() {
        let s = NormStats::from_json(STATS).unwrap();
        let e = s.action(Some("bridge_orig")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "unnorm_key \"bridge_orig\" is not in the checkpoint's dataset statistics; it has: libero_goal_no_noops, libero_spatial"
        );
        let e = s.action(None).unwrap_err();
        assert!(e.to_string().contains("one of: libero_goal_no_noops, libero_spatial"), "{e}");
        assert_eq!(s.libero_unnorm_key("libero_goal").unwrap(), "libero_goal_no_noops");
        assert_eq!(s.libero_unnorm_key("libero_spatial").unwrap(), "libero_spatial");
        assert!(matches!(s.libero_unnorm_key("libero_10"), Err(PostprocessError::UnknownKey { .. })));
    }

    #[test]
    fn single_dataset_needs_no_key() {
        let s = NormStats::from_json(r#"{"only": {"action": {"q01": [0], "q99": [1]}}}"#).unwrap();
        assert_eq!(s.action(None).unwrap().q99, vec![1.0]);
    }

    #[test]
    fn malformed_statistics_are_errors() {
        for bad in [
            r#"[]"#,
            r#"{"k": {}}"#,
            r#"{"k": {"action": {"q01": [0, 1], "q99": [1]}}}"#,
            r#"{"k": {"action": {"q01": [0], "q99": [1], "mask": [1]}}}"#,
            r#"{"k": {"action": {"q01": ["a"], "q99": [1]}}}"#,
        ] {
            assert!(matches!(NormStats::from_json(bad), Err(PostprocessError::Parse(_))), "{bad}");
        }
    }

    #[test]
    fn full_action() {
        let s = NormStats::from_json(STATS).unwrap();
        let a = s.action(Some("libero_goal_no_noops")).unwrap();
        let out = postprocess_action(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.98], a, Gripper::OPENVLA).unwrap();
        assert_eq!(out, [0.0, 0.0, 2.0, 0.5, 0.5, 0.5, -1.0]);
        assert!(matches!(postprocess_action(&[0.0; 6], a, Gripper::OPENVLA), Err(PostprocessError::Dimension { .. })));
    }
}
