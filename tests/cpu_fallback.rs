//! No silent CPU fallback through the binary (`policies::models::cpu_fallback`): on this machine
//! (no GPU) a model of a billion parameters or more that did not ask for the CPU is refused before
//! any episode, with what it would cost and the option that runs it anyway.

use libero_e2e::{pipeline, spatial_task0_specs, test_dir};

/// A TorchScript file of 4 GB (sparse: no disk used, never read) is ~1 B fp32 parameters.
#[test]
fn a_large_model_without_devices_cpu_is_refused_before_any_episode() {
    let d = test_dir("cpu_fallback", "large-torchscript");
    let model = d.join("model.pt");
    std::fs::File::create(&model).unwrap().set_len(4_000_000_000).unwrap();
    std::fs::write(d.join("model.json"), r#"{"inputs": ["state"], "chunk_size": 1}"#).unwrap();
    let specs = spatial_task0_specs(&d, "1");
    let run = d.join("run");
    let policy = format!("torchscript:{}", model.display());
    let out = pipeline(&["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", &policy]);
    assert!(!out.status.success(), "a 1 B-parameter model ran on the CPU unasked");
    let stderr = String::from_utf8_lossy(&out.stderr);
    for says in ["~1.0 B parameters", "~4 GB of memory", "no NVIDIA GPU", "libtorch_cuda.so"] {
        assert!(stderr.contains(says), "{says:?} not in: {stderr}");
    }
    assert!(stderr.contains(&format!("{policy}?devices=cpu")), "the option that runs it anyway: {stderr}");
    assert!(!run.join("episodes").exists(), "episodes were run");
}
