//! The TorchScript policy on a real TorchScript file: a small module traced with libtorch
//! (`CModule::create_by_tracing`, the same graph format `torch.jit.trace` writes), saved, loaded
//! back through `TorchScriptPolicy` with its `model.json`, and compared with the same arithmetic
//! done directly: image layout and rotation, state, chunking, un-normalisation and gripper.
#![cfg(feature = "torch")]

use libero_policies::models::torchscript::TorchScriptPolicy;
use libero_policies::{Action, CameraImage, CameraImages, Observation, Policy};
use std::path::{Path, PathBuf};
use tch::{CModule, Device, Kind, Tensor};

const SIZE: u32 = 8;
const CHUNK: i64 = 4;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("libero-torchscript-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// out[0, i, j] = 0.1·state[j] + mean(agentview) + 2·mean(wrist[:, 0, 0, 0]) + 0.01·i, for j < 7.
fn trace(path: &Path) {
    let a = Tensor::rand([1, 3, SIZE as i64, SIZE as i64], (Kind::Float, Device::Cpu));
    let w = Tensor::rand([1, 3, SIZE as i64, SIZE as i64], (Kind::Float, Device::Cpu));
    let s = Tensor::rand([1, 8], (Kind::Float, Device::Cpu));
    let module = CModule::create_by_tracing("Toy", "forward", &[a, w, s], &mut |x| {
        let base =
            x[2].narrow(1, 0, 7) * 0.1 + x[0].mean(Kind::Float) + x[1].select(1, 0).select(1, 0).select(1, 0) * 2.0;
        let steps = Tensor::arange(CHUNK, (Kind::Float, Device::Cpu)).reshape([1, CHUNK, 1]) * 0.01;
        vec![base.unsqueeze(1) + steps]
    })
    .unwrap();
    module.save(path).unwrap();
}

fn manifest(path: &Path, extra: &str) {
    let json = format!(
        r#"{{"inputs": ["agentview", "wrist", "state"], "image_size": {SIZE}, "preprocessing": "rot180",
            "chunk_size": {CHUNK}, "replan_steps": 3 {extra}}}"#
    );
    std::fs::write(path.with_extension("json"), json).unwrap();
}

/// A camera image in the reference (OpenGL) row order whose pixel (row r, col c, channel k) is
/// `base + 3r + c + k` (mod 256).
fn camera(base: u8) -> CameraImage {
    let n = SIZE as usize;
    let rgb = (0..n * n * 3).map(|i| base.wrapping_add((3 * (i / (3 * n)) + (i / 3) % n + i % 3) as u8)).collect();
    CameraImage { width: SIZE, height: SIZE, rgb }
}

fn obs() -> Observation {
    Observation {
        eef_pos: [0.1, -0.2, 1.05],
        hand_quat: [0.1, 0.99, 0.05, 0.0],
        gripper_qpos: [0.03, -0.03],
        images: Some(CameraImages { agentview: camera(10), wrist: camera(100) }),
        ..Default::default()
    }
}

/// The expected chunk, computed without the module.
fn expected(o: &Observation) -> Vec<[f64; 7]> {
    let q = o.hand_quat;
    let state = libero_policies::preprocess::libero_state(
        o.eef_pos,
        [q[1], q[2], q[3], q[0]],
        o.gripper_qpos,
        libero_policies::preprocess::QuatSign::AsGiven,
    );
    let imgs = o.images.as_ref().unwrap();
    let mean_a = imgs.agentview.rgb.iter().map(|&v| v as f64).sum::<f64>() / imgs.agentview.rgb.len() as f64 / 255.0;
    // After the 180° rotation, the model's pixel (0, 0) is the reference array's last pixel.
    let n = imgs.wrist.rgb.len();
    let wrist00_red = imgs.wrist.rgb[n - 3] as f64 / 255.0;
    (0..CHUNK as usize)
        .map(|i| std::array::from_fn(|j| 0.1 * (state[j] as f32 as f64) + mean_a + 2.0 * wrist00_red + 0.01 * i as f64))
        .collect()
}

fn run(policy: &mut TorchScriptPolicy, o: &Observation, n: usize) -> Vec<Action> {
    policy.reset("put the bowl on the plate", 0);
    (0..n).map(|_| policy.act(o).unwrap()).collect()
}

#[test]
fn a_traced_module_runs_as_a_policy_with_chunks_in_env_units() {
    let d = dir("plain");
    let file = d.join("model.pt");
    trace(&file);
    manifest(&file, "");
    let mut policy = TorchScriptPolicy::load(&file).unwrap();
    assert_eq!(policy.camera_size(), Some(SIZE), "the first step needs images");
    let o = obs();
    let actions = run(&mut policy, &o, 5);
    let want = expected(&o);
    // replan_steps 3 of a chunk of 4: actions 0, 1, 2, then a new chunk's 0, 1.
    for (t, a) in actions.iter().enumerate() {
        let w = want[t % 3];
        for j in 0..6 {
            assert!((a[j] as f64 - w[j]).abs() < 1e-5, "step {t} dim {j}: {} vs {}", a[j], w[j]);
        }
        assert!((a[6] as f64 - w[6]).abs() < 1e-5, "gripper as is");
    }
    assert_eq!(policy.queries(), 2);
    let id = policy.identity();
    assert_eq!(id["chunking"], serde_json::json!({"predicted": CHUNK, "executed": 3}));
    assert_eq!(id["sha256"].as_str().unwrap().len(), 64);
    assert!(id["images"]["preprocessing"].as_str().unwrap().contains("rot180"));
}

#[test]
fn normalised_outputs_are_unnormalised_with_the_named_key_and_the_gripper_mapped() {
    let d = dir("stats");
    let file = d.join("model.pt");
    trace(&file);
    let stats = r#", "dataset_statistics": {"a": {"action": {"q01": [0,0,0,0,0,0,0], "q99": [2,4,2,2,2,2,1],
                     "mask": [true,true,true,true,true,true,false]}}, "b": {"action": {"q01": [0,0,0,0,0,0,0], "q99": [1,1,1,1,1,1,1]}}},
                     "unnorm_key": "a", "gripper": "openvla""#;
    manifest(&file, stats);
    let mut policy = TorchScriptPolicy::load(&file).unwrap();
    let o = obs();
    let a = run(&mut policy, &o, 1)[0];
    let w = expected(&o)[0];
    assert!((a[0] as f64 - (0.5 * (w[0] + 1.0) * 2.0)).abs() < 1e-5, "{a:?}");
    assert!((a[1] as f64 - (0.5 * (w[1] + 1.0) * 4.0)).abs() < 1e-5, "{a:?}");
    // gripper: unmasked, 2g - 1, sign, inverted
    assert_eq!(a[6] as f64, -(2.0 * w[6] - 1.0).signum());

    // A key the statistics lack names the ones they have.
    manifest(&file, &stats.replace(r#""unnorm_key": "a""#, r#""unnorm_key": "libero_spatial""#));
    let e = TorchScriptPolicy::load(&file).err().unwrap().to_string();
    assert!(e.contains("libero_spatial") && e.contains("a, b"), "{e}");
}

#[test]
fn bad_manifests_and_missing_images_are_clear_errors() {
    let d = dir("bad");
    let file = d.join("model.pt");
    trace(&file);
    let e = TorchScriptPolicy::load(&file).err().unwrap().to_string();
    assert!(e.contains("model.json") && e.contains("manifest"), "{e}");
    std::fs::write(d.join("model.json"), r#"{"inputs": ["agentview", "depth"]}"#).unwrap();
    let e = TorchScriptPolicy::load(&file).err().unwrap().to_string();
    assert!(e.contains("depth") && e.contains("known"), "{e}");
    manifest(&file, "");
    let mut policy = TorchScriptPolicy::load(&file).unwrap();
    policy.reset("x", 0);
    let e = policy.act(&Observation::default()).unwrap_err().to_string();
    assert!(e.contains("no camera images"), "{e}");
    std::fs::write(&file, b"not a module").unwrap();
    let e = TorchScriptPolicy::load(&file).err().unwrap().to_string();
    assert!(e.contains("not a TorchScript module"), "{e}");
}
