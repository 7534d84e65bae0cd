//! OpenVLA-OFT as a [`Policy`] (`--policy oft:<checkpoint dir>[?unnorm=<key>][&batch=N[&wait_ms=W]]`):
//! OFT's LIBERO loop (`experiments/robot/libero/run_libero_eval.py`, `GenerateConfig`) around
//! [`OftModel`]: both cameras rendered at 256² (`env_img_res`), each through
//! [`ImagePipeline::OPENVLA_OFT`] (rot180, JPEG 95, Lanczos 224, center crop 0.9); the state
//! `eef_pos ⊕ quat2axisangle(robot0_eef_quat) ⊕ gripper_qpos` with the quaternion as robosuite
//! gives it ([`QuatSign::AsGiven`], no antipodal flip: vla-eval measured OFT's LIBERO-Goal at 83.4%
//! with the flip, 97.4% without); the 8 × 7 chunk executed open loop in full
//! (`num_open_loop_steps = 8`), each action's gripper `[0, 1] → sign → inverted`. bf16 on a GPU,
//! fp32 on a CPU.

use super::{NUM_ACTIONS_CHUNK, OftModel, OftPrediction, OftQuery, PROPRIO_DIM};
use crate::batching::{BatchModel, Preparer, Request, forward_prepared};
use crate::chunking::ActionChunker;
use crate::models::cpu_fallback::ModelSize;
use crate::models::{device_and_dtype, files_hash};
use crate::placement::{ModelDevice, Quantization};
use crate::postprocess::Gripper;
use crate::preprocess::proprio::wxyz_to_xyzw;
use crate::preprocess::{ImagePipeline, QuatSign, RgbImage, libero_state};
use crate::{Action, Observation, Policy, PolicyError};
use std::path::Path;
use std::sync::Arc;

const NAME: &str = "oft";
/// OFT's LIBERO camera size (`env_img_res = 256`; 224 after preprocessing).
pub const RENDER_SIZE: u32 = 256;

fn err(detail: impl Into<String>) -> PolicyError {
    PolicyError { policy: NAME.into(), detail: detail.into() }
}

/// Errors of the shared OpenVLA code name `openvla`; the OFT policy's are its own.
fn rename(e: PolicyError) -> PolicyError {
    err(e.detail)
}

/// One query's inputs, prepared on the asking worker.
struct Prepared {
    primary: RgbImage,
    wrist: RgbImage,
    state: [f64; PROPRIO_DIM],
}

fn prepare(obs: &Observation) -> Result<Prepared, PolicyError> {
    let images = obs.images.as_ref().ok_or_else(|| err("the rollout gave no camera images"))?;
    let one = |cam: &crate::CameraImage, what: &str| {
        RgbImage::new(cam.width, cam.height, cam.rgb.clone())
            .and_then(|i| ImagePipeline::OPENVLA_OFT.apply(&i))
            .map_err(|e| err(format!("{what} image preprocessing: {e}")))
    };
    let state = libero_state(obs.eef_pos, wxyz_to_xyzw(obs.hand_quat), obs.gripper_qpos, QuatSign::AsGiven);
    Ok(Prepared { primary: one(&images.agentview, "agentview")?, wrist: one(&images.wrist, "wrist")?, state })
}

fn query<'a>(p: &'a Prepared, instruction: &'a str) -> OftQuery<'a> {
    OftQuery { primary: &p.primary, wrist: &p.wrist, state: p.state, instruction }
}

/// The un-normalised chunk as LIBERO actions (each gripper mapped to the env's convention).
fn env_chunk(p: &OftPrediction) -> Vec<Action> {
    p.actions
        .iter()
        .map(|a| {
            let mut out: Action = std::array::from_fn(|i| a[i] as f32);
            out[6] = Gripper::OPENVLA.apply(a[6]) as f32;
            out
        })
        .collect()
}

pub struct OftPolicy {
    model: OftModel,
    unnorm_key: Option<String>,
    instruction: String,
    chunker: ActionChunker,
}

impl OftPolicy {
    /// Load the checkpoint directory on `device` (the first GPU, else the CPU, for `None`), the
    /// backbone's linear layers stored as `quant` says; a missing head file or a wrong
    /// `unnorm_key` fails here.
    pub fn load(
        dir: &Path,
        unnorm_key: Option<String>,
        device: Option<ModelDevice>,
        quant: Quantization,
    ) -> Result<Self, PolicyError> {
        let (device, dtype) = device_and_dtype(device, &ModelSize::of_checkpoint(NAME, dir)).map_err(err)?;
        let model = OftModel::load_quantized(dir, device, dtype, quant).map_err(rename)?;
        model.stats(unnorm_key.as_deref()).map_err(rename)?;
        Ok(OftPolicy { model, unnorm_key, instruction: String::new(), chunker: ActionChunker::new(NUM_ACTIONS_CHUNK) })
    }

    /// The backbone's attention implementation (the spec's `attention=`).
    pub fn set_attention(&mut self, attention: crate::models::openvla::Attention) {
        self.model.set_attention(attention);
    }

    /// Identity for the run manifest from the checkpoint's files, without loading its weights (at
    /// the run's start): a bad directory, a missing head file or a wrong key fails here, before
    /// any episode.
    pub fn identity_of(
        dir: &Path,
        unnorm_key: Option<&str>,
        batch: Option<usize>,
    ) -> Result<serde_json::Value, PolicyError> {
        let (_, files) = super::check_dir(dir, unnorm_key).map_err(rename)?;
        let file_hash = |p: &Path| -> Result<serde_json::Value, PolicyError> {
            use sha2::{Digest, Sha256};
            let bytes = std::fs::read(p).map_err(|e| err(format!("{}: {e}", p.display())))?;
            Ok(serde_json::json!({
                "file": p.file_name().map(|n| n.to_string_lossy().into_owned()),
                "sha256": format!("{:x}", Sha256::digest(&bytes)),
            }))
        };
        Ok(serde_json::json!({
            "kind": "openvla-oft", "name": NAME,
            "checkpoint": dir.display().to_string(),
            "checkpoint_sha256": files_hash(dir, &["json", "safetensors", "pt"]).map_err(err)?,
            "action_head": file_hash(&files.action_head)?,
            "proprio_projector": file_hash(&files.proprio_projector)?,
            "unnorm_key": unnorm_key,
            "images": {"cameras": ["agentview", "wrist"], "render": format!("{RENDER_SIZE}x{RENDER_SIZE}, look mujoco-3.2.3"),
                       "preprocessing": ImagePipeline::OPENVLA_OFT.describe()},
            "state": "eef_pos, quat2axisangle(robot0_eef_quat as given, no antipodal flip), gripper_qpos; \
                      BOUNDS_Q99 normalised, clipped to [-1, 1]",
            "prompt": super::super::prompt("{instruction}"),
            "decoding": "parallel: 56 zeroed placeholders + </s>, one bidirectional forward, L1 regression head",
            "unnormalisation": "0.5 (a + 1) (q99 - q01 + 1e-8) + q01 where mask",
            "gripper": "[0,1] -> 2g-1 -> sign -> inverted",
            "chunking": {"predicted": NUM_ACTIONS_CHUNK, "executed": NUM_ACTIONS_CHUNK},
            "batch": batch.map_or_else(
                || serde_json::json!("one episode per forward"),
                |n| serde_json::json!({"max_episodes_per_forward": n, "padding": "left, masked"})
            ),
            "dtype": "bf16 on a GPU, f32 on a CPU",
            "kernels": crate::models::openvla::KERNELS,
        }))
    }
}

impl Policy for OftPolicy {
    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        self.chunker.set_ensemble(Some(ensemble));
        Ok(())
    }

    fn queries_model(&self) -> bool {
        self.chunker.needs_query()
    }

    fn reset(&mut self, instruction: &str, _episode_seed: u64) {
        self.instruction = instruction.to_string();
        self.chunker.reset();
    }

    /// Cameras only when the chunk is spent.
    fn camera_size(&self) -> Option<u32> {
        self.chunker.needs_query().then_some(RENDER_SIZE)
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        if self.chunker.needs_query() {
            let prepared = prepare(obs)?;
            let p = self
                .model
                .predict_chunk(&query(&prepared, &self.instruction), self.unnorm_key.as_deref())
                .map_err(rename)?;
            self.chunker.push_chunk(env_chunk(&p)).map_err(err)?;
        }
        self.chunker.next_action().ok_or_else(|| err("no action queued"))
    }
}

/// OFT behind a [`crate::batching::Batcher`] (`oft:<dir>?batch=N`): the rollout workers' queries
/// answered with one forward ([`OftModel::predict_chunks`]); each worker executes its 8 actions.
pub struct OftBatchModel {
    model: OftModel,
    unnorm_key: Option<String>,
}

impl OftBatchModel {
    pub fn load(
        dir: &Path,
        unnorm_key: Option<String>,
        device: Option<ModelDevice>,
        quant: Quantization,
    ) -> Result<Self, PolicyError> {
        let OftPolicy { model, unnorm_key, .. } = OftPolicy::load(dir, unnorm_key, device, quant)?;
        Ok(OftBatchModel { model, unnorm_key })
    }

    /// The backbone's attention implementation (the spec's `attention=`).
    pub fn set_attention(&mut self, attention: crate::models::openvla::Attention) {
        self.model.set_attention(attention);
    }
}

impl BatchModel for OftBatchModel {
    fn device_label(&self) -> Option<String> {
        Some(crate::models::device_label(self.model.device()))
    }

    fn predict_batch(&mut self, requests: &[Request]) -> Vec<Result<Vec<Action>, String>> {
        // Each worker prepared its images and state ([`Self::preparer`]).
        let unnorm = self.unnorm_key.as_deref();
        forward_prepared(
            requests,
            query,
            |ready| self.model.predict_chunks(ready, unnorm).map_err(|e| rename(e).to_string()),
            |p| Ok(env_chunk(&p)),
        )
    }

    fn camera_size(&self) -> Option<u32> {
        Some(RENDER_SIZE)
    }

    fn replan_steps(&self) -> usize {
        NUM_ACTIONS_CHUNK
    }

    fn preparer(&self) -> Option<Preparer> {
        Some(Arc::new(|obs: &Observation| {
            prepare(obs).map(|p| Box::new(p) as Box<dyn std::any::Any + Send>).map_err(|e| e.to_string())
        }))
    }
}
