//! A TorchScript policy on ALOHA-sim: `--policy torchscript:model.pt` on a spec of suite
//! `aloha_sim`, where `model.json` beside the file says so:
//!
//! ```json
//! {
//!   "benchmark": "aloha_sim",
//!   "inputs": ["top", "state"],
//!   "preprocessing": "none",
//!   "chunk_size": 100,
//!   "replan_steps": 100
//! }
//! ```
//!
//! - `inputs`: the forward's arguments in order. `top`: float32 `[1, 3, H, W]` in [0, 1], the
//!   480 × 640 `top` frame (`obs["pixels"]["top"]`, upright) after `preprocessing`: `none` keeps
//!   it whole, as lerobot's ACT and diffusion policies take it; `pad224` is openpi's
//!   `resize_with_pad` to 224 × 224 (Pillow bilinear, black bars). `state`: float32 `[1, 14]`,
//!   `agent_pos` (per arm 6 joint positions and the normalized gripper).
//! - The output: float `[1, chunk, 14]` or `[1, 14]`, in env units (joint targets in rad, grippers
//!   normalized 0 … 1). A policy's normalisation (lerobot's mean/std) belongs inside the exported
//!   module: there are no `dataset_statistics` here.
//! - `replan_steps` of each chunk are executed before the module runs again (lerobot's ACT
//!   executes all 100 of its chunk, `n_action_steps = chunk_size`).
//!
//! One forward per episode query; `?batch=` is LIBERO's only (refused before a run).

use super::torchscript::{load_module, read_manifest, unit_chw_tensor};
use crate::aloha::{ALOHA_ACTION_DIM, AlohaAction, AlohaObservation, AlohaPolicy};
use crate::chunking::ActionChunker;
use crate::preprocess::image::resize_with_pad;
use crate::preprocess::{Filter, RgbImage};
use crate::{CameraImage, PolicyError};
use serde_json::Value;
use std::path::{Path, PathBuf};
use tch::{CModule, Device, Kind, Tensor};

const NAME: &str = "torchscript";

fn err(detail: impl Into<String>) -> PolicyError {
    PolicyError { policy: NAME.into(), detail: detail.into() }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Input {
    Top,
    State,
}

/// How the `top` frame becomes the module's image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum TopPreprocessing {
    /// The 480 × 640 frame as rendered.
    None,
    /// openpi's `resize_with_pad` to 224 × 224.
    Pad224,
}

/// `model.json` of an ALOHA-sim module, checked.
#[derive(Debug, Clone)]
pub struct AlohaManifest {
    inputs: Vec<Input>,
    preprocessing: TopPreprocessing,
    chunk_size: usize,
    replan_steps: usize,
    raw: Value,
}

impl AlohaManifest {
    pub fn parse(text: &str, source: &Path) -> Result<Self, PolicyError> {
        let bad = |what: String| err(format!("{}: {what}", source.display()));
        let v: Value = serde_json::from_str(text).map_err(|e| bad(format!("not JSON: {e}")))?;
        if v.get("benchmark").and_then(Value::as_str) != Some("aloha_sim") {
            return Err(bad("an ALOHA-sim module's manifest says \"benchmark\": \"aloha_sim\"".into()));
        }
        for key in ["dataset_statistics", "unnorm_key", "gripper", "image_size", "render_size"] {
            if v.get(key).is_some() {
                return Err(bad(format!(
                    "{key} is a LIBERO manifest key; an ALOHA-sim module takes the 480x640 top frame (or pad224) and returns env units: put the normalisation inside the module"
                )));
            }
        }
        let inputs = v
            .get("inputs")
            .and_then(Value::as_array)
            .ok_or_else(|| bad("inputs must list the forward's arguments, e.g. [\"top\", \"state\"]".into()))?
            .iter()
            .map(|x| match x.as_str() {
                Some("top") => Ok(Input::Top),
                Some("state") => Ok(Input::State),
                _ => Err(bad(format!("unknown input {x}; known on ALOHA-sim: top, state"))),
            })
            .collect::<Result<Vec<_>, _>>()?;
        if inputs.is_empty() {
            return Err(bad("inputs is empty".into()));
        }
        let preprocessing = match v.get("preprocessing").and_then(Value::as_str).unwrap_or("none") {
            "none" => TopPreprocessing::None,
            "pad224" => TopPreprocessing::Pad224,
            other => return Err(bad(format!("unknown preprocessing {other:?}; known on ALOHA-sim: none, pad224"))),
        };
        let uint = |key: &str, default: u64| -> Result<usize, PolicyError> {
            match v.get(key) {
                Some(x) => x
                    .as_u64()
                    .filter(|&n| n > 0)
                    .map(|n| n as usize)
                    .ok_or_else(|| bad(format!("{key} must be a positive integer"))),
                None => Ok(default as usize),
            }
        };
        let chunk_size = uint("chunk_size", 1)?;
        let replan_steps = uint("replan_steps", chunk_size as u64)?;
        Ok(AlohaManifest { inputs, preprocessing, chunk_size, replan_steps, raw: v })
    }

    fn needs_top(&self) -> bool {
        self.inputs.contains(&Input::Top)
    }
}

/// A TorchScript module acting on ALOHA-sim, one episode at a time.
pub struct TorchScriptAloha {
    module: CModule,
    manifest: AlohaManifest,
    device: Device,
    file: PathBuf,
    sha256: String,
    chunker: ActionChunker<AlohaAction>,
}

impl TorchScriptAloha {
    /// Load `file` and its ALOHA-sim manifest, on the GPU when there is one.
    pub fn load(file: &Path) -> Result<Self, PolicyError> {
        Self::load_on(file, None)
    }

    /// [`Self::load`] on `device` (the spec's `devices=`).
    pub fn load_on(file: &Path, device: Option<crate::placement::ModelDevice>) -> Result<Self, PolicyError> {
        let (manifest_path, text) = read_manifest(file)?;
        let manifest = AlohaManifest::parse(&text, &manifest_path)?;
        let (module, device, sha256) = load_module(file, device)?;
        let chunker = ActionChunker::new(manifest.replan_steps);
        Ok(TorchScriptAloha { module, manifest, device, file: file.to_path_buf(), sha256, chunker })
    }

    /// Identity for the run manifest: the file's hash, the inputs, preprocessing and chunking.
    pub fn identity(&self) -> Value {
        let m = &self.manifest;
        serde_json::json!({
            "kind": "torchscript", "name": NAME, "benchmark": "aloha_sim",
            "file": self.file.display().to_string(), "sha256": self.sha256,
            "inputs": m.raw.get("inputs"),
            "images": if m.needs_top() {
                serde_json::json!({"cameras": ["top"], "render": "480x640, look mujoco-3.3.7 (the scene's own visual settings)",
                                   "preprocessing": match m.preprocessing {
                                       TopPreprocessing::None => "none: float32 [0, 1], CHW",
                                       TopPreprocessing::Pad224 => "pad224: resize_with_pad 224 (pil-bilinear, black bars), float32 [0, 1], CHW",
                                   }})
            } else { Value::Null },
            "state": "float32 (14,): agent_pos, per arm 6 joint positions and the normalized gripper",
            "chunking": {"predicted": m.chunk_size, "executed": m.replan_steps},
            "batch": "one episode per forward",
            "device": format!("{:?}", self.device),
        })
    }

    fn image_tensor(&self, top: &CameraImage) -> Result<Tensor, PolicyError> {
        let img = RgbImage::new(top.width, top.height, top.rgb.clone())
            .map_err(|e| err(format!("the top camera's image: {e}")))?;
        let img = match self.manifest.preprocessing {
            TopPreprocessing::None => img,
            TopPreprocessing::Pad224 => resize_with_pad(&img, 224, 224, Filter::Bilinear),
        };
        Ok(unit_chw_tensor(&img))
    }

    /// One forward: the chunk for `obs`.
    fn predict(&self, obs: &AlohaObservation) -> Result<Vec<AlohaAction>, PolicyError> {
        let args = self
            .manifest
            .inputs
            .iter()
            .map(|input| match input {
                Input::State => Ok(Tensor::from_slice(&obs.agent_pos.map(|x| x as f32)).unsqueeze(0)),
                Input::Top => self.image_tensor(obs.top.as_ref().ok_or_else(|| err("the env rendered no top camera"))?),
            })
            .map(|t| t.map(|t| t.to_device(self.device)))
            .collect::<Result<Vec<_>, _>>()?;
        let out = tch::no_grad(|| self.module.forward_ts(&args)).map_err(|e| err(format!("forward: {e}")))?;
        let out = out.to_device(Device::Cpu).to_kind(Kind::Float);
        let d = ALOHA_ACTION_DIM as i64;
        let out = match out.size().as_slice() {
            [1, c, n] if *n == d => out.reshape([*c, d]),
            [1, n] if *n == d => out.reshape([1, d]),
            other => {
                return Err(err(format!("the module returned shape {other:?}; expected [1, chunk, 14] or [1, 14]")));
            }
        };
        let values = Vec::<f32>::try_from(&out.reshape([-1])).map_err(|e| err(format!("reading the output: {e}")))?;
        Ok(values.chunks_exact(ALOHA_ACTION_DIM).map(|c| std::array::from_fn(|j| c[j])).collect())
    }
}

impl AlohaPolicy for TorchScriptAloha {
    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        self.chunker.set_ensemble(Some(ensemble));
        Ok(())
    }

    fn queries_model(&self) -> bool {
        self.chunker.needs_query()
    }

    fn reset(&mut self, _episode_seed: u64) {
        self.chunker.reset();
    }

    fn act(&mut self, obs: &AlohaObservation) -> Result<AlohaAction, PolicyError> {
        if self.chunker.needs_query() {
            let chunk = self.predict(obs)?;
            self.chunker.push_chunk(chunk).map_err(err)?;
        }
        self.chunker.next_action().ok_or_else(|| err("no action queued"))
    }

    fn wants_top_camera(&self) -> bool {
        self.manifest.needs_top() && self.chunker.needs_query()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_manifest_is_aloha_sims_and_refuses_libero_keys() {
        let src = Path::new("model.json");
        let m =
            AlohaManifest::parse(r#"{"benchmark": "aloha_sim", "inputs": ["top", "state"], "chunk_size": 100}"#, src)
                .unwrap();
        assert_eq!((m.chunk_size, m.replan_steps, m.preprocessing), (100, 100, TopPreprocessing::None));
        let e = |text: &str| AlohaManifest::parse(text, src).unwrap_err().to_string();
        assert!(e(r#"{"inputs": ["top"]}"#).contains("\"benchmark\": \"aloha_sim\""));
        assert!(e(r#"{"benchmark": "aloha_sim", "inputs": ["agentview"]}"#).contains("known on ALOHA-sim: top, state"));
        assert!(
            e(r#"{"benchmark": "aloha_sim", "inputs": ["top"], "gripper": "openvla"}"#).contains("LIBERO manifest key")
        );
        assert!(
            e(r#"{"benchmark": "aloha_sim", "inputs": ["top"], "preprocessing": "openvla"}"#).contains("none, pad224")
        );
    }
}
