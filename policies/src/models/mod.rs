//! In-process model ports on libtorch (tch; the `torch` feature): the models whose forward this
//! crate computes itself, loaded from their released files with no Python at run time.
//!
//! - [`torchscript`]: any policy exported with `torch.jit.save` and a JSON manifest of its
//!   conventions (the route for a model we have not ported); [`torchscript_aloha`], the same for
//!   ALOHA-sim's 14-D joint actions (the manifest says `"benchmark": "aloha_sim"`).
//! - [`openvla`]: OpenVLA's Prismatic architecture from a Hugging Face checkpoint directory (vision
//!   towers, projector, Llama-2, token decoding), and [`openvla::oft`], OpenVLA-OFT on the same
//!   backbone (two images, proprio token, one bidirectional forward, L1 head's 8 × 7 chunk).
//! - [`torch_save`]: `torch.save` archives read without Python (OFT's head files).
//! - [`quant`]: weight-only int8/int4 linear layers (`?quant=`), for GPUs with less memory.
//! - [`cpu_fallback`]: where a model may not run on the CPU unasked ([`model_device`]).
//!
//! Each model is two layers: the model (load, forward, parity-tested against its Python reference
//! on a tiny random-weight checkpoint) and its [`crate::Policy`] (the published LIBERO loop's
//! conventions around it: cameras, preprocessing, chunking, gripper), which may serve several
//! rollout workers through one [`crate::batching::Batcher`]. What a new port needs from the rest of
//! the crate — image and state preprocessing, action post-processing, chunking, batching — lives
//! outside this module, shared with the remote clients.

pub mod cpu_fallback;
pub mod openvla;
pub mod quant;
pub mod torch_save;
pub mod torchscript;
pub mod torchscript_aloha;

use crate::cuda_backend;
use crate::placement::ModelDevice;
use cpu_fallback::{Machine, ModelSize};
use sha2::{Digest, Sha256};
use std::collections::BTreeSet;
use std::path::Path;
use tch::{Device, Kind};

/// The tch device of `device` (the first GPU when there is one, else the CPU, for `None`) and the
/// dtype a model computes in there: bf16 on a GPU (the released checkpoints' dtype), fp32 on a
/// CPU. A CUDA device this machine does not have is an error that says which it has and what
/// became of libtorch's CUDA backend; a CPU the policy did not ask for is checked by
/// [`cpu_fallback::check_cpu`] ([`model_device`]).
/// A tch device as the policy strings write it (`cpu`, `cuda:1`).
pub(crate) fn device_label(device: Device) -> String {
    match device {
        Device::Cuda(i) => format!("cuda:{i}"),
        other => format!("{other:?}").to_lowercase(),
    }
}

pub(crate) fn device_and_dtype(device: Option<ModelDevice>, model: &ModelSize) -> Result<(Device, Kind), String> {
    let device = model_device(device, model)?;
    Ok((device, if device.is_cuda() { Kind::BFloat16 } else { Kind::Float }))
}

/// Where `model` runs for the spec's `device` (`None`: the first GPU libtorch sees, else the
/// CPU): a listed CUDA device must exist, and a CPU placement must pass
/// [`cpu_fallback::check_cpu`] (refused on a GPU machine unless asked for, or for a large model
/// on any machine unless asked for; asked for, a large model's cost goes to stderr once).
pub(crate) fn model_device(request: Option<ModelDevice>, model: &ModelSize) -> Result<Device, String> {
    let machine = Machine::this();
    let n = machine.cuda_devices;
    let device = match request {
        None if n > 0 => Device::Cuda(0),
        None | Some(ModelDevice::Cpu) => Device::Cpu,
        Some(ModelDevice::Cuda(i)) if i < n => Device::Cuda(i),
        Some(ModelDevice::Cuda(i)) => {
            let has = match n {
                0 => "no CUDA device libtorch can use".to_string(),
                1 => "only cuda:0".to_string(),
                n => format!("cuda:0 to cuda:{}", n - 1),
            };
            let driver = match machine.driver {
                Some(v) => format!("NVIDIA driver {v}"),
                None => "no NVIDIA driver found (/proc/driver/nvidia/version, nvidia-smi)".to_string(),
            };
            let fix = match (n, machine.backend.is_loaded()) {
                (0, false) if machine.driver.is_some() => format!("; fix: {}", cuda_backend::FIX),
                _ => String::new(),
            };
            return Err(format!(
                "devices: cuda:{i} is not on this machine, which has {has} ({driver}; libtorch's CUDA backend: {}){fix}",
                machine.backend.describe()
            ));
        }
    };
    if device == Device::Cpu
        && let Some(note) = cpu_fallback::check_cpu(model, request == Some(ModelDevice::Cpu), &machine)?
    {
        note_once(note);
    }
    Ok(device)
}

/// Prints `note` on stderr, once per process (each rollout worker loads its own model).
fn note_once(note: String) {
    static PRINTED: std::sync::Mutex<BTreeSet<String>> = std::sync::Mutex::new(BTreeSet::new());
    if PRINTED.lock().map(|mut p| p.insert(note.clone())).unwrap_or(true) {
        eprintln!("warning: {note}");
    }
}

/// sha256 over the files of `dir` with these extensions (name and bytes), sorted by name.
pub(crate) fn files_hash(dir: &Path, extensions: &[&str]) -> Result<String, String> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().and_then(|x| x.to_str()).is_some_and(|x| extensions.contains(&x)))
        .collect();
    files.sort();
    let mut h = Sha256::new();
    for f in files {
        h.update(f.file_name().unwrap_or_default().as_encoded_bytes());
        let mut file = std::fs::File::open(&f).map_err(|e| format!("{}: {e}", f.display()))?;
        std::io::copy(&mut file, &mut h).map_err(|e| format!("{}: {e}", f.display()))?;
    }
    Ok(format!("{:x}", h.finalize()))
}
