//! ALOHA-sim (gym-aloha 0.1.5): the bimanual ViperX tasks `transfer_cube` and `insertion`, in
//! Rust, matching the Python env (dm_control 1.0.34 on MuJoCo 3.3.7, numpy 1.26) bit for bit.
//!
//! A second benchmark beside LIBERO, with nothing in common but MuJoCo and the renderer, so it
//! lives in its own module:
//!
//! - [`bundle`]: the wheel's scene files, checked against their provenance, and what the oracle
//!   recorded (compiled model, initial poses, reference episodes);
//! - [`task`]: the two tasks and the initial object poses of a seed, drawn by [`mt19937`]
//!   (numpy's legacy `RandomState`, bitwise);
//! - [`control`]: action → actuator controls (the gripper mapping) and joints → `agent_pos`;
//! - [`reward`]: the 0–4 reward from ordered contact pairs;
//! - [`env`]: [`AlohaEnv`], reset, the 50 Hz step (dm_control's substep sequence) and the `top`
//!   camera;
//! - [`scripted`]: the positive control: ACT's scripted policies recorded in the end-effector
//!   scene with a stiffened weld ([`ScriptRecorder`]), replayed as joint targets
//!   ([`ScriptedPlan`]) in the unmodified joint-space env.
//!
//! ```no_run
//! use libero_sim::aloha::{AlohaBundle, AlohaEnv, AlohaTask, START_ARM_POSE};
//! let bundle = AlohaBundle::open("data/aloha")?;
//! let mut env = AlohaEnv::new(&bundle, AlohaTask::TransferCube)?;
//! env.reset(1000)?;                                    // lerobot's first protocol seed
//! let hold: [f32; 14] = std::array::from_fn(|i| env.agent_pos()[i] as f32);
//! let reward = env.step(&hold)?;                       // 0..=4; 4 is success
//! # let _ = (reward, START_ARM_POSE);
//! # Ok::<(), libero_sim::SimError>(())
//! ```

pub mod bundle;
pub mod control;
pub mod env;
pub mod mt19937;
pub mod reward;
pub mod scripted;
pub mod task;

pub use bundle::AlohaBundle;
pub use control::{ACTION_DIM, START_ARM_POSE};
pub use env::AlohaEnv;
pub use reward::MAX_REWARD;
pub use scripted::{ScriptRecorder, ScriptedPlan};
pub use task::AlohaTask;
