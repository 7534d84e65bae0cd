//! OpenVLA-OFT (`moojink/openvla-oft`) in-process: the OpenVLA backbone of this module with OFT's
//! parallel decoding, as its `predict_action` computes it (openvla-oft 213c5ff8,
//! `prismatic/extern/hf/modeling_prismatic.py`, `prismatic/models/{action_heads,projectors}.py`):
//!
//! - **Two images**, third-person then wrist, each through the vision backbone and projector: 2 ×
//!   256 patch tokens along the sequence.
//! - **The proprio token**: `ProprioProjector` (`fc1` Linear(8, llm), exact GELU, `fc2`) of the
//!   state normalised with the checkpoint's `proprio` q01/q99 (`clip(2 (s − q01)/(q99 − q01 + 1e-8)
//!   − 1, −1, 1)` where `mask`), appended after the patches.
//! - **The sequence** `[<s>] [512 patches] [proprio] [prompt tokens, 29871 last] [56 zero
//!   embeddings] [</s>]`: the prompt is OpenVLA's; the 7 × 8 placeholder ids (1) have their
//!   embeddings zeroed; `</s>` keeps its embedding.
//! - **One bidirectional forward** ([`super::llama::Llama::forward_full`]): openvla-oft's
//!   transformers fork runs SDPA with `is_causal=False` and only the padding mask.
//! - **The readout** `hidden_states[-1][NUM_PATCHES + NUM_PROMPT_TOKENS ..][..56]` (shifted by
//!   one: from the last prompt token to the second-to-last placeholder), reshaped to `(8, 7 ·
//!   llm)` and run through `L1RegressionActionHead` (an MLPResNet: LayerNorm, fc1, ReLU, 2 ×
//!   [LayerNorm, Linear, ReLU, + residual], LayerNorm, fc2): the normalised 8 × 7 chunk.
//! - **Un-normalisation** BOUNDS_Q99 with OFT's `+ 1e-8`: `0.5 (a + 1) (q99 − q01 + 1e-8) + q01`
//!   where `mask`, in numpy's precision (the head's f32 output, `0.5 (a + 1)` in f32, the rest in
//!   f64).
//!
//! The checkpoint directory is a released OFT LIBERO repository: the HF files of an OpenVLA
//! checkpoint (merged LoRA), `dataset_statistics.json` with `action` and `proprio` statistics,
//! and one `action_head--<step>_checkpoint.pt` and one `proprio_projector--<step>_checkpoint.pt`
//! (`torch.save`d state dicts whose keys carry DDP's `module.` prefix, read by [`crate::models::torch_save`]).
//!
//! Tested against the Python reference (transformers + timm + OFT's head and projector classes)
//! on a tiny random-weight model in the same layout: `tests/oft_parity.rs`.

mod policy;

pub use policy::{OftBatchModel, OftPolicy};

use super::{OpenVlaError, OpenVlaModel, bad};
use crate::models::torch_save::read_state_dict;
use crate::placement::Quantization;
use crate::postprocess::ActionStats;
use crate::preprocess::RgbImage;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use tch::{Device, Kind, Tensor};

/// Action dimensions (`ACTION_DIM` of openvla-oft's `prismatic/vla/constants.py`, LIBERO).
pub const ACTION_DIM: usize = 7;
/// Actions per chunk (`NUM_ACTIONS_CHUNK`, LIBERO).
pub const NUM_ACTIONS_CHUNK: usize = 8;
/// The LIBERO state's dimensions (`PROPRIO_DIM`).
pub const PROPRIO_DIM: usize = 8;
/// Images per query in OFT's LIBERO loop (`num_images_in_input`): agentview, wrist.
pub const NUM_IMAGES: usize = 2;
/// The placeholder id of the action positions (its embedding is zeroed).
const PLACEHOLDER_TOKEN: i64 = 1;
/// `</s>` after the placeholders (`STOP_INDEX`).
const STOP_TOKEN: i64 = 2;
/// torch.nn.LayerNorm's default.
const LN_EPS: f64 = 1e-5;
const READOUT: i64 = (ACTION_DIM * NUM_ACTIONS_CHUNK) as i64;

/// The two `.pt` files of an OFT checkpoint directory.
#[derive(Debug, Clone, PartialEq)]
pub struct OftFiles {
    pub action_head: PathBuf,
    pub proprio_projector: PathBuf,
}

impl OftFiles {
    /// `action_head--*_checkpoint.pt` and `proprio_projector--*_checkpoint.pt` of `dir`: exactly
    /// one of each (the step differs per release: 150000, 50000 for goal, 300000 for the joint one).
    pub fn find(dir: &Path) -> Result<Self, OpenVlaError> {
        let entries: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| bad(format!("{}: {e}", dir.display())))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file())
            .collect();
        let one = |stem: &str| -> Result<PathBuf, OpenVlaError> {
            let mut found: Vec<&PathBuf> = entries
                .iter()
                .filter(|p| {
                    let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
                    name.starts_with(&format!("{stem}--")) && name.ends_with("_checkpoint.pt")
                })
                .collect();
            found.sort();
            match found.as_slice() {
                [one] => Ok((*one).clone()),
                [] => Err(bad(format!(
                    "{}: no {stem}--<step>_checkpoint.pt (an OpenVLA-OFT checkpoint directory holds the HF files, \
                     action_head--*.pt, proprio_projector--*.pt and dataset_statistics.json)",
                    dir.display()
                ))),
                several => Err(bad(format!(
                    "{}: several {stem} files ({}); keep the one of the checkpoint's step",
                    dir.display(),
                    several.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
                ))),
            }
        };
        Ok(OftFiles { action_head: one("action_head")?, proprio_projector: one("proprio_projector")? })
    }
}

/// The `proprio` statistics of one dataset.
#[derive(Debug, Clone, PartialEq)]
pub struct ProprioStats {
    pub q01: Vec<f64>,
    pub q99: Vec<f64>,
    pub mask: Vec<bool>,
}

impl ProprioStats {
    /// `normalize_proprio` (BOUNDS_Q99): `clip(where(mask, 2 (s − q01)/(q99 − q01 + 1e-8) − 1, s),
    /// −1, 1)`, in f64 as numpy.
    pub fn normalize(&self, state: &[f64]) -> Vec<f64> {
        state
            .iter()
            .enumerate()
            .map(|(i, &s)| {
                let v =
                    if self.mask[i] { 2.0 * (s - self.q01[i]) / (self.q99[i] - self.q01[i] + 1e-8) - 1.0 } else { s };
                v.clamp(-1.0, 1.0)
            })
            .collect()
    }
}

/// Every dataset's `proprio` statistics in `dataset_statistics.json`.
fn proprio_stats(dir: &Path) -> Result<HashMap<String, ProprioStats>, OpenVlaError> {
    let path = dir.join("dataset_statistics.json");
    let text = std::fs::read_to_string(&path)
        .map_err(|e| bad(format!("{}: {e} (OpenVLA-OFT needs its proprio statistics)", path.display())))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("{}: not JSON: {e}", path.display())))?;
    let obj = v.as_object().ok_or_else(|| bad(format!("{}: not an object of unnorm keys", path.display())))?;
    let mut out = HashMap::new();
    for (key, entry) in obj {
        let Some(p) = entry.get("proprio") else { continue };
        let floats = |f: &str| -> Result<Vec<f64>, OpenVlaError> {
            p.get(f)
                .and_then(|x| x.as_array())
                .and_then(|a| a.iter().map(serde_json::Value::as_f64).collect::<Option<Vec<f64>>>())
                .ok_or_else(|| bad(format!("{}: {key}.proprio.{f} is not a list of numbers", path.display())))
        };
        let (q01, q99) = (floats("q01")?, floats("q99")?);
        let mask = match p.get("mask").and_then(|m| m.as_array()) {
            Some(m) => m.iter().map(|b| b.as_bool().unwrap_or(true)).collect(),
            None => vec![true; q01.len()],
        };
        if q01.len() != PROPRIO_DIM || q99.len() != PROPRIO_DIM || mask.len() != PROPRIO_DIM {
            return Err(bad(format!("{}: {key}.proprio: expected {PROPRIO_DIM} dimensions", path.display())));
        }
        out.insert(key.clone(), ProprioStats { q01, q99, mask });
    }
    Ok(out)
}

/// OFT's un-normalisation of one action, in numpy's precision: the head's f32 output `a`,
/// `0.5 * (a + 1)` in f32 (numpy keeps a float32 array's dtype against Python scalars), then
/// `* (q99 − q01 + 1e-8) + q01` in f64 where `mask`; `a` itself elsewhere.
pub fn unnormalize(stats: &ActionStats, normalized: &[f32]) -> Vec<f64> {
    normalized
        .iter()
        .enumerate()
        .map(|(i, &a)| {
            if stats.mask[i] {
                let half = 0.5f32 * (a + 1.0f32);
                f64::from(half) * (stats.q99[i] - stats.q01[i] + 1e-8) + stats.q01[i]
            } else {
                f64::from(a)
            }
        })
        .collect()
}

type Linear = (Tensor, Tensor);

/// `L1RegressionActionHead.model` (MLPResNet).
struct ActionHead {
    layer_norm1: Linear,
    fc1: Linear,
    blocks: Vec<(Linear, Linear)>,
    layer_norm2: Linear,
    fc2: Linear,
}

struct ProprioProjector {
    fc1: Linear,
    fc2: Linear,
}

fn ln(x: &Tensor, (w, b): &Linear) -> Tensor {
    x.layer_norm([w.size()[0]], Some(w), Some(b), LN_EPS, true)
}

fn lin(x: &Tensor, (w, b): &Linear) -> Tensor {
    x.linear(w, Some(b))
}

/// A state dict of `path`, DDP's `module.` prefix stripped (`load_component_state_dict`).
struct Component {
    path: PathBuf,
    tensors: HashMap<String, Tensor>,
}

impl Component {
    fn load(path: &Path, device: Device, kind: Kind) -> Result<Self, OpenVlaError> {
        let named = read_state_dict(path).map_err(bad)?;
        let tensors = named
            .into_iter()
            .map(|(k, t)| (k.strip_prefix("module.").unwrap_or(&k).to_string(), t.to_device(device).to_kind(kind)))
            .collect();
        Ok(Component { path: path.to_path_buf(), tensors })
    }
    fn take(&mut self, name: &str) -> Result<Tensor, OpenVlaError> {
        self.tensors.remove(name).ok_or_else(|| bad(format!("{}: no tensor {name:?}", self.path.display())))
    }
    fn linear(&mut self, prefix: &str) -> Result<Linear, OpenVlaError> {
        Ok((self.take(&format!("{prefix}.weight"))?, self.take(&format!("{prefix}.bias"))?))
    }
    fn shape_error(&self, what: &str) -> OpenVlaError {
        bad(format!("{}: {what}", self.path.display()))
    }
}

impl ActionHead {
    fn load(c: &mut Component, hidden: i64) -> Result<Self, OpenVlaError> {
        let layer_norm1 = c.linear("model.layer_norm1")?;
        let fc1 = c.linear("model.fc1")?;
        let mut blocks = Vec::new();
        while c.tensors.contains_key(&format!("model.mlp_resnet_blocks.{}.ffn.0.weight", blocks.len())) {
            let p = format!("model.mlp_resnet_blocks.{}.ffn", blocks.len());
            blocks.push((c.linear(&format!("{p}.0"))?, c.linear(&format!("{p}.1"))?));
        }
        let layer_norm2 = c.linear("model.layer_norm2")?;
        let fc2 = c.linear("model.fc2")?;
        let input = hidden * ACTION_DIM as i64;
        if fc1.0.size() != [fc1.0.size()[0], input] || fc2.0.size()[0] != ACTION_DIM as i64 {
            return Err(c.shape_error(&format!(
                "fc1 {:?} / fc2 {:?}: the L1 regression head takes {ACTION_DIM} x {hidden} (the LLM width) and gives \
                 {ACTION_DIM} numbers",
                fc1.0.size(),
                fc2.0.size()
            )));
        }
        Ok(ActionHead { layer_norm1, fc1, blocks, layer_norm2, fc2 })
    }

    /// `[B, 8, 7·hidden]` → `[B, 8, 7]`.
    fn forward(&self, x: &Tensor) -> Tensor {
        let mut x = lin(&ln(x, &self.layer_norm1), &self.fc1).relu();
        for (norm, fc) in &self.blocks {
            x = &x + lin(&ln(&x, norm), fc).relu();
        }
        lin(&ln(&x, &self.layer_norm2), &self.fc2)
    }
}

impl ProprioProjector {
    fn load(c: &mut Component, hidden: i64) -> Result<Self, OpenVlaError> {
        let fc1 = c.linear("fc1")?;
        let fc2 = c.linear("fc2")?;
        if fc1.0.size() != [hidden, PROPRIO_DIM as i64] || fc2.0.size() != [hidden, hidden] {
            return Err(c.shape_error(&format!(
                "fc1 {:?} / fc2 {:?}: the proprio projector maps {PROPRIO_DIM} numbers to the LLM width {hidden}",
                fc1.0.size(),
                fc2.0.size()
            )));
        }
        Ok(ProprioProjector { fc1, fc2 })
    }

    /// `[B, 8]` → `[B, hidden]`.
    fn forward(&self, x: &Tensor) -> Tensor {
        lin(&lin(x, &self.fc1).gelu("none"), &self.fc2)
    }
}

/// One query: the two images after the loop's preprocessing (at the model's size), the raw
/// 8-dim state and the instruction.
#[derive(Debug, Clone, Copy)]
pub struct OftQuery<'a> {
    pub primary: &'a RgbImage,
    pub wrist: &'a RgbImage,
    pub state: [f64; PROPRIO_DIM],
    pub instruction: &'a str,
}

/// One parallel decode.
#[derive(Debug)]
pub struct OftPrediction {
    /// The prompt's token ids, `<s>` first and 29871 last (without the placeholders and `</s>`).
    pub input_ids: Vec<i64>,
    /// The state after `normalize_proprio`.
    pub proprio: Vec<f64>,
    /// `[56, hidden]` f32: the readout hidden states the head sees.
    pub readout: Tensor,
    /// The head's output, 8 × 7.
    pub normalized: Vec<[f32; ACTION_DIM]>,
    /// Un-normalised, 8 × 7 (the gripper not yet mapped to the env's convention).
    pub actions: Vec<[f64; ACTION_DIM]>,
}

pub struct OftModel {
    base: OpenVlaModel,
    head: ActionHead,
    proprio: ProprioProjector,
    proprio_stats: HashMap<String, ProprioStats>,
    files: OftFiles,
}

impl OftModel {
    /// Where the model runs (the backbone's device; the heads sit beside it).
    pub fn device(&self) -> Device {
        self.base.device()
    }

    /// Loads `dir` on the CPU in f32.
    pub fn load(dir: &Path) -> Result<Self, OpenVlaError> {
        Self::load_on(dir, Device::Cpu, Kind::Float)
    }

    /// Loads `dir` on `device` in `kind` (bf16 on a GPU, as OFT's LIBERO runs).
    pub fn load_on(dir: &Path, device: Device, kind: Kind) -> Result<Self, OpenVlaError> {
        Self::load_quantized(dir, device, kind, Quantization::None)
    }

    /// [`Self::load_on`] with the backbone's linear layers stored as `quant` says
    /// ([`OpenVlaModel::load_quantized`]); the action head and the proprio projector (small, and
    /// they compute the actions themselves) stay in `kind`.
    pub fn load_quantized(dir: &Path, device: Device, kind: Kind, quant: Quantization) -> Result<Self, OpenVlaError> {
        let files = OftFiles::find(dir)?;
        let proprio_stats = proprio_stats(dir)?;
        let mut base = OpenVlaModel::load_quantized(dir, device, kind, quant)?;
        // openvla-oft's get_vla loads transformers' SDPA attention (its fork makes it bidirectional)
        base.set_attention(super::Attention::model_default(true, device.is_cuda()));
        let hidden = base.config.text.hidden_size;
        let head = ActionHead::load(&mut Component::load(&files.action_head, device, kind)?, hidden)?;
        let proprio = ProprioProjector::load(&mut Component::load(&files.proprio_projector, device, kind)?, hidden)?;
        Ok(OftModel { base, head, proprio, proprio_stats, files })
    }

    pub fn config(&self) -> &super::OpenVlaConfig {
        self.base.config()
    }

    /// The attention implementation (SDPA, as OFT loads it; eager for comparisons).
    /// The backbone's launch-saving kernels ([`super::Fusion`]).
    pub fn set_fusion(&mut self, fusion: super::Fusion) {
        self.base.set_fusion(fusion);
    }

    pub fn fusion(&self) -> super::Fusion {
        self.base.fusion()
    }

    pub fn set_attention(&mut self, attention: super::Attention) {
        self.base.set_attention(attention);
    }

    pub fn attention(&self) -> super::Attention {
        self.base.attention()
    }

    pub fn files(&self) -> &OftFiles {
        &self.files
    }

    /// The prompt's token ids (OpenVLA's).
    pub fn input_ids(&self, instruction: &str) -> Result<Vec<i64>, OpenVlaError> {
        self.base.input_ids(instruction)
    }

    /// The statistics of `unnorm_key` (the only dataset's with `None`): action and proprio.
    pub fn stats(&self, unnorm_key: Option<&str>) -> Result<(ActionStats, ProprioStats), OpenVlaError> {
        check_stats(self.base.config(), &self.proprio_stats, unnorm_key)
    }

    /// The proprio token of one state, `[hidden]` f32 (for tests).
    pub fn proprio_token(&self, state: &[f64; PROPRIO_DIM], unnorm_key: Option<&str>) -> Result<Tensor, OpenVlaError> {
        let (_, ps) = self.stats(unnorm_key)?;
        let x = self.proprio_input(&[ps.normalize(state)]);
        Ok(tch::no_grad(|| self.proprio.forward(&x)).get(0).to_kind(Kind::Float).to_device(Device::Cpu))
    }

    fn proprio_input(&self, normalized: &[Vec<f64>]) -> Tensor {
        // `torch.Tensor(proprio)`: f32, then the model's dtype
        let flat: Vec<f32> = normalized.iter().flatten().map(|&v| v as f32).collect();
        Tensor::from_slice(&flat)
            .view([normalized.len() as i64, PROPRIO_DIM as i64])
            .to_device(self.base.device)
            .to_kind(self.base.kind)
    }

    /// [`Self::predict_chunks`] for one query.
    pub fn predict_chunk(&self, query: &OftQuery, unnorm_key: Option<&str>) -> Result<OftPrediction, OpenVlaError> {
        Ok(self.predict_chunks(std::slice::from_ref(query), unnorm_key)?.remove(0))
    }

    /// OFT's `predict_action` for several queries in one forward: the prompts (of different
    /// lengths) left-padded to one length, padding masked as keys and positions counted from each
    /// row's first real token, each row's readout taken at its own offset. Each row's result is its
    /// result alone, up to the order of floating-point sums.
    pub fn predict_chunks(
        &self,
        queries: &[OftQuery],
        unnorm_key: Option<&str>,
    ) -> Result<Vec<OftPrediction>, OpenVlaError> {
        let (action_stats, proprio_stats) = self.stats(unnorm_key)?;
        if action_stats.dim() != ACTION_DIM {
            return Err(bad(format!(
                "the statistics have {} action dimensions; OFT predicts {ACTION_DIM}",
                action_stats.dim()
            )));
        }
        if queries.is_empty() {
            return Ok(Vec::new());
        }
        let b = queries.len() as i64;
        let mut input_ids = Vec::with_capacity(queries.len());
        let mut proprio = Vec::with_capacity(queries.len());
        for q in queries {
            input_ids.push(self.base.input_ids(q.instruction)?);
            proprio.push(proprio_stats.normalize(&q.state));
        }
        // primary, wrist per row
        let images: Vec<&RgbImage> = queries.iter().flat_map(|q| [q.primary, q.wrist]).collect();
        let pixel_values = self.base.pixel_values_of(&images)?;
        let (normalized, readout) = tch::no_grad(|| {
            // `[2B, patches, hidden]` (primary, wrist per row) → `[B, 2·patches, hidden]`
            let (_, projected) = self.base.vision_features(&pixel_values);
            let (n_img, width) = (projected.size()[1], projected.size()[2]);
            let projected = projected.reshape([b, NUM_IMAGES as i64 * n_img, width]);
            let proprio_tokens = self.proprio.forward(&self.proprio_input(&proprio)).unsqueeze(1);
            let num_patches = projected.size()[1] + 1;
            let lengths: Vec<i64> = input_ids.iter().map(|ids| ids.len() as i64 + READOUT + 1).collect();
            let longest = *lengths.iter().max().unwrap_or(&0);
            let left_pad: Vec<i64> = lengths.iter().map(|l| longest - l).collect();
            // per row: [padding, <s>, patches, proprio, prompt tokens after <s>, READOUT zeros, </s>],
            // gathered in one operation from [the left-padded ids (the placeholders among them),
            // the patches and proprio tokens, a zero]
            let rows: Vec<Vec<i64>> = input_ids
                .iter()
                .map(|ids| {
                    let mut all = ids.clone();
                    all.extend(std::iter::repeat_n(PLACEHOLDER_TOKEN, READOUT as usize));
                    all.push(STOP_TOKEN);
                    all
                })
                .collect();
            let t = longest + num_patches;
            let (patch_col, zero_col) = (longest, longest + num_patches);
            let mut starts = Vec::with_capacity(queries.len());
            let mut cols = Vec::with_capacity((b * t) as usize);
            for (ids, &pad) in input_ids.iter().zip(&left_pad) {
                let n = ids.len() as i64;
                let readout = pad + num_patches + n;
                starts.push(readout - 1);
                cols.extend((0..t).map(|p| match p {
                    p if p < pad => zero_col,
                    p if p == pad => pad,
                    p if p <= pad + num_patches => patch_col + (p - pad - 1),
                    p if (readout..readout + READOUT).contains(&p) => zero_col,
                    // a prompt token after <s>, or </s>: that index past the padding
                    p => p - num_patches,
                }));
            }
            let source = super::with_zero(&[&self.base.embed_left_padded(&rows), &projected, &proprio_tokens]);
            let embeds = super::gather_positions(&source, &cols, t);
            let hidden = self.base.llm.forward_full(&embeds, &left_pad);
            let readout: Vec<Tensor> =
                starts.iter().enumerate().map(|(r, &s)| hidden.get(r as i64).narrow(0, s, READOUT)).collect();
            let readout = Tensor::stack(&readout, 0);
            let chunk = self.head.forward(&readout.reshape([b, NUM_ACTIONS_CHUNK as i64, -1]));
            (chunk.to_kind(Kind::Float).to_device(Device::Cpu), readout.to_kind(Kind::Float).to_device(Device::Cpu))
        });
        let values: Vec<f32> = Vec::try_from(normalized.flatten(0, -1)).map_err(|e| bad(format!("the chunk: {e}")))?;
        let per_row = NUM_ACTIONS_CHUNK * ACTION_DIM;
        Ok(input_ids
            .into_iter()
            .zip(proprio)
            .enumerate()
            .map(|(r, (input_ids, proprio))| {
                let row = &values[r * per_row..(r + 1) * per_row];
                let normalized: Vec<[f32; ACTION_DIM]> =
                    row.chunks(ACTION_DIM).map(|a| std::array::from_fn(|i| a[i])).collect();
                let actions = normalized
                    .iter()
                    .map(|a| {
                        let u = unnormalize(&action_stats, a);
                        std::array::from_fn(|i| u[i])
                    })
                    .collect();
                OftPrediction { input_ids, proprio, readout: readout.get(r as i64), normalized, actions }
            })
            .collect())
    }
}

/// The action and proprio statistics of `unnorm_key`; a wrong or missing key names the keys the
/// checkpoint has.
pub(crate) fn check_stats(
    config: &super::OpenVlaConfig,
    proprio: &HashMap<String, ProprioStats>,
    unnorm_key: Option<&str>,
) -> Result<(ActionStats, ProprioStats), OpenVlaError> {
    let action = config.norm_stats.action(unnorm_key).map_err(|e| bad(e.to_string()))?.clone();
    let key = match unnorm_key {
        Some(k) => k.to_string(),
        None => config.norm_stats.keys().remove(0),
    };
    let p = proprio.get(&key).ok_or_else(|| {
        bad(format!(
            "dataset_statistics.json: {key:?} has no proprio statistics (OpenVLA-OFT normalises its state with them)"
        ))
    })?;
    Ok((action, p.clone()))
}

/// What [`OftModel::load`] checks before loading weights: the two `.pt` files exist, the
/// statistics of `unnorm_key` have actions and proprio. For the run's start (identity).
pub(crate) fn check_dir(
    dir: &Path,
    unnorm_key: Option<&str>,
) -> Result<(super::OpenVlaConfig, OftFiles), OpenVlaError> {
    let files = OftFiles::find(dir)?;
    let config = super::OpenVlaConfig::load(dir)?;
    let proprio = proprio_stats(dir)?;
    check_stats(&config, &proprio, unnorm_key)?;
    Ok((config, files))
}
