//! The checkpoint's tensors: every `*.safetensors` shard named by `model.safetensors.index.json`
//! (or a single `model.safetensors`), read into host memory, each moved to the model's device and
//! dtype when the model takes it, and linear weights quantised there as they are taken
//! ([`Weights::take_linear`]): the device never holds more than the model plus one layer's
//! weight in f32, so a quantised 7B model loads on a card that its bf16 weights would not fit.

use super::{OpenVlaError, bad};
use crate::models::quant::Linear;
use crate::placement::Quantization;
use std::collections::{BTreeSet, HashMap};
use std::path::Path;
use tch::{Device, Kind, Tensor};

pub struct Weights {
    tensors: HashMap<String, Tensor>,
    device: Device,
    kind: Kind,
    quant: Quantization,
}

impl Weights {
    pub fn load(dir: &Path, device: Device, kind: Kind, quant: Quantization) -> Result<Self, OpenVlaError> {
        let index = dir.join("model.safetensors.index.json");
        let files: BTreeSet<String> = if index.exists() {
            let text = std::fs::read_to_string(&index).map_err(|e| bad(format!("{}: {e}", index.display())))?;
            let v: serde_json::Value =
                serde_json::from_str(&text).map_err(|e| bad(format!("{}: not JSON: {e}", index.display())))?;
            v["weight_map"]
                .as_object()
                .ok_or_else(|| bad(format!("{}: no weight_map", index.display())))?
                .values()
                .filter_map(|f| f.as_str().map(str::to_string))
                .collect()
        } else if dir.join("model.safetensors").exists() {
            BTreeSet::from(["model.safetensors".to_string()])
        } else {
            return Err(bad(format!("{}: no model.safetensors.index.json or model.safetensors", dir.display())));
        };
        let mut tensors = HashMap::new();
        for f in files {
            let path = dir.join(&f);
            let named = Tensor::read_safetensors(&path).map_err(|e| bad(format!("{}: {e}", path.display())))?;
            tensors.extend(named);
        }
        Ok(Weights { tensors, device, kind, quant })
    }

    /// The tensor on the model's device, in its dtype.
    pub fn take(&mut self, name: &str) -> Result<Tensor, OpenVlaError> {
        self.take_opt(name).ok_or_else(|| bad(format!("the checkpoint has no tensor {name:?}")))
    }

    pub fn take_opt(&mut self, name: &str) -> Option<Tensor> {
        // moved first, converted there: a GPU converts bf16 checkpoints far faster than the host
        self.tensors.remove(name).map(|t| t.to_device(self.device).to_kind(self.kind))
    }

    pub fn has(&self, name: &str) -> bool {
        self.tensors.contains_key(name)
    }

    /// A linear layer's weight `[out, in]`, quantised as the model is loaded.
    pub fn take_linear(&mut self, name: &str) -> Result<Linear, OpenVlaError> {
        Ok(Linear::new(self.take(name)?, self.quant))
    }

    /// Linear weights that read the same input, stacked by output (`[Σ out, in]`) into one layer.
    /// Each is quantised alone, then stacked (levels are per output channel or per group of a
    /// row's inputs, so they are the same either way): a quantisation's f32 temporaries stay
    /// those of one layer, which sets a small card's peak memory at load.
    pub fn take_linear_stacked(&mut self, names: &[&str]) -> Result<Linear, OpenVlaError> {
        let parts = names.iter().map(|n| self.take_linear(n)).collect::<Result<Vec<_>, _>>()?;
        Linear::stack(parts).map_err(bad)
    }

    /// How many `{prefix}{i}.` groups there are (blocks, layers), counting from 0.
    pub fn count_indexed(&self, prefix: &str) -> usize {
        let mut n = 0;
        while self.tensors.keys().any(|k| k.starts_with(&format!("{prefix}{n}."))) {
            n += 1;
        }
        n
    }
}
