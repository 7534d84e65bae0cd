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
pub mod kernels;
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
pub const KERNELS: &str = "GPU: one GEMM for q/k/v and one for gate/up, a preallocated KV cache (8+ sequences), and \
     our own CUDA kernels compiled with NVRTC at load for the rotary embedding (keys written into the cache), the residual \
     add with the RMSNorm, and SwiGLU (where libnvrtc is missing, torch's fused RMSNorm and operators, with a warning); \
     logits within bf16 rounding of transformers' operations; CPU: transformers' operations one by one";
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

/// The phases of [`OpenVlaModel::predict_actions_marked`], in order: the images' upload and
/// normalisation with the prompts' tokenisation, the vision tower and projector, the language
/// model's input, the prefill, the decode steps, and the tokens' read-back.
pub const PHASES: [&str; 6] = ["inputs", "vision", "prompt", "prefill", "decode", "readback"];

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

    /// The language model's attention implementation ([`Attention`]; by default SDPA on a GPU,
    /// as the published loop's flash attention, and eager on a CPU, as the parity reference).
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

    pub fn device(&self) -> Device {
        self.device
    }

    /// Our CUDA kernels ([`kernels`]), or why this model has none.
    pub fn kernels(&self) -> Result<&kernels::Kernels, &str> {
        self.llm.kernels()
    }

    /// The weights' and activations' dtype.
    pub fn kind(&self) -> Kind {
        self.kind
    }

    /// The processor's `pixel_values` `[1, 3·backbones, H, W]` of one image already at the model's
    /// size ([`Self::pixel_values_of`]).
    pub fn pixel_values(&self, image: &RgbImage) -> Result<Tensor, OpenVlaError> {
        self.pixel_values_of(&[image])
    }

    /// The processor's `pixel_values` `[N, 3·backbones, H, W]` of N images already at the model's
    /// size: per backbone `(x / 255 - mean) / std` in f32, then the model's dtype.
    ///
    /// Why on the device, after one upload of the N images' bytes: at N = 64 the host's f32
    /// arithmetic and 64 uploads of 1.2 MB each held the GPU idle before every batched forward.
    /// The divisors are device tensors, not scalars: CUDA divides by a host scalar as a
    /// multiplication by its reciprocal (one ulp off at times), a tensor by IEEE division, which
    /// is what the processor computes on the host. The values are the processor's bit for bit on
    /// either device (`tests/openvla_parity.rs` on the CPU; the bench's `--phases` on CUDA).
    pub fn pixel_values_of(&self, images: &[&RgbImage]) -> Result<Tensor, OpenVlaError> {
        let size = self.config.backbones[0].image_size;
        let mut bytes = Vec::with_capacity(images.len() * (size * size * 3) as usize);
        for image in images {
            if i64::from(image.width) != size || i64::from(image.height) != size {
                return Err(bad(format!(
                    "the image is {}x{}; OpenVLA takes {size}x{size} (after the rollout's preprocessing)",
                    image.width, image.height
                )));
            }
            bytes.extend_from_slice(&image.rgb);
        }
        let on_device = |values: &[f32]| Tensor::from_slice(values).to_device(self.device);
        let x = Tensor::from_slice(&bytes)
            .view([images.len() as i64, size, size, 3])
            .to_device(self.device)
            .permute([0, 3, 1, 2])
            .to_kind(Kind::Float)
            / on_device(&[255.0]);
        let parts: Vec<Tensor> = self
            .config
            .backbones
            .iter()
            .map(|b| {
                let mean = on_device(&b.mean.map(|m| m as f32)).view([1, 3, 1, 1]);
                let std = on_device(&b.std.map(|s| s as f32)).view([1, 3, 1, 1]);
                (&x - mean) / std
            })
            .collect();
        Ok(Tensor::cat(&parts, 1).to_kind(self.kind))
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

    /// The language model's input `[B, T, hidden]`: per row `[padding, <s>, image patches, prompt
    /// tokens after <s>]`, its `left_pad[b]` padding positions zero (they are masked as keys).
    ///
    /// One embedding lookup of the left-padded ids and one gather, whatever B: a row at a time
    /// cost six operations and an upload per row, during which the GPU, done with the vision
    /// tower, had nothing queued.
    fn prompt_embeds(&self, input_ids: &[Vec<i64>], left_pad: &[i64], projected: &Tensor) -> Tensor {
        let patches = projected.size()[1];
        let longest = input_ids.iter().map(Vec::len).max().unwrap_or(0) as i64;
        let t = longest + patches;
        // the gather's source, per row: the padded ids' embeddings, then the patches, then a zero
        let (patch_col, zero_col) = (longest, longest + patches);
        let cols: Vec<i64> = left_pad
            .iter()
            .flat_map(|&pad| {
                (0..t).map(move |p| match p {
                    p if p < pad => zero_col,
                    p if p == pad => pad,
                    p if p <= pad + patches => patch_col + (p - pad - 1),
                    // prompt token `p - pad - patches` after <s>, at that index past the padding
                    p => p - patches,
                })
            })
            .collect();
        let source = with_zero(&[&self.embed_left_padded(input_ids), projected]);
        gather_positions(&source, &cols, t)
    }

    /// The embeddings `[B, longest, hidden]` of token id rows left-padded with `<s>` to the longest.
    pub(crate) fn embed_left_padded(&self, rows: &[Vec<i64>]) -> Tensor {
        let longest = rows.iter().map(Vec::len).max().unwrap_or(0);
        let mut padded = Vec::with_capacity(rows.len() * longest);
        for ids in rows {
            padded.extend(std::iter::repeat_n(self.bos, longest - ids.len()));
            padded.extend_from_slice(ids);
        }
        let ids = Tensor::from_slice(&padded).view([rows.len() as i64, longest as i64]).to_device(self.device);
        self.llm.embed(&ids)
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
        self.predict_actions_marked(queries, unnorm_key, &mut |_| {})
    }

    /// [`Self::predict_actions`], calling `mark` with each [`PHASES`] name as that phase's work has
    /// been queued (the bench's `--phases` synchronises the device there to time each phase).
    pub fn predict_actions_marked(
        &self,
        queries: &[(&RgbImage, &str)],
        unnorm_key: Option<&str>,
        mark: &mut dyn FnMut(&'static str),
    ) -> Result<Vec<OpenVlaPrediction>, OpenVlaError> {
        let stats = self.config.norm_stats.action(unnorm_key).map_err(|e| bad(e.to_string()))?.clone();
        if queries.is_empty() {
            return Ok(Vec::new());
        }
        let images: Vec<&RgbImage> = queries.iter().map(|(image, _)| *image).collect();
        let pixel_values = self.pixel_values_of(&images)?;
        let input_ids =
            queries.iter().map(|(_, instruction)| self.input_ids(instruction)).collect::<Result<Vec<_>, _>>()?;
        mark("inputs");
        let (_, projected) = self.vision_features(&pixel_values);
        mark("vision");
        let longest = input_ids.iter().map(Vec::len).max().unwrap_or(0);
        let left_pad: Vec<i64> = input_ids.iter().map(|ids| (longest - ids.len()) as i64).collect();
        let (tokens, step_logits) = tch::no_grad(|| {
            let embeds = self.prompt_embeds(&input_ids, &left_pad, &projected);
            mark("prompt");
            // room for the prompt and the generated tokens but the last (it is not fed back)
            let capacity = (longest + projected.size()[1] as usize + stats.dim()) as i64;
            let mut cache = self.llm.new_cache_with_capacity(&left_pad, capacity);
            let mut logits = self.llm.forward(&embeds, &mut cache);
            mark("prefill");
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
            mark("decode");
            // `[action_dim, B]` on the host, one read-back
            let steps = Tensor::stack(&next_tokens, 0).to_device(Device::Cpu);
            let tokens: Vec<Vec<i64>> = (0..stats.dim() as i64)
                .map(|s| Vec::<i64>::try_from(&steps.get(s)).expect("argmax is int64"))
                .collect();
            mark("readback");
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

/// `parts` (`[B, n, hidden]` each) concatenated along positions, then one zero position: the
/// source of [`gather_positions`], whose padding and placeholder positions point at the zero.
pub(crate) fn with_zero(parts: &[&Tensor]) -> Tensor {
    let first = parts[0];
    let (b, width) = (first.size()[0], first.size()[2]);
    let zero = Tensor::zeros([b, 1, width], (first.kind(), first.device()));
    let mut all: Vec<&Tensor> = parts.to_vec();
    all.push(&zero);
    Tensor::cat(&all, 1)
}

/// `[B, t, hidden]`, row b's position p being `source[b, cols[b·t + p]]`: one gather on the device.
pub(crate) fn gather_positions(source: &Tensor, cols: &[i64], t: i64) -> Tensor {
    let (b, device) = (source.size()[0], source.device());
    let rows = Tensor::arange(b, (Kind::Int64, device)).view([b, 1]);
    let cols = Tensor::from_slice(cols).view([b, t]).to_device(device);
    source.index(&[Some(rows), Some(cols)])
}
