//! The in-process OpenVLA port against the Python reference, on a tiny random-weight model of the
//! same architecture (the 7B weights cannot be downloaded here): `scripts/reference/openvla_tiny.py`
//! builds it with transformers + timm (the layer types and patches openvla's `modeling_prismatic.py`
//! uses), saves it as a Hugging Face checkpoint (sharded safetensors, config.json, tokenizer.json,
//! dataset_statistics.json), and writes its outputs on a fixed image and instruction. The Rust model
//! loads that directory and must give the same prompt tokens, the same pixel values, patch features
//! and projections, the same logits before each of the 7 greedy tokens (f32, max abs diff ≤ 1e-4),
//! and the same tokens, bins and action.
//!
//! Needs the venv of `scripts/setup/openvla_ref_venv.sh`: `$LIBERO_OPENVLA_VENV`, else
//! `<repo>/.openvla-venv`. Fails, never skips, when neither exists.

use crate::tiny_reference::{self, max_abs_diff, npy};
use libero_policies::models::openvla::{Fusion, OpenVlaModel};
use libero_policies::preprocess::RgbImage;
use std::path::PathBuf;

fn build_reference() -> PathBuf {
    tiny_reference::build("openvla_tiny.py")
}

#[test]
fn tiny_openvla_matches_the_python_reference() {
    let dir = build_reference();
    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("reference/expected.json")).unwrap()).unwrap();
    let model = OpenVlaModel::load(&dir).expect("load the tiny checkpoint");

    let image_t = npy(&dir, "image.npy");
    let size = image_t.size();
    let rgb: Vec<u8> = Vec::try_from(image_t.flatten(0, -1)).unwrap();
    let image = RgbImage::new(size[1] as u32, size[0] as u32, rgb).unwrap();
    let instruction = expected["instruction"].as_str().unwrap();
    let unnorm_key = expected["unnorm_key"].as_str().unwrap();

    // prompt tokens (tokenizers crate vs transformers' LlamaTokenizerFast on the same tokenizer.json)
    let ids: Vec<i64> = expected["input_ids"].as_array().unwrap().iter().map(|v| v.as_i64().unwrap()).collect();
    assert_eq!(model.input_ids(instruction).unwrap(), ids, "prompt token ids");
    assert_eq!(*ids.last().unwrap(), libero_policies::models::openvla::EMPTY_TOKEN);

    // the stages, for a precise diagnosis when the end result differs
    let pv = model.pixel_values(&image).unwrap();
    let d_pv = max_abs_diff(&pv, &npy(&dir, "pixel_values.npy"));
    let (patches, projected) = model.vision_features(&pv);
    let d_patches = max_abs_diff(&patches, &npy(&dir, "patch_features.npy"));
    let d_proj = max_abs_diff(&projected, &npy(&dir, "projected.npy"));

    let pred = model.predict_action(&image, instruction, Some(unnorm_key)).unwrap();
    let ref_logits = npy(&dir, "step_logits.npy");
    let d_logits = max_abs_diff(&pred.step_logits, &ref_logits);
    let per_step: Vec<String> = (0..ref_logits.size()[0])
        .map(|i| format!("{:.2e}", max_abs_diff(&pred.step_logits.get(i), &ref_logits.get(i))))
        .collect();
    eprintln!(
        "max |rust - python|: pixel_values {d_pv:.3e}, patch features {d_patches:.3e}, projected {d_proj:.3e}, \
         logits {d_logits:.3e} (per step {}; logits range ±{:.1})",
        per_step.join(", "),
        ref_logits.abs().max().double_value(&[])
    );
    assert_eq!(d_pv, 0.0, "pixel values are computed with the same f32 operations");
    assert!(d_patches <= 1e-4, "patch features differ by {d_patches}");
    assert!(d_proj <= 1e-4, "projected patches differ by {d_proj}");
    assert!(d_logits <= 1e-4, "logits differ by {d_logits}");

    let tokens: Vec<i64> = expected["tokens"].as_array().unwrap().iter().map(|v| v.as_i64().unwrap()).collect();
    assert_eq!(pred.tokens, tokens, "greedy action tokens");
    let bins: Vec<usize> = expected["bins"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
    assert_eq!(pred.bins, bins);
    let f64s = |k: &str| -> Vec<f64> { expected[k].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect() };
    assert_eq!(pred.normalized_action, f64s("normalized_action"));
    // numpy's f64 arithmetic, same order; JSON round trip of f64 is exact
    assert_eq!(pred.action, f64s("action"));
    // the tiny model decodes to several distinct bins, so the comparison is not vacuous
    assert!(pred.bins.iter().collect::<std::collections::BTreeSet<_>>().len() >= 3);

    // one forward for several episodes: prompts of different lengths left-padded and masked; each
    // row must decode what it decodes alone
    let images: Vec<RgbImage> = (0..3u8)
        .map(|k| RgbImage::new(224, 224, image.rgb.iter().map(|&v| v.wrapping_add(k * 40)).collect()).unwrap())
        .collect();
    let instructions = [instruction, "open the top drawer of the cabinet", "put the bowl on the plate"];
    let queries: Vec<(&RgbImage, &str)> = images.iter().zip(instructions).collect();
    let batched = model.predict_actions(&queries, Some(unnorm_key)).unwrap();
    let lengths: std::collections::BTreeSet<usize> = batched.iter().map(|p| p.input_ids.len()).collect();
    assert_eq!(lengths.len(), 3, "the prompts must differ in length so that padding is exercised: {lengths:?}");
    for ((img, instr), b) in queries.iter().zip(&batched) {
        let alone = model.predict_action(img, instr, Some(unnorm_key)).unwrap();
        let d = max_abs_diff(&alone.step_logits, &b.step_logits);
        eprintln!("batch of 3 vs alone ({instr:?}, {} prompt tokens): logits {d:.3e}", b.input_ids.len());
        assert!(d <= 1e-5, "{instr:?}: batched logits differ by {d}");
        assert_eq!(alone.tokens, b.tokens, "{instr:?}: batched tokens");
        assert_eq!(alone.action, b.action, "{instr:?}: batched action");
    }

    // the fused kernels (the default on CUDA; here on the CPU, the RMSNorm excepted): the same
    // tokens and actions as the reference, logits within the same bound, alone and batched
    assert_eq!(model.fusion(), Fusion::NONE, "a CPU model computes transformers' operations one by one");
    let mut fused = OpenVlaModel::load(&dir).unwrap();
    fused.set_fusion(Fusion::ALL);
    let f = fused.predict_action(&image, instruction, Some(unnorm_key)).unwrap();
    let d_fused = max_abs_diff(&f.step_logits, &ref_logits);
    eprintln!("fused kernels: logits {d_fused:.3e} from the Python reference");
    assert!(d_fused <= 1e-4, "fused logits differ by {d_fused}");
    assert_eq!(f.tokens, tokens, "fused greedy action tokens");
    assert_eq!(f.action, pred.action);
    for (b, fb) in batched.iter().zip(fused.predict_actions(&queries, Some(unnorm_key)).unwrap()) {
        assert!(max_abs_diff(&b.step_logits, &fb.step_logits) <= 1e-4);
        assert_eq!(b.tokens, fb.tokens, "fused batched tokens");
    }
    // 8 sequences: the preallocated KV cache (`Fusion::static_cache`, from STATIC_CACHE_MIN_ROWS)
    // and q/k/v stacked in the decode steps; each row decodes what it decodes alone
    let eight: Vec<(&RgbImage, &str)> = queries.iter().cycle().take(8).copied().collect();
    assert!(eight.len() as i64 >= libero_policies::models::openvla::STATIC_CACHE_MIN_ROWS);
    for (i, fb) in fused.predict_actions(&eight, Some(unnorm_key)).unwrap().iter().enumerate() {
        let b = &batched[i % batched.len()];
        let d = max_abs_diff(&b.step_logits, &fb.step_logits);
        assert!(d <= 1e-4, "row {i} of 8 (static cache): logits differ by {d}");
        assert_eq!(b.tokens, fb.tokens, "row {i} of 8 (static cache): tokens");
    }

    // errors that name what to fix
    let e = model.predict_action(&image, instruction, Some("libero_nope")).unwrap_err();
    assert!(e.to_string().contains(unnorm_key), "{e}");
    let small = RgbImage::new(8, 8, vec![0; 8 * 8 * 3]).unwrap();
    assert!(model.predict_action(&small, instruction, None).unwrap_err().to_string().contains("224x224"));

    // checkpoint files that cannot be used name the fix
    let partial = dir.join("partial");
    std::fs::create_dir_all(&partial).unwrap();
    std::fs::copy(dir.join("config.json"), partial.join("config.json")).unwrap();
    let e = OpenVlaModel::load(&partial).err().expect("no tokenizer.json").to_string();
    assert!(e.contains("tokenizer.json") && e.contains("save_pretrained"), "{e}");
    let pre = std::fs::read_to_string(dir.join("preprocessor_config.json")).unwrap();
    let letterboxed = pre.replace("\"tvf_do_letterbox\": false", "\"tvf_do_letterbox\": [true, true]");
    assert_ne!(pre, letterboxed);
    std::fs::write(partial.join("preprocessor_config.json"), letterboxed).unwrap();
    let e = libero_policies::models::openvla::OpenVlaConfig::load(&partial).expect_err("letterbox").to_string();
    assert!(e.contains("letterbox"), "{e}");

    let _ = std::fs::remove_dir_all(&dir);
}
