//! OpenVLA as a [`Policy`] (`--policy openvla:<checkpoint dir>[?unnorm=<key>]`): the published
//! LIBERO loop's conventions around [`OpenVlaModel`]: the agentview camera rendered at 256²,
//! OpenVLA's preprocessing ([`ImagePipeline::OPENVLA`]: rot180, JPEG 95, Lanczos 224, center crop
//! 0.9), one action per query (no chunking), un-normalised with the checkpoint's statistics of
//! `unnorm_key`, gripper [0, 1] → sign → inverted. bf16 on a GPU, fp32 on a CPU.

use super::{OpenVlaModel, OpenVlaPrediction};
use crate::batching::{BatchModel, Preparer, Request, forward_prepared};
use crate::models::cpu_fallback::ModelSize;
use crate::models::{device_and_dtype, files_hash};
use crate::placement::{ModelDevice, Quantization};
use crate::postprocess::Gripper;
use crate::preprocess::{ImagePipeline, RgbImage};
use crate::{Action, Observation, Policy, PolicyError};
use std::path::Path;
use std::sync::Arc;

const NAME: &str = "openvla";
/// The camera size of OpenVLA's LIBERO loop (`resize_size` 224 comes after).
pub const RENDER_SIZE: u32 = 256;

fn err(detail: impl Into<String>) -> PolicyError {
    PolicyError { policy: NAME.into(), detail: detail.into() }
}

pub struct OpenVlaPolicy {
    model: OpenVlaModel,
    unnorm_key: Option<String>,
    instruction: String,
}

/// A wrong or missing `unnorm_key` is an error listing the keys the checkpoint has.
fn check_unnorm_key(config: &super::OpenVlaConfig, unnorm_key: Option<&str>) -> Result<(), PolicyError> {
    config.norm_stats.action(unnorm_key).map(|_| ()).map_err(|e| err(e.to_string()))
}

impl OpenVlaPolicy {
    /// Load the checkpoint directory on `device` (the first GPU, else the CPU, for `None`), its
    /// linear layers stored as `quant` says; a wrong or missing `unnorm_key` fails here, listing
    /// the keys the checkpoint has.
    pub fn load(
        dir: &Path,
        unnorm_key: Option<String>,
        device: Option<ModelDevice>,
        quant: Quantization,
    ) -> Result<Self, PolicyError> {
        let (device, dtype) = device_and_dtype(device, &ModelSize::of_checkpoint(NAME, dir)).map_err(err)?;
        let model = OpenVlaModel::load_quantized(dir, device, dtype, quant).map_err(|e| err(e.to_string()))?;
        check_unnorm_key(model.config(), unnorm_key.as_deref())?;
        Ok(OpenVlaPolicy { model, unnorm_key, instruction: String::new() })
    }

    /// The language model's attention implementation (the spec's `attention=`).
    pub fn set_attention(&mut self, attention: super::Attention) {
        self.model.set_attention(attention);
    }

    /// Identity for the run manifest, from the checkpoint's files without loading its weights
    /// (once per run, at its start; each worker then loads the model itself). Checks the key.
    pub fn identity_of(
        dir: &Path,
        unnorm_key: Option<&str>,
        batch: Option<usize>,
    ) -> Result<serde_json::Value, PolicyError> {
        let config = super::OpenVlaConfig::load(dir).map_err(|e| err(e.to_string()))?;
        check_unnorm_key(&config, unnorm_key)?;
        Ok(serde_json::json!({
            "kind": "openvla", "name": NAME,
            "checkpoint": dir.display().to_string(),
            "checkpoint_sha256": checkpoint_hash(dir)?,
            "unnorm_key": unnorm_key,
            "images": {"cameras": ["agentview"], "render": format!("{RENDER_SIZE}x{RENDER_SIZE}, look mujoco-3.2.3"),
                       "preprocessing": ImagePipeline::OPENVLA.describe()},
            "prompt": super::prompt("{instruction}"),
            "decoding": "greedy, 7 action tokens from the last 256 vocabulary bins",
            "gripper": "[0,1] -> 2g-1 -> sign -> inverted",
            "chunking": {"predicted": 1, "executed": 1},
            "batch": batch.map_or_else(
                || serde_json::json!("one episode per forward"),
                |n| serde_json::json!({"max_episodes_per_forward": n, "padding": "left, masked"})
            ),
            "dtype": "bf16 on a GPU, f32 on a CPU",
            "kernels": crate::models::openvla::KERNELS,
        }))
    }
}

/// sha256 over the checkpoint's small files and every weight file (name and bytes), sorted.
fn checkpoint_hash(dir: &Path) -> Result<String, PolicyError> {
    files_hash(dir, &["json", "safetensors"]).map_err(err)
}

impl Policy for OpenVlaPolicy {
    fn reset(&mut self, instruction: &str, _episode_seed: u64) {
        self.instruction = instruction.to_string();
    }

    fn camera_size(&self) -> Option<u32> {
        Some(RENDER_SIZE)
    }

    /// OpenVLA sees the agentview camera only.
    fn wants_wrist_camera(&self) -> bool {
        false
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        let image = model_image(obs)?;
        let p = self
            .model
            .predict_action(&image, &self.instruction, self.unnorm_key.as_deref())
            .map_err(|e| err(e.to_string()))?;
        env_action(&p)
    }
}

/// The agentview camera after OpenVLA's image preprocessing.
fn model_image(obs: &Observation) -> Result<RgbImage, PolicyError> {
    let cam = &obs.images.as_ref().ok_or_else(|| err("the rollout gave no camera images"))?.agentview;
    RgbImage::new(cam.width, cam.height, cam.rgb.clone())
        .and_then(|i| ImagePipeline::OPENVLA.apply(&i))
        .map_err(|e| err(format!("image preprocessing: {e}")))
}

/// The un-normalised prediction as a LIBERO action (gripper sign inverted).
fn env_action(p: &OpenVlaPrediction) -> Result<Action, PolicyError> {
    if p.action.len() != 7 {
        return Err(err(format!("the checkpoint predicts {} action dimensions, LIBERO needs 7", p.action.len())));
    }
    let mut a: Action = std::array::from_fn(|i| p.action[i] as f32);
    a[6] = Gripper::OPENVLA.apply(p.action[6]) as f32;
    Ok(a)
}

/// OpenVLA behind a [`crate::batching::Batcher`] (`openvla:<dir>?batch=N`): the rollout workers'
/// queries answered with one forward ([`OpenVlaModel::predict_actions`]).
pub struct OpenVlaBatchModel {
    model: OpenVlaModel,
    unnorm_key: Option<String>,
}

impl OpenVlaBatchModel {
    pub fn load(
        dir: &Path,
        unnorm_key: Option<String>,
        device: Option<ModelDevice>,
        quant: Quantization,
    ) -> Result<Self, PolicyError> {
        let OpenVlaPolicy { model, unnorm_key, .. } = OpenVlaPolicy::load(dir, unnorm_key, device, quant)?;
        Ok(OpenVlaBatchModel { model, unnorm_key })
    }

    /// The language model's attention implementation (the spec's `attention=`).
    pub fn set_attention(&mut self, attention: super::Attention) {
        self.model.set_attention(attention);
    }
}

impl BatchModel for OpenVlaBatchModel {
    fn device_label(&self) -> Option<String> {
        Some(crate::models::device_label(self.model.device()))
    }

    fn predict_batch(&mut self, requests: &[Request]) -> Vec<Result<Vec<Action>, String>> {
        // Each worker prepared its image ([`Self::preparer`]).
        let unnorm = self.unnorm_key.as_deref();
        forward_prepared(
            requests,
            |image: &RgbImage, instruction| (image, instruction),
            |ready| self.model.predict_actions(ready, unnorm).map_err(|e| e.to_string()),
            |p| env_action(&p).map(|a| vec![a]).map_err(|e| e.to_string()),
        )
    }

    fn camera_size(&self) -> Option<u32> {
        Some(RENDER_SIZE)
    }

    /// OpenVLA sees the agentview camera only.
    fn wants_wrist_camera(&self) -> bool {
        false
    }

    fn preparer(&self) -> Option<Preparer> {
        Some(Arc::new(|obs: &Observation| {
            model_image(obs).map(|i| Box::new(i) as Box<dyn std::any::Any + Send>).map_err(|e| e.to_string())
        }))
    }
}
