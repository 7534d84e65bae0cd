//! The in-process OpenVLA-OFT port against the Python reference, on a tiny random-weight model in
//! the released LIBERO checkpoint layout: `scripts/reference/oft_tiny.py` builds openvla_tiny.py's
//! Prismatic model (transformers + timm, SDPA attention), OFT's `L1RegressionActionHead` and
//! `ProprioProjector` (torch.nn, saved with `torch.save` under DDP's `module.` keys as
//! `action_head--150000_checkpoint.pt` / `proprio_projector--150000_checkpoint.pt`),
//! `dataset_statistics.json` with action and proprio statistics, and runs OFT's `predict_action`
//! (placeholders, two images, the proprio token, one forward with a 4-D all-ones mask = the fork's
//! bidirectional attention) on fixed inputs. The Rust model loads that directory and must give the
//! same prompt ids and normalised state, the same proprio token and readout hidden states, the
//! same 8 × 7 chunk (f32, max abs diff ≤ 1e-4), the same env actions (gripper equal), and the
//! same actions batched as alone.
//!
//! Needs the venv of `scripts/setup/openvla_ref_venv.sh`: `$LIBERO_OPENVLA_VENV`, else
//! `<repo>/.openvla-venv`. Fails, never skips, when neither exists.

use crate::tiny_reference::{self, max_abs_diff, npy};
use libero_policies::models::openvla::oft::{self, OftModel, OftQuery};
use libero_policies::models::torch_save::read_state_dict;
use libero_policies::postprocess::Gripper;
use libero_policies::preprocess::RgbImage;
use std::path::{Path, PathBuf};
use tch::{Kind, Tensor};

fn build_reference() -> PathBuf {
    tiny_reference::build("oft_tiny.py")
}

fn image(dir: &Path, name: &str) -> RgbImage {
    let t = npy(dir, name);
    let size = t.size();
    RgbImage::new(size[1] as u32, size[0] as u32, Vec::try_from(t.flatten(0, -1)).unwrap()).unwrap()
}

fn f64s(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

#[test]
fn tiny_oft_matches_the_python_reference() {
    let dir = build_reference();
    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("reference/expected.json")).unwrap()).unwrap();

    // torch.save edge cases: dtypes, a transposed view, a slice at an offset of a shared storage
    let probe = read_state_dict(&dir.join("reference/pt_probe.pt")).unwrap();
    let kinds: Vec<(String, Kind)> = probe.iter().map(|(n, t)| (n.clone(), t.kind())).collect();
    assert_eq!(
        kinds,
        [
            ("bf16".to_string(), Kind::BFloat16),
            ("fp16".into(), Kind::Half),
            ("int64".into(), Kind::Int64),
            ("transposed".into(), Kind::Float),
            ("offset_slice".into(), Kind::Float),
            ("scalar".into(), Kind::Float)
        ]
    );
    for (name, t) in &probe {
        let want = npy(&dir, &format!("pt_probe_{name}.npy"));
        // tch's read_npy gives a 0-d array the shape [1]
        let want = if name == "scalar" { want.view([] as [i64; 0]) } else { want };
        assert_eq!(t.size(), want.size(), "{name}");
        assert_eq!(max_abs_diff(&t.to_kind(Kind::Float), &want), 0.0, "{name}");
    }

    let model = OftModel::load(&dir).expect("load the tiny OFT checkpoint");
    let (primary, wrist) = (image(&dir, "primary.npy"), image(&dir, "wrist.npy"));
    let state_v: Vec<f64> = Vec::try_from(npy(&dir, "state.npy")).unwrap();
    let state: [f64; 8] = state_v.try_into().unwrap();
    let instruction = expected["instruction"].as_str().unwrap();
    let key = expected["unnorm_key"].as_str().unwrap();

    let ids: Vec<i64> = expected["input_ids"].as_array().unwrap().iter().map(|v| v.as_i64().unwrap()).collect();
    assert_eq!(model.input_ids(instruction).unwrap(), ids, "prompt token ids");
    let d_token = max_abs_diff(&model.proprio_token(&state, Some(key)).unwrap(), &npy(&dir, "proprio_token.npy"));

    let query = OftQuery { primary: &primary, wrist: &wrist, state, instruction };
    let pred = model.predict_chunk(&query, Some(key)).unwrap();
    // numpy's f64 arithmetic in the same order: equal
    assert_eq!(pred.proprio, f64s(&expected["proprio_normalized"]));
    assert!(pred.proprio.contains(&1.0), "the state must exercise the clip: {:?}", pred.proprio);
    let d_readout = max_abs_diff(&pred.readout, &npy(&dir, "readout.npy"));
    let ref_norm = npy(&dir, "normalized.npy");
    let flat: Vec<f32> = pred.normalized.iter().flatten().copied().collect();
    let d_norm = max_abs_diff(&Tensor::from_slice(&flat).view([8, 7]), &ref_norm);
    let ref_actions: Vec<Vec<f64>> = expected["actions"].as_array().unwrap().iter().map(f64s).collect();
    let ref_env: Vec<Vec<f64>> = expected["env_actions"].as_array().unwrap().iter().map(f64s).collect();
    assert_eq!((pred.actions.len(), ref_actions.len()), (8, 8), "an 8-action chunk");
    let d_actions = pred
        .actions
        .iter()
        .zip(&ref_actions)
        .flat_map(|(a, r)| a.iter().zip(r).map(|(x, y)| (x - y).abs()))
        .fold(0.0, f64::max);
    eprintln!(
        "max |rust - python|: proprio token {d_token:.3e}, readout {d_readout:.3e} (range ±{:.1}), normalized chunk \
         {d_norm:.3e}, un-normalised chunk {d_actions:.3e}; bidirectional vs causal in the reference {:.2}",
        npy(&dir, "readout.npy").abs().max().double_value(&[]),
        expected["bidirectional_vs_causal_max_abs"].as_f64().unwrap()
    );
    assert!(d_token <= 1e-4, "proprio token differs by {d_token}");
    assert!(d_readout <= 1e-4, "readout differs by {d_readout}");
    assert!(d_norm <= 1e-4, "normalized chunk differs by {d_norm}");
    assert!(d_actions <= 1e-4, "un-normalised chunk differs by {d_actions}");
    // the env's chunk: arm within 1e-4, the binarised gripper equal
    let env: Vec<[f64; 7]> = pred
        .actions
        .iter()
        .map(|a| {
            let mut a = *a;
            a[6] = Gripper::OPENVLA.apply(a[6]);
            a
        })
        .collect();
    for (a, r) in env.iter().zip(&ref_env) {
        assert_eq!(a[6], r[6], "gripper");
        assert!(a.iter().zip(r).all(|(x, y)| (x - y).abs() <= 1e-4), "{a:?} vs {r:?}");
    }
    let grippers: std::collections::BTreeSet<i64> = env.iter().map(|a| a[6] as i64).collect();
    assert_eq!(grippers.len(), 2, "the chunk should open and close the gripper so that the check is not vacuous");
    // OFT's un-normalisation in numpy's precision, on the reference's own head output: equal
    let (action_stats, _) = model.stats(Some(key)).unwrap();
    let ref_flat: Vec<f32> = Vec::try_from(ref_norm.flatten(0, -1)).unwrap();
    for (row, want) in ref_flat.chunks(7).zip(&ref_actions) {
        assert_eq!(&oft::unnormalize(&action_stats, row), want);
    }

    // one forward for several episodes: prompts of different lengths left-padded; each row must
    // give what it gives alone
    let shifted = |img: &RgbImage, k: u8| {
        RgbImage::new(224, 224, img.rgb.iter().map(|&v| v.wrapping_add(k * 40)).collect()).unwrap()
    };
    let primaries: Vec<RgbImage> = (0..3).map(|k| shifted(&primary, k)).collect();
    let wrists: Vec<RgbImage> = (0..3).map(|k| shifted(&wrist, 2 * k)).collect();
    let instructions = [instruction, "open the top drawer of the cabinet", "put the bowl on the plate"];
    let queries: Vec<OftQuery> = (0..3)
        .map(|k| {
            let mut s = state;
            s[0] += 0.05 * k as f64;
            OftQuery { primary: &primaries[k], wrist: &wrists[k], state: s, instruction: instructions[k] }
        })
        .collect();
    let batched = model.predict_chunks(&queries, Some(key)).unwrap();
    let lengths: std::collections::BTreeSet<usize> = batched.iter().map(|p| p.input_ids.len()).collect();
    assert_eq!(lengths.len(), 3, "the prompts must differ in length so that padding is exercised: {lengths:?}");
    for (q, b) in queries.iter().zip(&batched) {
        let alone = model.predict_chunk(q, Some(key)).unwrap();
        let d = max_abs_diff(&alone.readout, &b.readout);
        let da = alone
            .actions
            .iter()
            .flatten()
            .zip(b.actions.iter().flatten())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        eprintln!(
            "batch of 3 vs alone ({:?}, {} prompt tokens): readout {d:.3e}, actions {da:.3e}",
            q.instruction,
            b.input_ids.len()
        );
        assert!(d <= 1e-5 && da <= 1e-5, "{:?}: batched differs by {d} / {da}", q.instruction);
        let grip = |p: &oft::OftPrediction| p.actions.iter().map(|a| Gripper::OPENVLA.apply(a[6])).collect::<Vec<_>>();
        assert_eq!(grip(&alone), grip(b));
    }

    // errors that name what to fix, before any weight is used
    let e = model.predict_chunk(&query, Some("libero_nope")).unwrap_err().to_string();
    assert!(e.contains(key), "{e}");
    let partial = dir.join("partial");
    std::fs::create_dir_all(&partial).unwrap();
    for f in std::fs::read_dir(&dir).unwrap() {
        let p = f.unwrap().path();
        if p.is_file() && !p.file_name().unwrap().to_str().unwrap().starts_with("action_head") {
            std::fs::copy(&p, partial.join(p.file_name().unwrap())).unwrap();
        }
    }
    let e = OftModel::load(&partial).err().expect("no action head").to_string();
    assert!(e.contains("action_head--") && e.contains("partial"), "{e}");
    std::fs::write(partial.join("action_head--150000_checkpoint.pt"), b"not a zip").unwrap();
    let e = OftModel::load(&partial).err().expect("a bad action head").to_string();
    assert!(e.contains("action_head--150000_checkpoint.pt") && e.contains("torch.save"), "{e}");
    let e = OftModel::load(&dir.join("nope")).err().expect("no directory").to_string();
    assert!(e.contains("nope"), "{e}");

    let _ = std::fs::remove_dir_all(&dir);
}
