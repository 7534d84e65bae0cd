//! Baseline policies that must fail: they anchor "is the pipeline scoring honestly?" (a random
//! or scripted policy scoring above a few percent means the success check is broken).

use crate::{Action, Observation, Policy, PolicyError};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Uniform random actions in [-1, 1]^7, seeded per episode (ChaCha8: reproducible across builds
/// and platforms, unlike `StdRng`).
pub struct RandomPolicy {
    rng: ChaCha8Rng,
}

impl RandomPolicy {
    pub fn new() -> Self {
        RandomPolicy { rng: ChaCha8Rng::seed_from_u64(0) }
    }
}

impl Default for RandomPolicy {
    fn default() -> Self {
        Self::new()
    }
}

impl Policy for RandomPolicy {
    fn reset(&mut self, _instruction: &str, episode_seed: u64) {
        self.rng = ChaCha8Rng::seed_from_u64(episode_seed);
    }
    fn act(&mut self, _obs: &Observation) -> Result<Action, PolicyError> {
        Ok(std::array::from_fn(|_| self.rng.random_range(-1.0f32..=1.0)))
    }
}

/// The scripted "lift" baseline: `[0, 0, 0.05, 0, 0, 0, 0]` every step, i.e. move up by
/// 0.05 × 5 cm = 2.5 mm per step. The gripper component 0 neither opens nor closes (only its sign
/// matters in the env: -1 opens, +1 closes), so the gripper stays open as the wait steps left it
/// and nothing is ever grasped.
pub struct LiftPolicy;

impl Policy for LiftPolicy {
    fn reset(&mut self, _instruction: &str, _episode_seed: u64) {}
    fn act(&mut self, _obs: &Observation) -> Result<Action, PolicyError> {
        Ok([0.0, 0.0, 0.05, 0.0, 0.0, 0.0, 0.0])
    }
}

/// Diagnostic policy for fault handling: zero motion, then a NaN action at policy step `n`
/// (the env rejects it with a typed error, and the episode becomes an error row).
pub struct NanAtPolicy {
    pub at: u32,
}

impl Policy for NanAtPolicy {
    fn reset(&mut self, _instruction: &str, _episode_seed: u64) {}
    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        let mut a = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0];
        if obs.policy_step == self.at {
            a[0] = f32::NAN;
        }
        Ok(a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_is_uniform_in_range_and_reproducible_per_episode_seed() {
        let mut p = RandomPolicy::new();
        p.reset("x", 3);
        let a: Vec<Action> = (0..200).map(|_| p.act(&Observation::default()).unwrap()).collect();
        p.reset("x", 3);
        let b: Vec<Action> = (0..200).map(|_| p.act(&Observation::default()).unwrap()).collect();
        assert_eq!(a, b);
        p.reset("x", 4);
        assert_ne!(a[0], p.act(&Observation::default()).unwrap());
        let flat: Vec<f32> = a.iter().flatten().copied().collect();
        assert!(flat.iter().all(|x| (-1.0..=1.0).contains(x)));
        let mean = flat.iter().sum::<f32>() / flat.len() as f32;
        assert!(mean.abs() < 0.1, "mean {mean}");
        assert!(flat.iter().any(|&x| x > 0.9) && flat.iter().any(|&x| x < -0.9));
    }
}
