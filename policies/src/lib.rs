//! # libero-policies
//!
//! The [`Policy`] seam between the rollout and the models it evaluates, and its implementations.
//! It knows nothing of MuJoCo: a policy sees an [`Observation`] (proprio state, the instruction,
//! the camera images it asks for) and returns 7-dim env actions. The crate is laid out by concern:
//!
//! | concern | where |
//! |---|---|
//! | the seam: [`Policy`], [`Observation`], [`PolicyError`], timing | this file |
//! | naming a policy (`--policy` strings), its identity, making instances | [`PolicySpec`] (`spec.rs`) |
//! | the published loops' transforms: images, state, action un-normalisation, gripper | [`preprocess`], [`postprocess`] |
//! | driving a model: open-loop chunks, one batched forward for many episodes, replicas on several devices | [`chunking`], [`batching`] |
//! | combining overlapping chunks (`ensemble=`: vla-eval's, ACT's and starVLA's rules) | [`ensembling`] |
//! | where a model runs and how its weights are stored (`devices=`, `quant=`) | [`placement`], `models::quant` |
//! | libtorch's CUDA backend loaded at start; no silent CPU fallback of a model | `cuda_backend`, `models::cpu_fallback` (feature `torch`) |
//! | in-process model ports on libtorch: TorchScript, OpenVLA, OpenVLA-OFT | `models` (feature `torch`) |
//! | clients of policy servers: openpi, vla-eval, starVLA | [`remote`] |
//! | Python policies (lerobot checkpoints, any `python:` object) in a host process it starts | [`python_host`] |
//! | policies without a model: baselines, the privileged scripted [`Expert`] | `baselines.rs`, `expert/`, [`scene`] |
//! | ALOHA-sim's seam (14-D joint actions) and its policies: [`aloha::AlohaPolicy`] | [`aloha`] |
//!
//! A new model port goes under `models/`, a new server protocol under `remote/`; both reuse the
//! transforms and the drivers, and get a [`PolicySpec`] kind.
//!
//! A run names its policy with a [`PolicySpec`] string (`random`, `lift`, ...). Each rollout
//! worker makes its own instance with [`PolicySpec::instantiate`], and every episode starts with
//! [`Policy::reset`], which receives a per-episode seed so that a re-run (or a resumed run)
//! reproduces the same actions.
//!
//! ```
//! use libero_policies::{Observation, PolicySpec};
//! let spec: PolicySpec = "lift".parse().unwrap();
//! let mut policy = spec.instantiate().unwrap();
//! policy.reset("pick up the bowl", 42);
//! let action = policy.act(&Observation::default()).unwrap();
//! assert_eq!(action[2], 0.05);
//! ```

pub mod aloha;
mod baselines;
pub mod batching;
pub mod chunking;
#[cfg(feature = "torch")]
pub mod cuda_backend;
pub mod ensembling;
mod expert;
#[cfg(feature = "torch")]
pub mod models;
pub mod placement;
pub mod postprocess;
pub mod preprocess;
pub mod python_host;
pub mod remote;
pub mod scene;
mod spec;

pub use baselines::{LiftPolicy, NanAtPolicy, RandomPolicy};
pub use expert::{Expert, ExpertDrop};
pub use scene::SceneView;
pub use spec::{Batching, CheckpointOptions, PolicySpec, PythonOptions};

/// What a policy sees at one step (the env's observation, without MuJoCo types).
#[derive(Debug, Clone, Default)]
pub struct Observation {
    /// Policy step index from 0 (wait steps are not shown to the policy).
    pub policy_step: u32,
    pub eef_pos: [f64; 3],
    /// (w, x, y, z) of the grip site frame (what the scripted expert steers).
    pub eef_quat: [f64; 4],
    /// (w, x, y, z) of the hand body: robosuite's `obs["robot0_eef_quat"]` (in x, y, z, w there),
    /// the quaternion the published loops turn into the proprio state's axis-angle.
    pub hand_quat: [f64; 4],
    pub gripper_qpos: [f64; 2],
    /// The finger joints' velocities (robosuite's `robot0_gripper_qvel`).
    pub gripper_qvel: [f64; 2],
    /// The grip site's rotation matrix, row-major (MuJoCo's `site_xmat`, robosuite's
    /// controller `ee_ori_mat`): lerobot's LIBERO env passes it on.
    pub eef_mat: [f64; 9],
    pub joint_pos: [f64; 7],
    pub joint_vel: [f64; 7],
    /// Privileged simulator state, only for policies that ask for it ([`Policy::wants_scene`]).
    pub scene: Option<SceneView>,
    /// The two cameras, only for policies that ask for them ([`Policy::camera_size`]).
    pub images: Option<CameraImages>,
}

/// A camera image as the reference env returns it (`obs["agentview_image"]`): RGB bytes, 3 per
/// pixel, rows in OpenGL order (row 0 at the bottom, so it looks upside down). A policy's own
/// preprocessing turns it into what its model was trained on; the published OpenVLA and openpi
/// loops rotate it by 180° (`img[::-1, ::-1]`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CameraImage {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// LIBERO's two cameras, rendered after the step the policy is about to answer.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CameraImages {
    /// `agentview`: the third-person camera.
    pub agentview: CameraImage,
    /// `robot0_eye_in_hand`: the wrist camera.
    pub wrist: CameraImage,
}

/// A 7-dim env action: delta eef position (3), delta axis-angle (3), gripper (-1 open … +1 close).
pub type Action = [f32; 7];

/// Why a policy could not produce an action; the episode becomes an error row.
#[derive(Debug, thiserror::Error)]
#[error("policy {policy}: {detail}")]
pub struct PolicyError {
    pub policy: String,
    pub detail: String,
}

/// Where the model behind a policy's `act` spent its time, beyond the call's wall time: a batched
/// model's query is prepared on the worker (image preprocessing), then waits for its forward,
/// which runs the model once for all of its episodes. Stored with each step (`steps.queue_ms` ...),
/// so a GPU run shows whether the forward, the preparation or the waiting bounds it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ActTiming {
    /// From the query's arrival until its forward started (ms).
    pub queue_ms: f32,
    /// The worker's preparation of this query's inputs (image preprocessing; ms); None where the
    /// model prepares nothing apart from its forward.
    pub prepare_ms: Option<f32>,
    /// The forward (ms, shared by the batch).
    pub forward_ms: f32,
    /// The forward's sequence number in this process: distinct ids count the forwards.
    pub forward_id: u64,
    /// Episodes the forward answered.
    pub forward_batch: u32,
}

/// A policy evaluated by the rollout. One instance serves one episode at a time.
pub trait Policy: Send {
    /// Start an episode: the instruction and a seed derived from the episode key.
    fn reset(&mut self, instruction: &str, episode_seed: u64);
    /// The action for this step.
    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError>;
    /// Whether the rollout must fill [`Observation::scene`] (privileged state: scripted experts
    /// only; a learned policy must never see it).
    fn wants_scene(&self) -> bool {
        false
    }
    /// The camera images this policy needs for its next `act`, as a square size in pixels (the
    /// published loops render 256×256 and resize to 224); `None`: no images. Asked before every
    /// policy step, so a chunked policy that still has queued actions answers `None` and the
    /// rollout skips the render (a camera pair costs far more than a physics step on a CPU).
    fn camera_size(&self) -> Option<u32> {
        None
    }
    /// The episode ended (success, cap or error): called after every episode the policy was reset
    /// for, and harmless without one. A batched model stops waiting for this worker's queries.
    fn end_episode(&mut self) {}
    /// Whether the images must include the wrist camera (else [`CameraImages::wrist`] is empty and
    /// the rollout renders one camera: on a GPU that also runs the model, each render waits for
    /// the GPU, so a camera nobody looks at costs a policy step real time).
    fn wants_wrist_camera(&self) -> bool {
        true
    }
    /// The model timing of the last `act`, where it queried a timed model ([`ActTiming`]); None
    /// for an action from a queued chunk and for policies that do not time their model apart.
    fn last_timing(&self) -> Option<ActTiming> {
        None
    }
    /// Combine this policy's action chunks by `ensemble` (`ensemble=`), asking its model as the
    /// rule needs; a policy without chunks refuses (the spec parser refuses it first).
    fn set_ensemble(&mut self, ensemble: ensembling::Ensemble) -> Result<(), String> {
        Err(format!("ensemble={ensemble}: this policy predicts no action chunks"))
    }
    /// Whether the next `act` runs the model (asked before it): a real-time run with a fixed
    /// latency charges it to these calls only. A chunked policy with queued actions answers
    /// false; a policy that computes every step (the default), true.
    fn queries_model(&self) -> bool {
        true
    }
}
