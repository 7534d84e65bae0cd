//! No silent CPU fallback: a model that would run on the CPU without the policy string asking
//! for it (`devices=cpu`) is refused when it is loaded, which is before any episode (a run
//! resolves its policy's identity, and checks its camera size, before the first episode).
//!
//! Why: libtorch falls back to the CPU without a word where its CUDA backend is missing, and the
//! released checkpoints are 7.5 B parameters: in fp32 on a CPU that is ~30 GB of memory and tens
//! of seconds per policy step (OpenVLA-7B on an H200 machine's CPU: 2 policy steps in 26 s, 33 GB
//! peak). A run that looks like it is working but would take weeks is worse than one that stops
//! and says why. Two cases:
//! - **A GPU machine** (an NVIDIA driver, [`crate::cuda_backend::nvidia_driver`]) where the model
//!   would land on the CPU, because libtorch's CUDA backend did not load or sees no device: refused
//!   whatever the model's size, with the loader's outcome and the fix.
//! - **A large model** ([`LARGE_PARAMS`] or more) on a machine without a GPU: refused with what it
//!   would cost. The tests' tiny random-weight checkpoints (thousands of parameters) run on the
//!   CPU with no option.
//!
//! `devices=cpu` runs it on the CPU in either case; a large model then prints its cost on stderr.
//! The size comes from the checkpoint's files without loading any weight ([`ModelSize`]).

use crate::cuda_backend::{self, CudaBackend, FIX};
use serde_json::Value;
use std::io::Read;
use std::path::{Path, PathBuf};

/// Parameters from which a model counts as large on a CPU: 4 GB of fp32 weights, and seconds per
/// policy step. The tests' checkpoints are far below, OpenVLA-7B (7.5 B) far above.
pub const LARGE_PARAMS: u64 = 1_000_000_000;
/// fp32, what a model computes in on a CPU (`models::device_and_dtype`).
const CPU_BYTES_PER_PARAM: u64 = 4;
/// Seconds per policy step per billion parameters on a CPU, the order of magnitude of OpenVLA-7B's
/// measurement (26 s for 2 steps of 7.5 B, the load included): only for the size of the warning.
const CPU_SECONDS_PER_BILLION: f64 = 3.5;

/// A model's parameter count as its files say, without loading them.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSize {
    /// The policy kind as the spec names it (`openvla`, `oft`, `torchscript`).
    pub kind: &'static str,
    /// The checkpoint directory or module file.
    pub path: PathBuf,
    /// `None` where the files do not say (the load then fails on them, naming what is missing).
    pub params: Option<u64>,
    /// How `params` was estimated, or why it could not be.
    pub how: String,
}

impl ModelSize {
    /// An OpenVLA-family checkpoint directory: the parameter counts in its safetensors shards'
    /// headers (exact; a few kB read per shard); where shards are missing,
    /// `model.safetensors.index.json`'s `total_size` at 2 bytes a parameter (bf16, the released
    /// checkpoints' dtype). OFT's `.pt` heads (~1 % of the model) are not counted.
    pub fn of_checkpoint(kind: &'static str, dir: &Path) -> ModelSize {
        let (params, how) = checkpoint_params(dir).map_or_else(|why| (None, why), |(n, how)| (Some(n), how));
        ModelSize { kind, path: dir.to_path_buf(), params, how }
    }

    /// A TorchScript module: its file's size at 4 bytes a parameter (fp32; a module saved in bf16
    /// holds twice as many, which only makes the estimate of its CPU memory right).
    pub fn of_torchscript(file: &Path) -> ModelSize {
        let (params, how) = match std::fs::metadata(file) {
            Ok(m) => (Some(m.len() / 4), format!("the file's {} bytes at 4 bytes a parameter (fp32)", m.len())),
            Err(e) => (None, format!("{}: {e}", file.display())),
        };
        ModelSize { kind: "torchscript", path: file.to_path_buf(), params, how }
    }

    pub fn is_large(&self) -> bool {
        self.params.is_some_and(|n| n >= LARGE_PARAMS)
    }

    /// `~7.5 B parameters (the safetensors headers of 3 shards)`.
    pub fn describe(&self) -> String {
        match self.params {
            Some(n) if n >= 100_000_000 => format!("~{:.1} B parameters ({})", n as f64 / 1e9, self.how),
            Some(n) => format!("{n} parameters ({})", self.how),
            None => format!("an unknown number of parameters ({})", self.how),
        }
    }

    /// What running it on a CPU costs.
    pub fn cpu_cost(&self) -> String {
        let n = self.params.unwrap_or(0);
        format!(
            "~{:.0} GB of memory (fp32, {CPU_BYTES_PER_PARAM} bytes a parameter) and on the order of {:.0} s per policy \
             step (OpenVLA-7B on an H200 machine's CPU: 2 policy steps in 26 s, 33 GB peak)",
            (n * CPU_BYTES_PER_PARAM) as f64 / 1e9,
            n as f64 / 1e9 * CPU_SECONDS_PER_BILLION
        )
    }

    /// The policy string that runs it on the CPU on purpose.
    fn on_cpu_example(&self) -> String {
        format!("{}:{}?devices=cpu", self.kind, self.path.display())
    }
}

/// What decides where a model may run: this machine's GPU, and libtorch's view of it.
#[derive(Debug, Clone, Copy)]
pub struct Machine<'a> {
    /// The NVIDIA driver's version, where the machine has one.
    pub driver: Option<&'a str>,
    pub backend: &'a CudaBackend,
    /// The CUDA devices libtorch sees.
    pub cuda_devices: usize,
}

impl Machine<'static> {
    /// This process's machine (loads the CUDA backend if nothing did yet).
    pub fn this() -> Self {
        let backend = cuda_backend::load();
        Machine { driver: cuda_backend::nvidia_driver(), backend, cuda_devices: cuda_backend::torch_cuda_devices() }
    }
}

/// Whether `model` may run on the CPU: `explicit` when the policy string says `devices=cpu`.
/// `Ok(Some(note))`: it may, and the note (its cost) goes to stderr; `Err`: refused, with the
/// cause and the fix.
pub fn check_cpu(model: &ModelSize, explicit: bool, machine: &Machine) -> Result<Option<String>, String> {
    let name = format!("{}:{}", model.kind, model.path.display());
    if explicit {
        return Ok(model.is_large().then(|| {
            format!("{name} runs on the CPU as devices=cpu asks: {}, {}", model.describe(), model.cpu_cost())
        }));
    }
    if let Some(driver) = machine.driver {
        let why = match machine.backend.is_loaded() {
            false => format!("libtorch's CUDA backend is {}", machine.backend.describe()),
            true => format!(
                "libtorch's CUDA backend is {}, but it sees no CUDA device (CUDA_VISIBLE_DEVICES={}; a driver older than \
                 CUDA 13 needs sees none either)",
                machine.backend.describe(),
                std::env::var("CUDA_VISIBLE_DEVICES").map_or_else(|_| "unset".into(), |v| format!("{v:?}"))
            ),
        };
        return Err(format!(
            "{name} would run on the CPU although this machine has an NVIDIA GPU (driver {driver}): {why}. Fix: {FIX}. \
             `pipeline doctor` shows what a run would use. To run it on the CPU on purpose: {}",
            model.on_cpu_example()
        ));
    }
    if model.is_large() {
        return Err(format!(
            "{name} has {}, and this machine has no NVIDIA GPU (libtorch's CUDA backend: {}): on the CPU it would take {}. \
             Run it on a GPU machine (after ./setup.sh there), or on the CPU on purpose: {}",
            model.describe(),
            machine.backend.describe(),
            model.cpu_cost(),
            model.on_cpu_example()
        ));
    }
    Ok(None)
}

/// The checkpoint's parameter count and how it was read.
fn checkpoint_params(dir: &Path) -> Result<(u64, String), String> {
    let index_path = dir.join("model.safetensors.index.json");
    if index_path.is_file() {
        let text = std::fs::read_to_string(&index_path).map_err(|e| format!("{}: {e}", index_path.display()))?;
        let index: Value =
            serde_json::from_str(&text).map_err(|e| format!("{}: not JSON: {e}", index_path.display()))?;
        let mut shards: Vec<PathBuf> = index["weight_map"]
            .as_object()
            .map(|m| m.values().filter_map(Value::as_str).map(|f| dir.join(f)).collect())
            .unwrap_or_default();
        shards.sort();
        shards.dedup();
        if !shards.is_empty() && shards.iter().all(|s| s.is_file()) {
            let n = shards.iter().map(|s| safetensors_params(s)).sum::<Result<u64, String>>()?;
            return Ok((n, format!("the safetensors headers of {} shard(s)", shards.len())));
        }
        if let Some(total) = index["metadata"]["total_size"].as_u64() {
            return Ok((
                total / 2,
                format!(
                    "model.safetensors.index.json's total_size, {total} bytes at 2 bytes a parameter (bf16, the released \
                     checkpoints' dtype), as its shards are not all there"
                ),
            ));
        }
        return Err(format!("{}: no shard files and no metadata.total_size", index_path.display()));
    }
    let single = dir.join("model.safetensors");
    if single.is_file() {
        return Ok((safetensors_params(&single)?, "the safetensors header of model.safetensors".into()));
    }
    Err(format!("no model.safetensors.index.json or model.safetensors in {}", dir.display()))
}

/// The parameters a safetensors file holds, from its header alone (8 bytes of length, then JSON
/// `{name: {dtype, shape, data_offsets}}`).
fn safetensors_params(path: &Path) -> Result<u64, String> {
    let bad = |why: String| format!("{}: {why}", path.display());
    let mut file = std::fs::File::open(path).map_err(|e| bad(e.to_string()))?;
    let mut len = [0u8; 8];
    file.read_exact(&mut len).map_err(|e| bad(format!("no safetensors header: {e}")))?;
    let len = u64::from_le_bytes(len);
    if len > 100_000_000 {
        return Err(bad(format!("a safetensors header of {len} bytes: not a safetensors file")));
    }
    let mut header = vec![0u8; len as usize];
    file.read_exact(&mut header).map_err(|e| bad(format!("the safetensors header is cut short: {e}")))?;
    let header: Value = serde_json::from_slice(&header).map_err(|e| bad(format!("safetensors header: {e}")))?;
    let tensors = header.as_object().ok_or_else(|| bad("the safetensors header is not an object".into()))?;
    Ok(tensors
        .iter()
        .filter(|(name, _)| name.as_str() != "__metadata__")
        .map(|(_, t)| t["shape"].as_array().map_or(0, |s| s.iter().filter_map(Value::as_u64).product::<u64>()))
        .sum())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cuda_backend::{Candidate, Source};

    fn temp_dir(name: &str) -> PathBuf {
        crate::cuda_backend::tests::temp_dir_of("cpu-fallback", name)
    }

    /// A safetensors file of the given tensor shapes (f32, zero bytes).
    fn write_safetensors(path: &Path, shapes: &[(&str, &[u64])]) {
        let mut header = serde_json::Map::new();
        let mut offset = 0u64;
        for (name, shape) in shapes {
            let bytes = 4 * shape.iter().product::<u64>();
            header.insert(
                name.to_string(),
                serde_json::json!({"dtype": "F32", "shape": shape, "data_offsets": [offset, offset + bytes]}),
            );
            offset += bytes;
        }
        header.insert("__metadata__".into(), serde_json::json!({"format": "pt"}));
        let header = serde_json::to_vec(&Value::Object(header)).unwrap();
        let mut out = (header.len() as u64).to_le_bytes().to_vec();
        out.extend_from_slice(&header);
        out.resize(out.len() + offset as usize, 0);
        std::fs::write(path, out).unwrap();
    }

    /// What the released OpenVLA-7B's index says (its bf16 shards' total size), without shards.
    fn seven_b_checkpoint() -> PathBuf {
        let dir = temp_dir("openvla-7b");
        let index = serde_json::json!({
            "metadata": {"total_size": 15_082_852_992u64},
            "weight_map": {"language_model.lm_head.weight": "model-00003-of-00003.safetensors",
                           "vision_backbone.featurizer.cls_token": "model-00001-of-00003.safetensors"},
        });
        std::fs::write(dir.join("model.safetensors.index.json"), index.to_string()).unwrap();
        dir
    }

    fn not_found() -> CudaBackend {
        CudaBackend::NotFound {
            looked: vec![Candidate { source: Source::Checkout, dir: "/repo/third_party/libtorch-cuda".into() }],
        }
    }

    #[test]
    fn a_7b_checkpoint_without_cuda_is_refused_on_the_cpu_unless_devices_cpu() {
        let size = ModelSize::of_checkpoint("openvla", &seven_b_checkpoint());
        assert_eq!(size.params, Some(7_541_426_496));
        assert!(size.is_large() && size.how.contains("total_size"), "{size:?}");
        let backend = not_found();
        let cpu_machine = Machine { driver: None, backend: &backend, cuda_devices: 0 };
        let e = check_cpu(&size, false, &cpu_machine).unwrap_err();
        for says in ["~7.5 B parameters", "~30 GB of memory", "s per policy step", "no NVIDIA GPU", "?devices=cpu"] {
            assert!(e.contains(says), "{says:?} not in: {e}");
        }
        assert!(e.contains("not loaded: no libtorch_cuda.so in /repo/third_party/libtorch-cuda"), "{e}");
        // asked for: it runs, and the cost is printed
        let note = check_cpu(&size, true, &cpu_machine).unwrap().expect("a cost note");
        assert!(note.contains("~30 GB") && note.contains("devices=cpu"), "{note}");
    }

    #[test]
    fn a_tiny_checkpoint_runs_on_a_cuda_less_cpu_machine_but_not_beside_an_unused_gpu() {
        let dir = temp_dir("tiny");
        write_safetensors(&dir.join("model-00001-of-00002.safetensors"), &[("a", &[64, 48]), ("b", &[48])]);
        write_safetensors(&dir.join("model-00002-of-00002.safetensors"), &[("c", &[32064, 64])]);
        let index = serde_json::json!({"metadata": {"total_size": 1}, "weight_map": {
            "a": "model-00001-of-00002.safetensors", "b": "model-00001-of-00002.safetensors",
            "c": "model-00002-of-00002.safetensors"}});
        std::fs::write(dir.join("model.safetensors.index.json"), index.to_string()).unwrap();
        let size = ModelSize::of_checkpoint("oft", &dir);
        assert_eq!(size.params, Some(64 * 48 + 48 + 32064 * 64), "{size:?}");
        assert!(size.how.contains("headers of 2 shard(s)"), "{}", size.how);
        let backend = not_found();
        assert_eq!(check_cpu(&size, false, &Machine { driver: None, backend: &backend, cuda_devices: 0 }), Ok(None));
        assert_eq!(check_cpu(&size, true, &Machine { driver: None, backend: &backend, cuda_devices: 0 }), Ok(None));
        // a GPU machine without the CUDA backend: refused whatever the size, with the cause and the fix
        let gpu = Machine { driver: Some("570.86.15"), backend: &backend, cuda_devices: 0 };
        let e = check_cpu(&size, false, &gpu).unwrap_err();
        for says in
            ["NVIDIA GPU (driver 570.86.15)", "not loaded: no libtorch_cuda.so", "./setup.sh", "LIBERO_TORCH_CUDA_LIB"]
        {
            assert!(e.contains(says), "{says:?} not in: {e}");
        }
        assert!(e.contains(&format!("oft:{}?devices=cpu", dir.display())), "{e}");
        assert_eq!(check_cpu(&size, true, &gpu), Ok(None), "devices=cpu is a choice");
        // the backend loaded but no device visible: the same refusal, saying so
        let loaded = CudaBackend::Loaded { path: "/t/lib/libtorch_cuda.so".into(), source: Source::Override };
        let e = check_cpu(&size, false, &Machine { driver: Some("570.86.15"), backend: &loaded, cuda_devices: 0 })
            .unwrap_err();
        assert!(e.contains("sees no CUDA device") && e.contains("/t/lib/libtorch_cuda.so"), "{e}");
    }

    #[test]
    fn cuda_less_size_of_a_torchscript_file_is_its_bytes_in_fp32() {
        let dir = temp_dir("torchscript");
        let file = dir.join("model.pt");
        std::fs::write(&file, vec![0u8; 4000]).unwrap();
        let size = ModelSize::of_torchscript(&file);
        assert_eq!((size.params, size.is_large()), (Some(1000), false));
        let missing = ModelSize::of_torchscript(&dir.join("none.pt"));
        assert_eq!(missing.params, None);
        let unknown = ModelSize::of_checkpoint("openvla", &dir);
        assert!(unknown.params.is_none() && unknown.how.contains("no model.safetensors"), "{unknown:?}");
        assert!(!unknown.is_large());
    }
}
