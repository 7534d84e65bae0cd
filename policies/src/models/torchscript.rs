//! Any PyTorch policy exported as TorchScript (`torch.jit.script` / `torch.jit.trace`), run
//! in-process through libtorch (`tch::CModule`): `--policy torchscript:model.pt`.
//!
//! Beside the file, `model.json` says what the module expects and what its outputs mean:
//!
//! ```json
//! {
//!   "inputs": ["agentview", "wrist", "state"],
//!   "image_size": 224,
//!   "render_size": 256,
//!   "preprocessing": "openvla",
//!   "chunk_size": 8,
//!   "replan_steps": 8,
//!   "dataset_statistics": {"libero_spatial_no_noops": {"action": {"q01": [...], "q99": [...], "mask": [...]}}},
//!   "unnorm_key": "libero_spatial_no_noops",
//!   "gripper": "openvla"
//! }
//! ```
//!
//! - `inputs`: the forward's arguments in order. `agentview` / `wrist`: float32 `[1, 3, H, W]` in
//!   [0, 1] after `preprocessing`; `state`: float32 `[1, 8]`, LIBERO's proprio state (eef
//!   position, axis-angle of robosuite's `robot0_eef_quat`, finger joints).
//! - `preprocessing`: `openvla` / `openpi` ([`ImagePipeline`] presets, to 224) or `rot180` (only
//!   the published loops' 180° rotation; the cameras are then rendered at `image_size`).
//! - The output: float `[1, chunk, 7]` or `[1, 7]`, normalised to [-1, 1] when
//!   `dataset_statistics` is given (un-normalised with `unnorm_key`, OpenVLA's q01/q99 with the
//!   mask), else already in env units. `gripper`: `openvla` ([0, 1] → sign → inverted) or `as_is`.
//! - `replan_steps` of each chunk are executed before the module runs again ([`ActionChunker`]).
//! - `benchmark`: `libero` (the default). A module for ALOHA-sim says `aloha_sim` and has its
//!   own manifest form ([`super::torchscript_aloha`]).
//!
//! Where it runs: the policy string's `devices=D` (one device: `cpu`, `cuda` or `cuda:N`), else
//! the first GPU libtorch sees, else the CPU. Landing on the CPU unasked is refused on a GPU
//! machine (libtorch's CUDA backend did not load) and for a file of 4 GB or more (a billion fp32
//! parameters): `devices=cpu` is how to ask ([`super::cpu_fallback`]). One device only, also with
//! `batch=N`: a module's forward is whatever its author exported, so one replica is what it gets.

use crate::batching::BatchModel;
use crate::chunking::ActionChunker;
use crate::models::cpu_fallback::ModelSize;
use crate::placement::ModelDevice;
use crate::postprocess::{ActionStats, Gripper, NormStats, postprocess_action};
use crate::preprocess::{ImagePipeline, QuatSign, RgbImage, libero_state, proprio::wxyz_to_xyzw};
use crate::{Action, CameraImage, Observation, Policy, PolicyError};
use serde_json::Value;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use tch::{CModule, Device, Kind, Tensor};

const NAME: &str = "torchscript";

/// One forward argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Input {
    Agentview,
    Wrist,
    State,
}

/// `model.json`, checked.
#[derive(Debug, Clone)]
pub struct TorchScriptManifest {
    inputs: Vec<Input>,
    image_size: u32,
    render_size: u32,
    preprocessing: (String, ImagePipeline),
    chunk_size: usize,
    replan_steps: usize,
    stats: Option<(String, ActionStats)>,
    gripper: (String, Gripper),
    raw: Value,
}

fn err(detail: impl Into<String>) -> PolicyError {
    PolicyError { policy: NAME.into(), detail: detail.into() }
}

impl TorchScriptManifest {
    /// The manifest of `model` (`model.pt` → `model.json`).
    pub fn path_for(model: &Path) -> PathBuf {
        model.with_extension("json")
    }

    pub fn parse(text: &str, source: &Path) -> Result<Self, PolicyError> {
        let bad = |what: String| err(format!("{}: {what}", source.display()));
        let v: Value = serde_json::from_str(text).map_err(|e| bad(format!("not JSON: {e}")))?;
        match v.get("benchmark").and_then(Value::as_str) {
            None | Some("libero") => {}
            Some(other) => {
                return Err(bad(format!(
                    "the module declares \"benchmark\": {other:?}; this manifest form is LIBERO's (see models::torchscript_aloha for ALOHA-sim's)"
                )));
            }
        }
        let uint = |key: &str, default: Option<u64>| -> Result<u64, PolicyError> {
            match v.get(key) {
                Some(x) => {
                    x.as_u64().filter(|&n| n > 0).ok_or_else(|| bad(format!("{key} must be a positive integer")))
                }
                None => default.ok_or_else(|| bad(format!("{key} is missing"))),
            }
        };
        let inputs = v
            .get("inputs")
            .and_then(Value::as_array)
            .ok_or_else(|| {
                bad("inputs must list the forward's arguments, e.g. [\"agentview\", \"wrist\", \"state\"]".into())
            })?
            .iter()
            .map(|x| match x.as_str() {
                Some("agentview") => Ok(Input::Agentview),
                Some("wrist") => Ok(Input::Wrist),
                Some("state") => Ok(Input::State),
                _ => Err(bad(format!("unknown input {x}; known: agentview, wrist, state"))),
            })
            .collect::<Result<Vec<_>, _>>()?;
        if inputs.is_empty() {
            return Err(bad("inputs is empty".into()));
        }
        let image_size = uint("image_size", Some(224))? as u32;
        let name = v.get("preprocessing").and_then(Value::as_str).unwrap_or("rot180").to_string();
        let (pipeline, default_render) = match name.as_str() {
            "openvla" => (ImagePipeline::OPENVLA, 256),
            "openpi" => (ImagePipeline::OPENPI, 256),
            "rot180" => (
                ImagePipeline {
                    rotate_180: true,
                    jpeg_quality: None,
                    resize: crate::preprocess::Resize::None,
                    center_crop: None,
                },
                image_size as u64,
            ),
            other => return Err(bad(format!("unknown preprocessing {other:?}; known: openvla, openpi, rot180"))),
        };
        if name != "rot180" && image_size != 224 {
            return Err(bad(format!("preprocessing {name} gives 224x224 images, but image_size is {image_size}")));
        }
        let render_size = uint("render_size", Some(default_render))? as u32;
        if name == "rot180" && render_size != image_size {
            return Err(bad("preprocessing rot180 does not resize: render_size must equal image_size".into()));
        }
        let chunk_size = uint("chunk_size", Some(1))? as usize;
        let replan_steps = uint("replan_steps", Some(chunk_size as u64))? as usize;
        let stats = match v.get("dataset_statistics") {
            None | Some(Value::Null) => None,
            Some(s) => {
                let stats = NormStats::from_value(s).map_err(|e| bad(e.to_string()))?;
                let key = v.get("unnorm_key").and_then(Value::as_str);
                let action = stats.action(key).map_err(|e| bad(e.to_string()))?.clone();
                let key = key.map(str::to_string).unwrap_or_else(|| stats.keys().concat());
                Some((key, action))
            }
        };
        let gripper_name = v.get("gripper").and_then(Value::as_str).unwrap_or("as_is").to_string();
        let gripper = match gripper_name.as_str() {
            "openvla" => Gripper::OPENVLA,
            "as_is" => Gripper::AS_IS,
            other => return Err(bad(format!("unknown gripper {other:?}; known: openvla, as_is"))),
        };
        Ok(TorchScriptManifest {
            inputs,
            image_size,
            render_size,
            preprocessing: (name, pipeline),
            chunk_size,
            replan_steps,
            stats,
            gripper: (gripper_name, gripper),
            raw: v,
        })
    }

    fn needs_images(&self) -> bool {
        self.inputs.iter().any(|i| *i != Input::State)
    }

    fn needs_wrist(&self) -> bool {
        self.inputs.contains(&Input::Wrist)
    }
}

/// The text of `model`'s manifest (`model.pt` → `model.json`) and its path.
pub(crate) fn read_manifest(model: &Path) -> Result<(PathBuf, String), PolicyError> {
    let path = TorchScriptManifest::path_for(model);
    let text = std::fs::read_to_string(&path).map_err(|e| {
        err(format!(
            "{}: {e}; a TorchScript policy needs its manifest beside it (see policies::torchscript)",
            path.display()
        ))
    })?;
    Ok((path, text))
}

/// `file` loaded by libtorch (in eval mode) on `device` (`None`: the first GPU when there is one,
/// else the CPU, which [`super::model_device`] refuses on a GPU machine or for a module of a
/// billion parameters or more, unless asked for with `devices=cpu`), the device, and the file's
/// sha256 (the identity's). The module computes in the dtype it was saved in, on either device.
pub(crate) fn load_module(file: &Path, device: Option<ModelDevice>) -> Result<(CModule, Device, String), PolicyError> {
    let device = super::model_device(device, &ModelSize::of_torchscript(file)).map_err(err)?;
    let bytes = std::fs::read(file).map_err(|e| err(format!("{}: {e}", file.display())))?;
    let sha256 = format!("{:x}", Sha256::digest(&bytes));
    let mut module = CModule::load_on_device(file, device)
        .map_err(|e| err(format!("{} is not a TorchScript module libtorch 2.11 can load: {e}", file.display())))?;
    module.set_eval();
    Ok((module, device, sha256))
}

/// An RGB image as a module's image input: float32 `[1, 3, H, W]` in [0, 1].
pub(crate) fn unit_chw_tensor(img: &RgbImage) -> Tensor {
    let (h, w) = (img.height as i64, img.width as i64);
    Tensor::from_slice(&img.rgb)
        .reshape([h, w, 3])
        .permute([2, 0, 1])
        .to_kind(Kind::Float)
        .divide_scalar(255.0)
        .unsqueeze(0)
}

/// A loaded TorchScript module and its manifest: runs batches of observations.
pub struct TorchScriptModel {
    module: CModule,
    manifest: TorchScriptManifest,
    device: Device,
    file: PathBuf,
    sha256: String,
}

impl TorchScriptModel {
    /// Load `file` and its manifest, on the GPU when there is one.
    pub fn load(file: &Path) -> Result<Self, PolicyError> {
        Self::load_on(file, None)
    }

    /// Load `file` and its manifest on `device` (the spec's `devices=`; `None`: the GPU when
    /// there is one).
    pub fn load_on(file: &Path, device: Option<ModelDevice>) -> Result<Self, PolicyError> {
        let (manifest_path, text) = read_manifest(file)?;
        let manifest = TorchScriptManifest::parse(&text, &manifest_path)?;
        let (module, device, sha256) = load_module(file, device)?;
        Ok(TorchScriptModel { module, manifest, device, file: file.to_path_buf(), sha256 })
    }

    /// Identity for the run manifest: the file's hash, its manifest, preprocessing, chunking and
    /// the batch size (`None`: one episode per forward).
    pub fn identity(&self, batch: Option<usize>) -> Value {
        let m = &self.manifest;
        serde_json::json!({
            "kind": "torchscript", "name": NAME,
            "file": self.file.display().to_string(), "sha256": self.sha256,
            "inputs": m.raw.get("inputs"),
            "images": if m.needs_images() {
                serde_json::json!({"render": format!("{0}x{0}, look mujoco-3.2.3", m.render_size),
                                   "preprocessing": format!("{}: {}", m.preprocessing.0, m.preprocessing.1.describe())})
            } else { Value::Null },
            "state": "float32 (8,): eef_pos (3), quat2axisangle(robot0_eef_quat as given) (3), gripper_qpos (2)",
            "chunking": {"predicted": m.chunk_size, "executed": m.replan_steps},
            "unnorm_key": m.stats.as_ref().map(|(k, _)| k.clone()),
            "gripper": m.gripper.0,
            "batch": batch.map_or(serde_json::json!("one episode per forward"), |b| serde_json::json!({"max_episodes_per_forward": b})),
            "device": format!("{:?}", self.device),
        })
    }

    pub fn replan_steps(&self) -> usize {
        self.manifest.replan_steps
    }

    fn image_tensor(&self, cam: &CameraImage) -> Result<Tensor, PolicyError> {
        let img = RgbImage::new(cam.width, cam.height, cam.rgb.clone())
            .and_then(|i| self.manifest.preprocessing.1.apply(&i))
            .map_err(|e| err(format!("image preprocessing: {e}")))?;
        let size = self.manifest.image_size;
        if (img.width, img.height) != (size, size) {
            return Err(err(format!(
                "preprocessing gave {}x{} images, the manifest's image_size is {size}",
                img.width, img.height
            )));
        }
        Ok(unit_chw_tensor(&img))
    }

    /// The forward's arguments for one observation, each with a batch dimension of 1.
    fn inputs(&self, obs: &Observation) -> Result<Vec<Tensor>, PolicyError> {
        self.manifest
            .inputs
            .iter()
            .map(|input| match input {
                Input::State => {
                    let s = libero_state(obs.eef_pos, wxyz_to_xyzw(obs.hand_quat), obs.gripper_qpos, QuatSign::AsGiven);
                    Ok(Tensor::from_slice(&s.map(|x| x as f32)).unsqueeze(0))
                }
                Input::Agentview | Input::Wrist => {
                    let images = obs.images.as_ref().ok_or_else(|| err("the rollout gave no camera images"))?;
                    self.image_tensor(if *input == Input::Agentview { &images.agentview } else { &images.wrist })
                }
            })
            .collect()
    }

    /// One forward for all `observations` (stacked along the batch dimension): a chunk each, in
    /// env units.
    pub fn predict(&self, observations: &[&Observation]) -> Result<Vec<Vec<Action>>, PolicyError> {
        let per_obs = observations.iter().map(|o| self.inputs(o)).collect::<Result<Vec<_>, _>>()?;
        let args: Vec<Tensor> = (0..self.manifest.inputs.len())
            .map(|k| Tensor::cat(&per_obs.iter().map(|a| &a[k]).collect::<Vec<_>>(), 0).to_device(self.device))
            .collect();
        let out = tch::no_grad(|| self.module.forward_ts(&args)).map_err(|e| err(format!("forward: {e}")))?;
        let out = out.to_device(Device::Cpu).to_kind(Kind::Double);
        let b = observations.len() as i64;
        let out = match out.size().as_slice() {
            [n, c, 7] if *n == b => out.reshape([b, *c, 7]),
            [n, 7] if *n == b => out.reshape([b, 1, 7]),
            other => {
                return Err(err(format!("the module returned shape {other:?}; expected [{b}, chunk, 7] or [{b}, 7]")));
            }
        };
        let m = &self.manifest;
        (0..b)
            .map(|i| {
                let rows: Vec<Vec<f64>> =
                    Vec::<Vec<f64>>::try_from(&out.get(i)).map_err(|e| err(format!("reading the output: {e}")))?;
                rows.iter()
                    .map(|r| match &m.stats {
                        Some((_, stats)) => postprocess_action(r, stats, m.gripper.1).map_err(|e| err(e.to_string())),
                        None => {
                            let mut a: Action = std::array::from_fn(|i| r[i] as f32);
                            a[6] = m.gripper.1.apply(r[6]) as f32;
                            Ok(a)
                        }
                    })
                    .collect()
            })
            .collect()
    }
}

impl BatchModel for TorchScriptModel {
    fn device_label(&self) -> Option<String> {
        Some(super::device_label(self.device))
    }

    fn predict_batch(&mut self, requests: &[crate::batching::Request]) -> Vec<Result<Vec<Action>, String>> {
        let observations: Vec<&Observation> = requests.iter().map(|r| &r.obs).collect();
        match self.predict(&observations) {
            Ok(chunks) => chunks.into_iter().map(Ok).collect(),
            // A batch fails together; each episode gets the reason.
            Err(e) => requests.iter().map(|_| Err(e.detail.clone())).collect(),
        }
    }

    fn camera_size(&self) -> Option<u32> {
        self.manifest.needs_images().then_some(self.manifest.render_size)
    }

    fn wants_wrist_camera(&self) -> bool {
        self.manifest.needs_wrist()
    }

    fn replan_steps(&self) -> usize {
        self.manifest.replan_steps
    }
}

/// A TorchScript module run for one episode at a time (`--policy torchscript:<file>`).
pub struct TorchScriptPolicy {
    model: TorchScriptModel,
    chunker: ActionChunker,
}

impl TorchScriptPolicy {
    pub fn load(file: &Path) -> Result<Self, PolicyError> {
        Self::load_on(file, None)
    }

    /// [`Self::load`] on `device` (the spec's `devices=`).
    pub fn load_on(file: &Path, device: Option<ModelDevice>) -> Result<Self, PolicyError> {
        let model = TorchScriptModel::load_on(file, device)?;
        let chunker = ActionChunker::new(model.replan_steps());
        Ok(TorchScriptPolicy { model, chunker })
    }

    pub fn identity(&self) -> Value {
        self.model.identity(None)
    }

    /// Model queries since the episode started.
    pub fn queries(&self) -> u64 {
        self.chunker.queries()
    }
}

impl Policy for TorchScriptPolicy {
    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        self.chunker.set_ensemble(Some(ensemble));
        Ok(())
    }

    fn queries_model(&self) -> bool {
        self.chunker.needs_query()
    }

    fn reset(&mut self, _instruction: &str, _episode_seed: u64) {
        self.chunker.reset();
    }

    fn camera_size(&self) -> Option<u32> {
        (self.model.manifest.needs_images() && self.chunker.needs_query()).then_some(self.model.manifest.render_size)
    }

    fn wants_wrist_camera(&self) -> bool {
        self.model.manifest.needs_wrist()
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        if self.chunker.needs_query() {
            let chunk = self.model.predict(&[obs])?.pop().ok_or_else(|| err("no chunk"))?;
            self.chunker.push_chunk(chunk).map_err(err)?;
        }
        self.chunker.next_action().ok_or_else(|| err("no action queued"))
    }
}
