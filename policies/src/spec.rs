//! Naming a policy on the command line and recording its identity in the run manifest.

use crate::{Expert, ExpertDrop, LiftPolicy, NanAtPolicy, Policy, PolicyError, RandomPolicy};
use std::fmt;
use std::str::FromStr;

/// A policy a run evaluates, as named on the command line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PolicySpec {
    /// Uniform random actions (baseline; must score ≈ 0).
    Random,
    /// Move up, gripper untouched (baseline; must score ≈ 0).
    Lift,
    /// The privileged scripted expert (positive control; reads the simulator state).
    Expert,
    /// Diagnostic: NaN action at policy step N (exercises error rows).
    NanAt(u32),
    /// Diagnostic: the expert forced to let go early in its first carry (real `dropped` failures).
    ExpertDrop,
}

impl PolicySpec {
    /// A fresh instance for one rollout worker.
    pub fn instantiate(&self) -> Result<Box<dyn Policy>, PolicyError> {
        Ok(match self {
            PolicySpec::Random => Box::new(RandomPolicy::new()),
            PolicySpec::Lift => Box::new(LiftPolicy),
            PolicySpec::Expert => Box::new(Expert::new()),
            PolicySpec::NanAt(n) => Box::new(NanAtPolicy { at: *n }),
            PolicySpec::ExpertDrop => Box::new(ExpertDrop::new()),
        })
    }

    /// Short name stored in every episode row.
    pub fn name(&self) -> String {
        self.to_string()
    }

    /// Baselines are expected to fail; results warn when one scores above 5%.
    pub fn is_baseline(&self) -> bool {
        matches!(self, PolicySpec::Random | PolicySpec::Lift)
    }

    /// Identity for the manifest: what a reader needs to know which policy produced the steps
    /// (checkpoint hash, unnorm key, chunking and image preprocessing for model policies).
    pub fn identity(&self) -> serde_json::Value {
        match self {
            PolicySpec::Random => serde_json::json!({
                "kind": "baseline", "name": "random", "distribution": "uniform [-1,1]^7",
                "rng": "ChaCha8 seeded per episode from the episode key", "chunking": 1,
            }),
            PolicySpec::Lift => serde_json::json!({
                "kind": "baseline", "name": "lift", "action": [0, 0, 0.05, 0, 0, 0, 0], "chunking": 1,
            }),
            PolicySpec::Expert => serde_json::json!({
                "kind": "scripted expert", "name": "expert", "privileged": true,
                "plan": "goal terms -> pick-and-place / open / close / turn-on skills, closed loop on the eef pose",
                "chunking": 1,
            }),
            PolicySpec::NanAt(n) => {
                serde_json::json!({"kind": "diagnostic", "name": "nan-at", "step": n})
            }
            PolicySpec::ExpertDrop => serde_json::json!({
                "kind": "diagnostic", "name": "expert-drop", "privileged": true,
                "forced": "the expert opens its gripper 5 steps into its first carry, then holds still",
                "chunking": 1,
            }),
        }
    }
}

impl fmt::Display for PolicySpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PolicySpec::Random => f.write_str("random"),
            PolicySpec::Lift => f.write_str("lift"),
            PolicySpec::Expert => f.write_str("expert"),
            PolicySpec::NanAt(n) => write!(f, "nan-at:{n}"),
            PolicySpec::ExpertDrop => f.write_str("expert-drop"),
        }
    }
}

impl FromStr for PolicySpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "random" => Ok(PolicySpec::Random),
            "lift" => Ok(PolicySpec::Lift),
            "expert" => Ok(PolicySpec::Expert),
            "expert-drop" => Ok(PolicySpec::ExpertDrop),
            _ => match s.strip_prefix("nan-at:").map(str::parse) {
                Some(Ok(n)) => Ok(PolicySpec::NanAt(n)),
                _ => {
                    Err(format!("unknown policy {s:?}; known: random, lift, expert; diagnostics: nan-at:<policy step>, expert-drop"))
                }
            },
        }
    }
}
