//! OpenVLA in-process on libtorch: the Prismatic architecture of `openvla/openvla-7b` and its
//! LIBERO fine-tunes, loaded from a Hugging Face checkpoint directory.
//!
//! The pieces, each as openvla's `prismatic/extern/hf/modeling_prismatic.py` computes them:
//!
//! - **Vision** ([`vision`]): the fused DINOv2 (ViT-L/14, 4 registers, LayerScale) + SigLIP
//!   (so400m/14) featurizers, each read at its second-to-last block, patch features concatenated
//!   along channels; `pixel_values` has 3 channels per backbone, each normalised with its own
//!   mean/std (`preprocessor_config.json`).
//! - **Projector**: `fc1 → GELU → fc2 → GELU → fc3` (`fused-gelu-mlp`).
//! - **Language model** ([`llama`]): Llama-2 as transformers' `LlamaForCausalLM`, the projected patches
//!   inserted after `<s>`.
//! - **Action decoding** ([`action`]): the prompt `In: What action should the robot take to
//!   {instruction.lower()}?\nOut:`, token 29871 appended when the prompt does not end with it,
//!   greedy decoding of `action_dim` tokens, token → bin → bin center, un-normalised with the
//!   checkpoint's q01/q99 and mask ([`crate::postprocess::ActionStats`]).
//!
//! The checkpoint directory holds `config.json`, `preprocessor_config.json`, `tokenizer.json`,
//! `model.safetensors.index.json` with its shards, and optionally `dataset_statistics.json`.
//! The image given to [`OpenVlaModel::predict_action`] is the one after the rollout's image
//! preprocessing (180° rotation, JPEG round trip, resize to 224: [`crate::preprocess`]); the
//! processor's own resize to 224 is then the identity.
//!
//! Tested against the Python reference (transformers + timm) on a tiny random-weight model of the
//! same architecture: `tests/openvla_parity.rs`.
//!
//! [`oft`]: OpenVLA-OFT on the same backbone (two images, the proprio token, one bidirectional
//! forward, the L1 regression head's 8 × 7 chunk), its `.pt` heads read by [`crate::models::torch_save`].

pub mod action;
pub mod config;
mod llama;
pub mod oft;
pub mod policy;
mod vision;
mod weights;

use crate::PolicyError;
use crate::placement::Quantization;
use crate::preprocess::RgbImage;
pub use action::ActionBins;
pub use config::OpenVlaConfig;
pub use llama::{Attention, FUSED_QKV_DECODE_MAX_ROWS, Fusion, STATIC_CACHE_MIN_ROWS};

/// What the language model's kernels are, for the run manifest ([`Fusion`]).
pub const KERNELS: &str = "GPU: one GEMM for q/k/v and one for gate/up, torch's fused RMSNorm, the rotary embedding with a fused \
     multiply-add (logits within bf16 rounding of transformers' operations); CPU: transformers' operations one by one";
pub use policy::{OpenVlaBatchModel, OpenVlaPolicy};
use std::path::Path;
use tch::{Device, Kind, Tensor};

/// Errors name the policy `openvla`.
pub type OpenVlaError = PolicyError;

pub(crate) fn bad(detail: impl Into<String>) -> OpenVlaError {
    PolicyError { policy: "openvla".into(), detail: detail.into() }
}

/// Llama-2's `▁` token, which OpenVLA was trained to see after `Out:`.
pub const EMPTY_TOKEN: i64 = 29871;

/// openvla's LIBERO prompt (`experiments/robot/openvla_utils.py`, OpenVLA v0.1 excepted).
pub fn prompt(instruction: &str) -> String {
    format!("In: What action should the robot take to {}?\nOut:", instruction.to_lowercase())
}

/// One greedy decode.
#[derive(Debug)]
pub struct OpenVlaPrediction {
    /// The prompt's token ids, `<s>` first and 29871 last.
    pub input_ids: Vec<i64>,
    /// The generated action tokens.
    pub tokens: Vec<i64>,
    pub bins: Vec<usize>,
    /// In [-1, 1].
    pub normalized_action: Vec<f64>,
    /// Un-normalised with the checkpoint's statistics (q01/q99 where `mask`).
    pub action: Vec<f64>,
    /// `[action_dim, padded vocab]` f32: the last position's logits before each generated token.
    pub step_logits: Tensor,
}

pub struct OpenVlaModel {
    config: OpenVlaConfig,
    tower: vision::VisionTower,
    llm: llama::Llama,
    tokenizer: tokenizers::Tokenizer,
    bos: i64,
    bins: ActionBins,
    device: Device,
    kind: Kind,
}

impl OpenVlaModel {
    /// Loads `dir` on the CPU in f32.
    pub fn load(dir: &Path) -> Result<Self, OpenVlaError> {
        Self::load_on(dir, Device::Cpu, Kind::Float)
    }

    /// Loads `dir` on `device` with weights and activations in `kind` (the released checkpoints are
    /// bf16; RMSNorm, softmax and the logits are computed in f32 as transformers does).
    pub fn load_on(dir: &Path, device: Device, kind: Kind) -> Result<Self, OpenVlaError> {
        Self::load_quantized(dir, device, kind, Quantization::None)
    }

    /// [`Self::load_on`] with the linear layers of the vision towers, the projector and the
    /// language model stored as `quant` says (`models::quant`; the embeddings, the LM head, the
    /// norms and the patch embedding stay in `kind`).
    pub fn load_quantized(dir: &Path, device: Device, kind: Kind, quant: Quantization) -> Result<Self, OpenVlaError> {
        let config = OpenVlaConfig::load(dir)?;
        let tok_path = dir.join("tokenizer.json");
        if !tok_path.exists() {
            return Err(bad(format!(
                "{} is missing (only tokenizer.model?): write it once with transformers, \
                 `AutoTokenizer.from_pretrained(DIR).save_pretrained(DIR)`, which adds tokenizer.json",
                tok_path.display()
            )));
        }
        let tokenizer =
            tokenizers::Tokenizer::from_file(&tok_path).map_err(|e| bad(format!("{}: {e}", tok_path.display())))?;
        let bos =
            tokenizer.token_to_id("<s>").ok_or_else(|| bad(format!("{}: no <s> token", tok_path.display())))? as i64;
        let mut w = weights::Weights::load(dir, device, kind, quant)?;
        let names = ["vision_backbone.featurizer.", "vision_backbone.fused_featurizer."];
        let mut featurizers = Vec::new();
        for (bc, prefix) in config.backbones.iter().zip(names) {
            featurizers.push(vision::Vit::load(&mut w, prefix, bc.num_heads, bc.quick_gelu, bc.image_size)?);
        }
        let tower = vision::VisionTower::new(featurizers, &mut w)?;
        let llm = llama::Llama::load(&mut w, &config.text, device)?;
        let bins = ActionBins::new(config.action_vocab_size, config.n_action_bins);
        Ok(OpenVlaModel { config, tower, llm, tokenizer, bos, bins, device, kind })
    }

    pub fn config(&self) -> &OpenVlaConfig {
        &self.config
    }

    /// The language model's attention implementation: eager by default, as the parity reference
    /// runs it (see [`Attention`]).
    pub fn set_attention(&mut self, attention: Attention) {
        self.llm.set_attention(attention);
    }

    /// The language model's launch-saving kernels ([`Fusion`]: all on by default on CUDA, none on a CPU).
    pub fn set_fusion(&mut self, fusion: Fusion) {
        self.llm.set_fusion(fusion);
    }

    pub fn fusion(&self) -> Fusion {
        self.llm.fusion()
    }

    pub fn attention(&self) -> Attention {
        self.llm.attention()
    }

    /// The processor's `pixel_values` `[1, 3·backbones, H, W]` of one image already at the model's
    /// size: per backbone `(x / 255 - mean) / std`.
    pub fn pixel_values(&self, image: &RgbImage) -> Result<Tensor, OpenVlaError> {
        let size = self.config.backbones[0].image_size;
        if i64::from(image.width) != size || i64::from(image.height) != size {
            return Err(bad(format!(
                "the image is {}x{}; OpenVLA takes {size}x{size} (after the rollout's preprocessing)",
                image.width, image.height
            )));
        }
        let x = Tensor::from_slice(&image.rgb).view([size, size, 3]).permute([2, 0, 1]).to_kind(Kind::Float) / 255.0;
        let parts: Vec<Tensor> = self
            .config
            .backbones
            .iter()
            .map(|b| {
                let mean = Tensor::from_slice(&b.mean.map(|m| m as f32)).view([3, 1, 1]);
                let std = Tensor::from_slice(&b.std.map(|s| s as f32)).view([3, 1, 1]);
                (&x - mean) / std
            })
            .collect();
        Ok(Tensor::cat(&parts, 0).unsqueeze(0).to_device(self.device).to_kind(self.kind))
    }

    /// The prompt's token ids: `<s>` first (the tokenizer's template adds it), 29871 last.
    pub fn input_ids(&self, instruction: &str) -> Result<Vec<i64>, OpenVlaError> {
        let enc = self.tokenizer.encode(prompt(instruction), true).map_err(|e| bad(format!("tokenizer: {e}")))?;
        let mut ids: Vec<i64> = enc.get_ids().iter().map(|&i| i64::from(i)).collect();
        if ids.first() != Some(&self.bos) {
            ids.insert(0, self.bos);
        }
        if ids.last() != Some(&EMPTY_TOKEN) {
            ids.push(EMPTY_TOKEN);
        }
        Ok(ids)
    }

    /// The fused patch features `[B, patches, vision width]` and their projection `[B, patches, llm]`.
    pub fn vision_features(&self, pixel_values: &Tensor) -> (Tensor, Tensor) {
        tch::no_grad(|| {
            let patches = self.tower.patch_features(pixel_values);
            let projected = self.tower.project(&patches);
            (patches, projected)
        })
    }

    /// OpenVLA's `predict_action` on one image (RGB, at the model's size, as the rollout's
    /// preprocessing leaves it) and instruction; `unnorm_key` selects the dataset statistics (`None`
    /// when the checkpoint has one dataset).
    pub fn predict_action(
        &self,
        image: &RgbImage,
        instruction: &str,
        unnorm_key: Option<&str>,
    ) -> Result<OpenVlaPrediction, OpenVlaError> {
        let mut batch = self.predict_actions(&[(image, instruction)], unnorm_key)?;
        Ok(batch.remove(0))
    }

    /// [`Self::predict_action`] for several (image, instruction) pairs in one forward: the vision
    /// tower runs on the stacked images, the prompts (of different lengths) are left-padded to one
    /// length, and each decode step is one forward of the whole batch. Each row's result is its
    /// result alone, up to the order of floating-point sums.
    pub fn predict_actions(
        &self,
        queries: &[(&RgbImage, &str)],
        unnorm_key: Option<&str>,
    ) -> Result<Vec<OpenVlaPrediction>, OpenVlaError> {
        let stats = self.config.norm_stats.action(unnorm_key).map_err(|e| bad(e.to_string()))?.clone();
        if queries.is_empty() {
            return Ok(Vec::new());
        }
        let mut pixel_values = Vec::with_capacity(queries.len());
        let mut input_ids = Vec::with_capacity(queries.len());
        for (image, instruction) in queries {
            pixel_values.push(self.pixel_values(image)?);
            input_ids.push(self.input_ids(instruction)?);
        }
        let (_, projected) = self.vision_features(&Tensor::cat(&pixel_values, 0));
        let longest = input_ids.iter().map(Vec::len).max().unwrap_or(0);
        let left_pad: Vec<i64> = input_ids.iter().map(|ids| (longest - ids.len()) as i64).collect();
        let (tokens, step_logits) = tch::no_grad(|| {
            // per row: [padding, <s>, image patches, prompt tokens]
            let rows: Vec<Tensor> = input_ids
                .iter()
                .zip(&left_pad)
                .enumerate()
                .map(|(b, (ids, &pad))| {
                    let ids = Tensor::from_slice(ids).view([1, -1]).to_device(self.device);
                    let emb = self.llm.embed(&ids);
                    let (n, width) = (emb.size()[1], emb.size()[2]);
                    let padding = Tensor::zeros([1, pad, width], (emb.kind(), self.device));
                    let patches = projected.narrow(0, b as i64, 1);
                    Tensor::cat(&[padding, emb.narrow(1, 0, 1), patches, emb.narrow(1, 1, n - 1)], 1)
                })
                .collect();
            // room for the prompt and the generated tokens but the last (it is not fed back)
            let capacity = (longest + projected.size()[1] as usize + stats.dim()) as i64;
            let mut cache = self.llm.new_cache_with_capacity(&left_pad, capacity);
            let mut logits = self.llm.forward(&Tensor::cat(&rows, 0), &mut cache);
            // the tokens stay on the device until the last step: a read-back per step would make
            // the host wait for each step's kernels before it could queue the next step's
            let (mut next_tokens, mut all) = (Vec::new(), Vec::new());
            for step in 0..stats.dim() {
                let next = logits.argmax(-1, false);
                if step + 1 < stats.dim() {
                    let following = self.llm.forward(&self.llm.embed(&next.view([-1, 1])), &mut cache);
                    all.push(std::mem::replace(&mut logits, following));
                } else {
                    all.push(logits.shallow_clone());
                }
                next_tokens.push(next);
            }
            // `[action_dim, B]` on the host, one read-back
            let steps = Tensor::stack(&next_tokens, 0).to_device(Device::Cpu);
            let tokens: Vec<Vec<i64>> = (0..stats.dim() as i64)
                .map(|s| Vec::<i64>::try_from(&steps.get(s)).expect("argmax is int64"))
                .collect();
            // `[B, action_dim, vocab]`
            (tokens, Tensor::stack(&all, 1))
        });
        let predictions = input_ids
            .into_iter()
            .enumerate()
            .map(|(b, input_ids)| {
                let tokens: Vec<i64> = tokens.iter().map(|step| step[b]).collect();
                let bins: Vec<usize> = tokens.iter().map(|&t| self.bins.bin(t)).collect();
                let normalized_action: Vec<f64> = bins.iter().map(|&b| self.bins.center(b)).collect();
                let action = stats.unnormalize(&normalized_action);
                // a copy: a view would keep the whole batch's logits alive
                let step_logits = step_logits.get(b as i64).copy();
                OpenVlaPrediction { input_ids, tokens, bins, normalized_action, action, step_logits }
            })
            .collect();
        Ok(predictions)
    }
}
