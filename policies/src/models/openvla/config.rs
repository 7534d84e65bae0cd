//! What an OpenVLA checkpoint directory says about itself: `config.json` (prismatic's
//! `OpenVLAConfig`: the timm ids of the vision backbone(s), the Llama `text_config`,
//! `pad_to_multiple_of`, `n_action_bins`, `norm_stats`), `preprocessor_config.json` (the per-backbone
//! image normalisation) and `dataset_statistics.json` (which, when present, replaces `norm_stats`, as
//! openvla's `experiments/robot/openvla_utils.py` does).

use super::{OpenVlaError, bad};
use crate::postprocess::NormStats;
use serde_json::Value;
use std::path::Path;

/// The Llama language model (`text_config`).
#[derive(Debug, Clone, PartialEq)]
pub struct LlamaConfig {
    pub vocab_size: i64,
    pub hidden_size: i64,
    pub intermediate_size: i64,
    pub num_hidden_layers: usize,
    pub num_attention_heads: i64,
    pub num_key_value_heads: i64,
    pub rms_norm_eps: f64,
    pub rope_theta: f64,
    pub tie_word_embeddings: bool,
}

/// One timm ViT featurizer; the widths and the depth come from the weights.
#[derive(Debug, Clone, PartialEq)]
pub struct BackboneConfig {
    pub timm_id: String,
    pub num_heads: i64,
    /// `quick_gelu` (CLIP) instead of the exact GELU.
    pub quick_gelu: bool,
    /// `tvf_normalize_params` (else `means`/`stds`) of `preprocessor_config.json`.
    pub mean: [f64; 3],
    pub std: [f64; 3],
    pub image_size: i64,
}

#[derive(Debug, Clone)]
pub struct OpenVlaConfig {
    pub backbones: Vec<BackboneConfig>,
    pub text: LlamaConfig,
    /// The Llama vocabulary before OpenVLA's padding (`text_config.vocab_size - pad_to_multiple_of`,
    /// 32000 for Llama-2): action bin `i` is token `vocab_size - 1 - i`.
    pub action_vocab_size: i64,
    pub n_action_bins: usize,
    pub norm_stats: NormStats,
}

/// Attention heads of the timm models prismatic uses (the weights do not say).
fn timm_heads(timm_id: &str) -> Option<i64> {
    let base = timm_id.split('.').next().unwrap_or(timm_id);
    match base {
        "vit_large_patch14_reg4_dinov2" | "vit_large_patch14_dinov2" => Some(16),
        "vit_so400m_patch14_siglip_224" | "vit_so400m_patch14_siglip_384" => Some(16),
        "vit_large_patch14_clip_224" | "vit_large_patch14_clip_336" | "vit_large_patch16_224" => Some(16),
        _ => None,
    }
}

fn read_json(path: &Path) -> Result<Value, OpenVlaError> {
    let text = std::fs::read_to_string(path).map_err(|e| bad(format!("{}: {e}", path.display())))?;
    serde_json::from_str(&text).map_err(|e| bad(format!("{}: not JSON: {e}", path.display())))
}

fn f64s(v: &Value, what: &str) -> Result<[f64; 3], OpenVlaError> {
    let arr = v.as_array().filter(|a| a.len() == 3).ok_or_else(|| bad(format!("{what}: expected 3 numbers")))?;
    let mut out = [0.0; 3];
    for (o, x) in out.iter_mut().zip(arr) {
        *o = x.as_f64().ok_or_else(|| bad(format!("{what}: expected numbers")))?;
    }
    Ok(out)
}

impl OpenVlaConfig {
    pub fn load(dir: &Path) -> Result<Self, OpenVlaError> {
        let cfg = read_json(&dir.join("config.json"))?;
        let src = dir.join("config.json").display().to_string();
        let field = |k: &str| cfg.get(k).ok_or_else(|| bad(format!("{src}: {k} is missing")));
        let text = field("text_config")?;
        // Missing fields take transformers' LlamaConfig defaults (the released config.json writes only
        // what differs from them).
        let t_int = |k: &str, default: i64| -> Result<i64, OpenVlaError> {
            match text.get(k) {
                None | Some(Value::Null) => Ok(default),
                Some(v) => v.as_i64().ok_or_else(|| bad(format!("{src}: text_config.{k} is not an integer"))),
            }
        };
        let t_f64 = |k: &str, default: f64| text.get(k).and_then(Value::as_f64).unwrap_or(default);
        let heads = t_int("num_attention_heads", 32)?;
        let text = LlamaConfig {
            vocab_size: t_int("vocab_size", 32000)?,
            hidden_size: t_int("hidden_size", 4096)?,
            intermediate_size: t_int("intermediate_size", 11008)?,
            num_hidden_layers: t_int("num_hidden_layers", 32)? as usize,
            num_attention_heads: heads,
            num_key_value_heads: t_int("num_key_value_heads", heads)?,
            rms_norm_eps: t_f64("rms_norm_eps", 1e-6),
            rope_theta: t_f64("rope_theta", 10000.0),
            tie_word_embeddings: text.get("tie_word_embeddings").and_then(Value::as_bool).unwrap_or(false),
        };
        let tc = &cfg["text_config"];
        if tc.get("hidden_act").and_then(Value::as_str).is_some_and(|a| a != "silu")
            || tc.get("attention_bias").and_then(Value::as_bool) == Some(true)
        {
            return Err(bad(format!("{src}: text_config: only Llama's silu MLP without attention biases is ported")));
        }
        if let Some(kind) = cfg["text_config"].get("model_type").and_then(Value::as_str)
            && kind != "llama"
        {
            return Err(bad(format!("{src}: text_config.model_type {kind:?}: only Llama language models are ported")));
        }
        if cfg["text_config"].get("rope_scaling").is_some_and(|v| !v.is_null()) {
            return Err(bad(format!("{src}: text_config.rope_scaling is not supported")));
        }
        let pad = cfg.get("pad_to_multiple_of").and_then(Value::as_i64).unwrap_or(64);
        let n_action_bins = cfg.get("n_action_bins").and_then(Value::as_u64).unwrap_or(256) as usize;
        let ids: Vec<String> = field("timm_model_ids")?
            .as_array()
            .ok_or_else(|| bad(format!("{src}: timm_model_ids is not a list")))?
            .iter()
            .map(|v| v.as_str().map(str::to_string).ok_or_else(|| bad(format!("{src}: timm_model_ids: not strings"))))
            .collect::<Result<_, _>>()?;
        let fused = cfg.get("use_fused_vision_backbone").and_then(Value::as_bool).unwrap_or(ids.len() == 2);
        if ids.is_empty() || ids.len() > 2 || fused != (ids.len() == 2) {
            return Err(bad(format!("{src}: expected one timm model id, or two with use_fused_vision_backbone")));
        }
        let pre_path = dir.join("preprocessor_config.json");
        let pre = if pre_path.exists() { Some(read_json(&pre_path)?) } else { None };
        let mut backbones = Vec::new();
        for (i, id) in ids.iter().enumerate() {
            // `timm_model_kwargs` is not an OpenVLA field: the tiny test model's overrides of the timm defaults.
            let num_heads = cfg
                .get("timm_model_kwargs")
                .and_then(|k| k.get(i))
                .and_then(|k| k.get("num_heads"))
                .and_then(Value::as_i64)
                .or_else(|| timm_heads(id))
                .ok_or_else(|| bad(format!("{src}: unknown timm model {id:?} (its number of heads is not known)")))?;
            let act = cfg.get("timm_override_act_layers").and_then(|a| a.get(i)).and_then(Value::as_str);
            let quick_gelu = match act {
                None => false,
                Some("quick_gelu") => true,
                Some(other) => return Err(bad(format!("{src}: timm_override_act_layers {other:?} is not supported"))),
            };
            let image_size = cfg.get("image_sizes").and_then(|a| a.get(i)).and_then(Value::as_i64).unwrap_or(224);
            let (mut mean, mut std) = if id.contains("siglip") {
                ([0.5; 3], [0.5; 3])
            } else if id.contains("clip") {
                ([0.48145466, 0.4578275, 0.40821073], [0.26862954, 0.26130258, 0.27577711])
            } else {
                ([0.485, 0.456, 0.406], [0.229, 0.224, 0.225])
            };
            if let Some(pre) = &pre {
                let what = pre_path.display().to_string();
                if let Some(p) = pre.get("tvf_normalize_params").and_then(|a| a.get(i)) {
                    mean = f64s(&p["mean"], &format!("{what}: tvf_normalize_params[{i}].mean"))?;
                    std = f64s(&p["std"], &format!("{what}: tvf_normalize_params[{i}].std"))?;
                } else if let (Some(m), Some(s)) =
                    (pre.get("means").and_then(|a| a.get(i)), pre.get("stds").and_then(|a| a.get(i)))
                {
                    mean = f64s(m, &format!("{what}: means[{i}]"))?;
                    std = f64s(s, &format!("{what}: stds[{i}]"))?;
                }
                // a bool, or one per backbone in fused processors
                let letterbox = match pre.get("tvf_do_letterbox") {
                    Some(Value::Array(per_backbone)) => per_backbone.get(i).and_then(Value::as_bool),
                    Some(v) => v.as_bool(),
                    None => None,
                };
                if letterbox == Some(true) {
                    return Err(bad(format!("{what}: letterbox preprocessing is not supported")));
                }
            }
            backbones.push(BackboneConfig { timm_id: id.clone(), num_heads, quick_gelu, mean, std, image_size });
        }
        let stats_path = dir.join("dataset_statistics.json");
        let norm_stats = if stats_path.exists() {
            let text =
                std::fs::read_to_string(&stats_path).map_err(|e| bad(format!("{}: {e}", stats_path.display())))?;
            NormStats::from_json(&text).map_err(|e| bad(format!("{}: {e}", stats_path.display())))?
        } else {
            NormStats::from_value(field("norm_stats")?).map_err(|e| bad(format!("{src}: norm_stats: {e}")))?
        };
        Ok(OpenVlaConfig { backbones, action_vocab_size: text.vocab_size - pad, text, n_action_bins, norm_stats })
    }
}
