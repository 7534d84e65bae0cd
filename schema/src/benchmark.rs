//! The benchmarks a run can be of, and what each fixes for the tables: LIBERO (single-arm
//! end-effector control, 7-D actions) and ALOHA-sim (bimanual joint-position control, 14-D).
//!
//! A spec row's `suite` names its benchmark: `aloha_sim` is ALOHA-sim (gym-aloha's two tasks,
//! `task_id` 0 `transfer_cube` and 1 `insertion`); every other suite name is LIBERO's or one of
//! its perturbation suites'. A run is of one benchmark: the steps tables differ in what a step
//! records (the end-effector and the BDDL goal terms; the 14 joints and the 0–4 reward), while
//! the episode table, and with it every score, is the same.

/// The suite name of ALOHA-sim's episodes.
pub const ALOHA_SUITE: &str = "aloha_sim";

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Benchmark {
    Libero,
    AlohaSim,
}

impl Benchmark {
    /// The benchmark of a spec row's suite name.
    pub fn of_suite(suite: &str) -> Benchmark {
        if suite == ALOHA_SUITE { Benchmark::AlohaSim } else { Benchmark::Libero }
    }

    /// As stored in `episodes.env` and the manifest's `env`.
    pub fn name(self) -> &'static str {
        match self {
            Benchmark::Libero => "libero",
            Benchmark::AlohaSim => "aloha_sim",
        }
    }

    /// Components of an env action: LIBERO's delta end-effector pose and gripper (7); ALOHA's
    /// per-arm 6 joint targets and a gripper (14).
    pub fn action_dim(self) -> usize {
        match self {
            Benchmark::Libero => 7,
            Benchmark::AlohaSim => 14,
        }
    }
}

impl std::fmt::Display for Benchmark {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Benchmark {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "libero" => Ok(Benchmark::Libero),
            "aloha_sim" => Ok(Benchmark::AlohaSim),
            _ => Err(format!("unknown benchmark {s:?}; the benchmarks are libero and aloha_sim")),
        }
    }
}

/// ALOHA-sim's protocol constants (aloha-sim.md §3, §7).
pub mod aloha {
    /// lerobot's evaluation seeds start here: episode i is `reset(seed = 1000 + i)`.
    pub const LEROBOT_FIRST_SEED: i64 = 1000;
    /// Episodes per task in lerobot's evaluation.
    pub const EPISODES_PER_TASK: u32 = 50;
    /// The episode cap lerobot and ACT evaluate with (`max_episode_steps` 400).
    pub const LEROBOT_MAX_STEPS: u32 = 400;
    /// The cap of gym-aloha's registration (`max_episode_steps=300`), which openpi inherits; the
    /// scripted insertion only succeeds after ~330 steps, so insertion cannot succeed under it.
    pub const GYM_MAX_STEPS: u32 = 300;
    /// Env steps per second (`control_timestep` 0.02 s) and physics substeps per env step.
    pub const CONTROL_FREQ_HZ: i32 = 50;
    pub const SUBSTEPS_PER_STEP: i32 = 10;
    /// The tasks by `task_id`.
    pub const TASKS: [&str; 2] = ["transfer_cube", "insertion"];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suites_name_their_benchmark() {
        assert_eq!(Benchmark::of_suite("aloha_sim"), Benchmark::AlohaSim);
        assert_eq!(Benchmark::of_suite("libero_goal_swap"), Benchmark::Libero);
        for b in [Benchmark::Libero, Benchmark::AlohaSim] {
            assert_eq!(b.name().parse::<Benchmark>().unwrap(), b);
        }
        assert_eq!(Benchmark::AlohaSim.action_dim(), 14);
    }
}
