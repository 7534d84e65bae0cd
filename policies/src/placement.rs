//! Where an in-process model runs and how its weights are stored: the `devices=` and `quant=`
//! options of a model policy (`openvla:<dir>?batch=32&devices=cuda:0,cuda:1&quant=int8`).
//!
//! These are names only (no libtorch here), so that a policy string parses and prints the same
//! in a build without the `torch` feature; `models` turns them into tch devices and quantised
//! layers.
//!
//! - **Devices.** One model replica per listed device, each behind its own batcher; an episode is
//!   served by one replica from its start to its end, the replica with the least (episodes in
//!   progress + 1) × recent forward ms when it starts (`batching::Replicas`). A device may be
//!   listed twice (two replicas on one GPU, when one replica's host work leaves the GPU idle).
//! - **Quantisation.** Weight-only, of the linear layers (`models::quant`): int8 per output
//!   channel, int4 in groups of (up to) 128 along the input; activations stay in the model's dtype. For
//!   8–16 GB cards: OpenVLA-7B's weights take ~15 GB in bf16.

use std::fmt;
use std::str::FromStr;

/// A device a model replica runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ModelDevice {
    Cpu,
    /// A CUDA device by its index (as `CUDA_VISIBLE_DEVICES` numbers them).
    Cuda(usize),
}

impl fmt::Display for ModelDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ModelDevice::Cpu => f.write_str("cpu"),
            ModelDevice::Cuda(i) => write!(f, "cuda:{i}"),
        }
    }
}

impl FromStr for ModelDevice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "cpu" => Ok(ModelDevice::Cpu),
            "cuda" => Ok(ModelDevice::Cuda(0)),
            _ => match s.strip_prefix("cuda:").map(str::parse::<usize>) {
                Some(Ok(i)) => Ok(ModelDevice::Cuda(i)),
                _ => Err(format!("{s:?} is not a device: cpu, cuda or cuda:N")),
            },
        }
    }
}

/// A comma-separated device list (`cuda:0,cuda:1`), at least one.
pub fn parse_devices(s: &str) -> Result<Vec<ModelDevice>, String> {
    let devices = s.split(',').map(str::parse).collect::<Result<Vec<ModelDevice>, _>>()?;
    if devices.is_empty() {
        return Err("no device listed".into());
    }
    Ok(devices)
}

/// `cuda:0,cuda:1`.
pub fn devices_text(devices: &[ModelDevice]) -> String {
    devices.iter().map(ModelDevice::to_string).collect::<Vec<_>>().join(",")
}

/// Which of transformers' attention implementations an OpenVLA-family forward reproduces
/// (`&attention=eager|sdpa`). In fp32 on a CPU they agree to ~1e-6; in bf16 on a GPU each is the
/// arithmetic of its own kernels, and SDPA's fused kernels (flash or memory-efficient attention)
/// also cost far less time and memory on long sequences.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Attention {
    /// `softmax(q kᵀ / √d + mask) v` in separate kernels, the softmax in f32 (`attn_implementation="eager"`).
    Eager,
    /// `torch.nn.functional.scaled_dot_product_attention` with the same additive mask, or none
    /// (`attn_implementation="sdpa"`): the flash kernel where no mask is needed (one episode per
    /// forward), the memory-efficient one with a padding mask.
    Sdpa,
}

impl Attention {
    /// A model's attention when the spec names none.
    /// - OpenVLA on a GPU: SDPA. The published LIBERO loop loads OpenVLA with
    ///   `attn_implementation="flash_attention_2"` (openvla's `experiments/robot/openvla_utils.py`,
    ///   `get_vla`); SDPA is libtorch's flash attention where no mask is needed, and 72.1 ms a B = 1
    ///   call on an H100 against eager's 83.8 (`data/benchmarks/gpu-forward-recheck-h100-2026-11-27`).
    /// - OpenVLA on a CPU: eager, the arithmetic of the Python reference the parity tests compare
    ///   with (SDPA agrees with it to ~1e-6 in fp32).
    /// - OpenVLA-OFT: SDPA everywhere, what openvla-oft's `get_vla` loads.
    pub fn model_default(oft: bool, on_gpu: bool) -> Attention {
        if oft || on_gpu { Attention::Sdpa } else { Attention::Eager }
    }

    /// What the run manifest records.
    pub fn describe(&self) -> &'static str {
        match self {
            Attention::Eager => {
                "eager: softmax(q k^T / sqrt(d) + mask) v in separate kernels, softmax in f32 (transformers' eager)"
            }
            Attention::Sdpa => {
                "sdpa: torch's scaled_dot_product_attention (flash attention without a mask, memory-efficient with a padding mask)"
            }
        }
    }
}

impl fmt::Display for Attention {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Attention::Eager => "eager",
            Attention::Sdpa => "sdpa",
        })
    }
}

impl FromStr for Attention {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "eager" => Ok(Attention::Eager),
            "sdpa" => Ok(Attention::Sdpa),
            other => Err(format!("unknown attention {other:?}: eager or sdpa")),
        }
    }
}

/// The environment that keeps libtorch's cuDNN attention behind flash and memory-efficient
/// attention for [`Attention::Sdpa`]. torch 2.11 on an H100 (sm90, cuDNN ≥ 9.9) puts cuDNN's
/// attention first unless told otherwise; torch reads `TORCH_CUDNN_SDPA_PREFERRED` in some
/// releases and `TORCH_CUDNN_SDPA_DEPRIORITIZED` in later ones, once per process at the first
/// attention call, so both are set.
///
/// Why: cuDNN's attention builds an execution graph for each problem shape (batch, query and key
/// lengths) and caches it per thread (`aten/src/ATen/native/cudnn/MHA.cpp`). A run's forwards
/// change all three all the time (how many episodes wait, the longest instruction, and every
/// decode step's key length), so it keeps building graphs on the host. A benchmark of fixed shapes
/// hits the cache and does not see this. Real episodes on one H100, 32 workers, 30 episodes each,
/// back to back (`data/benchmarks/gpu-sdpa-cudnn-h100-2026-11-27`): SDPA with cuDNN first 36.4
/// policy steps/s (389 ms per forward), eager 48.6 (239 ms), SDPA with cuDNN last **63.5**
/// (165 ms).
///
/// It is also the arithmetic closer to the published numbers': torch prefers cuDNN's attention
/// only on sm90/sm100 (H100, B200), so on an A100 the same SDPA call runs flash attention, and
/// OpenVLA's LIBERO loop loads the model with the flash-attn package's kernels.
pub const CUDNN_ATTENTION_LAST: [(&str, &str); 2] =
    [("TORCH_CUDNN_SDPA_PREFERRED", "0"), ("TORCH_CUDNN_SDPA_DEPRIORITIZED", "1")];

/// What [`keep_cudnn_attention_last`] sets, given the environment's `var`: nothing where either
/// variable is already set (the user's choice stands, e.g. `TORCH_CUDNN_SDPA_PREFERRED=1` to
/// measure cuDNN's attention), else [`CUDNN_ATTENTION_LAST`].
pub fn cudnn_attention_settings(
    var: impl Fn(&str) -> Option<std::ffi::OsString>,
) -> &'static [(&'static str, &'static str)] {
    if CUDNN_ATTENTION_LAST.iter().any(|(name, _)| var(name).is_some()) { &[] } else { &CUDNN_ATTENTION_LAST }
}

/// The two variables' values as `var` reads them (`null` where unset), for a run's policy
/// identity: whether cuDNN's attention or flash and memory-efficient attention computed a GPU
/// run's SDPA, so that a resume under other settings is refused rather than mixing the two.
pub fn cudnn_attention_environment(var: impl Fn(&str) -> Option<std::ffi::OsString>) -> serde_json::Value {
    CUDNN_ATTENTION_LAST
        .iter()
        .map(|(name, _)| (name.to_string(), serde_json::json!(var(name).map(|v| v.to_string_lossy().into_owned()))))
        .collect::<serde_json::Map<_, _>>()
        .into()
}

/// Sets [`CUDNN_ATTENTION_LAST`] in this process's environment unless the user set either
/// variable. Call it first thing in `main`, before any thread exists (`std::env::set_var`'s
/// contract) and so before libtorch's first attention call reads it.
pub fn keep_cudnn_attention_last() {
    for (name, value) in cudnn_attention_settings(|name| std::env::var_os(name)) {
        // SAFETY: called at the start of `main`, while the process has one thread
        unsafe { std::env::set_var(name, value) };
    }
}

/// Weight-only quantisation of a model's linear layers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Quantization {
    /// The checkpoint's weights in the model's dtype (bf16 on a GPU).
    #[default]
    None,
    /// int8 per output channel, symmetric: `w ≈ q · scale`, `scale = max|w_row| / 127`.
    Int8,
    /// int4 in groups of 128 inputs (64 or 32 where the input width needs), asymmetric:
    /// `w ≈ (q − 8) · scale + zero` (torch's tinygemm layout); a layer whose input width is not a
    /// multiple of 32 falls back to int8.
    Int4,
}

impl Quantization {
    /// What the run manifest records.
    pub fn describe(&self) -> &'static str {
        match self {
            Quantization::None => "none: the checkpoint's weights in the model's dtype",
            Quantization::Int8 => {
                "int8 weight-only: linear layers per output channel, symmetric (q = round(w / (max|w_row| / 127))), \
                 dequantised to the activations' dtype per call; embeddings, lm_head, norms and the patch embedding unquantised"
            }
            Quantization::Int4 => {
                "int4 weight-only: linear layers in groups of 128 inputs (64 or 32 where the width needs), asymmetric \
                 (w = (q - 8) scale + zero, tinygemm's layout), int8 where the input width is not a multiple of 32; torch's \
                 tinygemm kernel for up to 64 rows on CUDA, dequantised otherwise; embeddings, lm_head, norms and the \
                 patch embedding unquantised"
            }
        }
    }
}

impl fmt::Display for Quantization {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Quantization::None => "none",
            Quantization::Int8 => "int8",
            Quantization::Int4 => "int4",
        })
    }
}

impl FromStr for Quantization {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "none" => Ok(Quantization::None),
            "int8" => Ok(Quantization::Int8),
            "int4" => Ok(Quantization::Int4),
            _ => Err(format!("{s:?} is not a quantisation: int8 or int4 (or none)")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_and_quantisations_parse_and_print_back() {
        assert_eq!(parse_devices("cuda:0,cuda:1").unwrap(), [ModelDevice::Cuda(0), ModelDevice::Cuda(1)]);
        assert_eq!(parse_devices("cuda").unwrap(), [ModelDevice::Cuda(0)]);
        assert_eq!(devices_text(&parse_devices("cpu,cuda:3,cuda:3").unwrap()), "cpu,cuda:3,cuda:3");
        for bad in ["", "gpu", "cuda:", "cuda:x", "cuda:0,", "cuda:-1"] {
            assert!(parse_devices(bad).is_err(), "{bad:?}");
        }
        for q in [Quantization::None, Quantization::Int8, Quantization::Int4] {
            assert_eq!(q.to_string().parse::<Quantization>().unwrap(), q);
        }
        assert!("int2".parse::<Quantization>().unwrap_err().contains("int8 or int4"));
    }

    #[test]
    fn cudnn_attention_goes_last_unless_the_user_set_either_variable() {
        let unset = |_: &str| None;
        assert_eq!(cudnn_attention_settings(unset), &CUDNN_ATTENTION_LAST[..]);
        for (name, _) in CUDNN_ATTENTION_LAST {
            let user_set = |asked: &str| (asked == name).then(|| std::ffi::OsString::from("1"));
            assert!(cudnn_attention_settings(user_set).is_empty(), "{name} set by the user");
        }
        let ours = |asked: &str| {
            CUDNN_ATTENTION_LAST
                .iter()
                .find(|(name, _)| *name == asked)
                .map(|(_, value)| std::ffi::OsString::from(value))
        };
        assert_eq!(
            cudnn_attention_environment(ours),
            serde_json::json!({"TORCH_CUDNN_SDPA_PREFERRED": "0", "TORCH_CUDNN_SDPA_DEPRIORITIZED": "1"})
        );
        assert_eq!(
            cudnn_attention_environment(unset),
            serde_json::json!({"TORCH_CUDNN_SDPA_PREFERRED": null, "TORCH_CUDNN_SDPA_DEPRIORITIZED": null})
        );
    }
}
