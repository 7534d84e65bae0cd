//! The canonical LIBERO evaluation protocol, as the published evaluations run it.
//!
//! Source: the VLA evaluation grammar (`shared/seeds/001_*.txt` §1), which took these from the
//! OpenVLA `run_libero_eval.py` origin inherited verbatim by openpi, starVLA and vla-eval.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Trials (episodes) per task; `init_state_id` = trial index. (OpenVLA/openpi: `num_trials_per_task=50`.)
pub const TRIALS_PER_TASK: u32 = 50;
/// The env seed of the canonical protocol (openpi `Args.seed = 7`, passed to `env.seed`).
pub const SEED: u64 = 7;
/// Dummy steps of `[0,0,0,0,0,0,-1]` before the policy acts, while objects settle (`num_steps_wait`).
pub const NUM_STEPS_WAIT: u32 = 10;
/// The action every wait step sends: no motion, gripper open (-1).
pub const WAIT_ACTION: [f32; 7] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0];
/// Control rate of the env (robosuite `control_freq=20`): one env step is 0.05 s.
pub const CONTROL_FREQ_HZ: u32 = 20;
/// Physics substeps per env step: `int(0.05 / 0.002)` (robosuite `environments/base.py:388`).
pub const SUBSTEPS_PER_STEP: u32 = 25;
/// Rendered camera size of the published evaluations (square).
pub const RENDER_SIZE: u32 = 256;

/// The LIBERO task suites this pipeline knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Suite {
    LiberoSpatial,
    LiberoObject,
    LiberoGoal,
    Libero10,
    Libero90,
}

impl Suite {
    /// The four suites of the canonical benchmark (libero_90 is pre-training data, not reported).
    pub const CANONICAL: [Suite; 4] = [Suite::LiberoSpatial, Suite::LiberoObject, Suite::LiberoGoal, Suite::Libero10];
    pub const ALL: [Suite; 5] =
        [Suite::LiberoSpatial, Suite::LiberoObject, Suite::LiberoGoal, Suite::Libero10, Suite::Libero90];

    pub fn name(self) -> &'static str {
        match self {
            Suite::LiberoSpatial => "libero_spatial",
            Suite::LiberoObject => "libero_object",
            Suite::LiberoGoal => "libero_goal",
            Suite::Libero10 => "libero_10",
            Suite::Libero90 => "libero_90",
        }
    }

    /// Episode length cap in policy steps, excluding the wait steps
    /// (`max_steps` of OpenVLA's `run_libero_eval.py`: 220 / 280 / 300 / 520 / 400).
    pub fn max_steps(self) -> u32 {
        match self {
            Suite::LiberoSpatial => 220,
            Suite::LiberoObject => 280,
            Suite::LiberoGoal => 300,
            Suite::Libero10 => 520,
            Suite::Libero90 => 400,
        }
    }
}

impl fmt::Display for Suite {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Suite {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Suite::ALL.into_iter().find(|x| x.name() == s).ok_or_else(|| {
            let known: Vec<_> = Suite::ALL.iter().map(|x| x.name()).collect();
            format!("unknown suite {s:?}; known suites: {}", known.join(", "))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suite_names_round_trip_and_unknown_names_list_the_known_ones() {
        for s in Suite::ALL {
            assert_eq!(s.name().parse::<Suite>().unwrap(), s);
        }
        let err = "libero_99".parse::<Suite>().unwrap_err();
        assert!(err.contains("libero_spatial") && err.contains("libero_99"), "{err}");
    }
}
