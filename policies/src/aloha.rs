//! Policies for ALOHA-sim: the second benchmark's seam. Its action space is not LIBERO's (per arm
//! (left, right) 6 absolute joint targets and a normalized gripper, 14 values, where LIBERO's are
//! a 7-D end-effector delta), and so is what a policy sees (the 14 joint positions `agent_pos`,
//! the `top` camera), so a LIBERO [`crate::Policy`] cannot act here: [`AlohaPolicy`] is the seam,
//! and [`crate::PolicySpec::instantiate_aloha`] makes the kinds that have an ALOHA form.
//!
//! | `--policy` | here |
//! |---|---|
//! | `expert` | [`ScriptedAloha`]: plays the scripted control the env recorded for the episode (privileged) |
//! | `random` | [`RandomWalkAloha`]: a seeded random walk of the joints, grippers uniform (baseline) |
//! | `nan-at:N` | [`NanAtAloha`]: holds the start pose, a NaN at policy step N (error rows) |
//! | `openpi:ws://…` | [`crate::remote::OpenpiAlohaPolicy`]: openpi's ALOHA-sim example's client |
//! | `torchscript:<file>` | `models::torchscript_aloha::TorchScriptAloha` (feature `torch`): a module whose `model.json` says `"benchmark": "aloha_sim"` |

use crate::{CameraImage, PolicyError};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;

/// Components of an ALOHA-sim action and of `agent_pos`.
pub const ALOHA_ACTION_DIM: usize = 14;
/// An ALOHA-sim action: per arm 6 joint targets (rad) and a gripper (0 closed … 1 open).
pub type AlohaAction = [f32; ALOHA_ACTION_DIM];

/// What an ALOHA-sim policy sees before a step.
#[derive(Debug, Clone, Default)]
pub struct AlohaObservation {
    /// gym-aloha's task name (`env.task`: `transfer_cube`, `insertion`), which lerobot-eval passes
    /// as the observation's `task` (gym-aloha has no `task_description`).
    pub task: &'static str,
    pub policy_step: u32,
    /// `obs["agent_pos"]`: per arm 6 joint positions and the normalized left-finger position.
    pub agent_pos: [f64; ALOHA_ACTION_DIM],
    /// `obs["pixels"]["top"]` (480 × 640, upright), when the policy asked for it before this step
    /// ([`AlohaPolicy::wants_top_camera`]).
    pub top: Option<CameraImage>,
    /// The scripted control's joint targets for this episode (privileged: made from where the
    /// seed put the objects), for [`AlohaPolicy::wants_script`] policies; entry t is step t's.
    pub script: Option<Arc<Vec<AlohaAction>>>,
}

/// A policy evaluated on ALOHA-sim. One instance serves one episode at a time.
pub trait AlohaPolicy: Send {
    /// Start an episode, with a seed derived from the episode key.
    fn reset(&mut self, episode_seed: u64);
    fn act(&mut self, obs: &AlohaObservation) -> Result<AlohaAction, PolicyError>;
    /// Whether the env must record the scripted control for it (privileged scripted policies).
    fn wants_script(&self) -> bool {
        false
    }
    /// Whether the env must render the `top` camera before the next step (asked every step: a
    /// chunked policy needs it only when it queries its model).
    fn wants_top_camera(&self) -> bool {
        false
    }
    /// As [`crate::Policy::set_ensemble`].
    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        Err(format!("ensemble={ensemble}: this policy predicts no action chunks"))
    }
    /// As [`crate::Policy::queries_model`].
    fn queries_model(&self) -> bool {
        true
    }
}

/// The positive control: ACT's scripted policy as the env recorded it for this episode's objects.
pub struct ScriptedAloha;

impl AlohaPolicy for ScriptedAloha {
    fn reset(&mut self, _episode_seed: u64) {}
    fn act(&mut self, obs: &AlohaObservation) -> Result<AlohaAction, PolicyError> {
        let script = obs.script.as_ref().ok_or_else(|| PolicyError {
            policy: "expert".into(),
            detail: "the env gave no scripted trajectory (wants_script)".into(),
        })?;
        // past the script (a cap above its 400 steps): hold its last target
        Ok(script[(obs.policy_step as usize).min(script.len() - 1)])
    }
    fn wants_script(&self) -> bool {
        true
    }
}

/// The random baseline: each joint target a random walk around the first observed joints
/// (steps uniform in ±0.1 rad, within ±1.2 rad of the start), each gripper uniform in [0, 1];
/// seeded per episode (ChaCha8). Uniform joint targets would fling the arms across their ranges
/// at the position controllers' full force, which tests the physics more than the scoring.
pub struct RandomWalkAloha {
    rng: ChaCha8Rng,
    start: Option<[f64; ALOHA_ACTION_DIM]>,
    offset: [f64; 12],
}

impl RandomWalkAloha {
    pub fn new() -> Self {
        RandomWalkAloha { rng: ChaCha8Rng::seed_from_u64(0), start: None, offset: [0.0; 12] }
    }
}

impl Default for RandomWalkAloha {
    fn default() -> Self {
        Self::new()
    }
}

impl AlohaPolicy for RandomWalkAloha {
    fn reset(&mut self, episode_seed: u64) {
        self.rng = ChaCha8Rng::seed_from_u64(episode_seed);
        self.start = None;
        self.offset = [0.0; 12];
    }
    fn act(&mut self, obs: &AlohaObservation) -> Result<AlohaAction, PolicyError> {
        let start = *self.start.get_or_insert(obs.agent_pos);
        let mut a = [0f32; ALOHA_ACTION_DIM];
        for (j, o) in self.offset.iter_mut().enumerate() {
            *o = (*o + self.rng.random_range(-0.1..=0.1)).clamp(-1.2, 1.2);
            let i = 7 * (j / 6) + j % 6;
            a[i] = (start[i] + *o) as f32;
        }
        a[6] = self.rng.random_range(0.0..=1.0);
        a[13] = self.rng.random_range(0.0..=1.0);
        Ok(a)
    }
}

/// Diagnostic: hold the first observed joints (grippers as observed), a NaN at policy step `at`.
pub struct NanAtAloha {
    pub at: u32,
    hold: Option<AlohaAction>,
}

impl NanAtAloha {
    pub fn new(at: u32) -> Self {
        NanAtAloha { at, hold: None }
    }
}

impl AlohaPolicy for NanAtAloha {
    fn reset(&mut self, _episode_seed: u64) {
        self.hold = None;
    }
    fn act(&mut self, obs: &AlohaObservation) -> Result<AlohaAction, PolicyError> {
        let mut a = *self.hold.get_or_insert(obs.agent_pos.map(|x| x as f32));
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
    fn the_random_walk_is_reproducible_and_stays_near_the_start() {
        let obs = AlohaObservation { agent_pos: [0.5; ALOHA_ACTION_DIM], ..Default::default() };
        let mut p = RandomWalkAloha::new();
        let mut run = |seed| {
            p.reset(seed);
            (0..400).map(|_| p.act(&obs).unwrap()).collect::<Vec<_>>()
        };
        let (a, b, c) = (run(7), run(7), run(8));
        assert_eq!(a, b);
        assert_ne!(a, c);
        for x in &a {
            assert!(x.iter().enumerate().all(|(i, v)| if i % 7 == 6 {
                (0.0..=1.0).contains(v)
            } else {
                (v - 0.5).abs() <= 1.2 + 1e-6
            }));
        }
    }

    #[test]
    fn the_scripted_policy_plays_the_script_and_holds_its_end() {
        let script: Vec<AlohaAction> = (0..3).map(|t| [t as f32; ALOHA_ACTION_DIM]).collect();
        let mut obs = AlohaObservation { script: Some(Arc::new(script)), ..Default::default() };
        let mut p = ScriptedAloha;
        obs.policy_step = 1;
        assert_eq!(p.act(&obs).unwrap()[0], 1.0);
        obs.policy_step = 10;
        assert_eq!(p.act(&obs).unwrap()[0], 2.0);
        obs.script = None;
        assert!(p.act(&obs).unwrap_err().to_string().contains("scripted"));
    }
}
