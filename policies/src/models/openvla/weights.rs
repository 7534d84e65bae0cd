//! The checkpoint's tensors: every `*.safetensors` shard named by `model.safetensors.index.json`
//! (or a single `model.safetensors`), converted to the model's dtype and device on load.

use super::{OpenVlaError, bad};
use std::collections::{BTreeSet, HashMap};
use std::path::Path;
use tch::{Device, Kind, Tensor};

pub struct Weights {
    tensors: HashMap<String, Tensor>,
}

impl Weights {
    pub fn load(dir: &Path, device: Device, kind: Kind) -> Result<Self, OpenVlaError> {
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
            for (name, t) in named {
                tensors.insert(name, t.to_device(device).to_kind(kind));
            }
        }
        Ok(Weights { tensors })
    }

    pub fn take(&mut self, name: &str) -> Result<Tensor, OpenVlaError> {
        self.tensors.remove(name).ok_or_else(|| bad(format!("the checkpoint has no tensor {name:?}")))
    }

    pub fn take_opt(&mut self, name: &str) -> Option<Tensor> {
        self.tensors.remove(name)
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
