//! Parity of the policy pre/post-processing with the reference Python, on the same inputs.
//!
//! `scripts/reference/preprocess_fixtures.py` runs with the reference venv's python (numpy,
//! Pillow, robosuite) into a temporary folder, on two synthetic images (256×256 and 256×200:
//! gradients, a fine checkerboard, a disc, a line) and two real camera frames of the reference
//! env (`data/frames/mujoco-3.3.7`, agentview and wrist); then every step is compared:
//!
//! | step | reference | asserted |
//! |---|---|---|
//! | rot180 | `img[::-1, ::-1]` | exact |
//! | Lanczos 224 | PIL `resize(LANCZOS)` | exact (Pillow's fixed-point algorithm reproduced) |
//! | bilinear 224 | PIL `resize(BILINEAR)` | exact |
//! | other sizes | PIL, 256² → 7 non-square sizes, both filters | exact (Pillow 13's pass order) |
//! | pad-resize 224 | openpi `resize_with_pad` | exact |
//! | center crop 0.9 | `tf.image.crop_and_resize` transcribed to float32 numpy | max 1 (measured 0; a last-bit float difference could cross a truncation) |
//! | JPEG 95 | PIL (libjpeg-turbo) save + open | frames max 3 (measured 3, mean 0.08), synthetic max 6 (measured 5, mean 0.11): jpeg-decoder's IDCT and upsampler are not libjpeg-turbo's |
//! | OpenVLA chain | rot → JPEG → Lanczos → crop | frames max 3, synthetic 4, mean ≤ 0.15 (measured 3, mean 0.10–0.14: the JPEG difference, carried through) |
//! | quat2axisangle | robosuite `transform_utils.quat2axisangle` | 1e-15 relative (measured: bit-identical) |
//! | un-normalisation + gripper | prismatic `predict_action` + `robot_utils` | 1e-12 |
//!
//! The test fails (never skips) without the reference venv: run ./setup.sh --tests.

use libero_policies::postprocess::{Gripper, NormStats, PostprocessError, postprocess_action};
use libero_policies::preprocess::image::{self, Filter, RgbImage};
use libero_policies::preprocess::proprio::{LIBERO_EEF_HEMISPHERE, QuatSign, libero_state, quat2axisangle};
use libero_policies::preprocess::{ImagePipeline, Resize};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// The fixtures, computed once per test process.
fn fixtures() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let root = repo_root();
        let python = root.join(".venv/bin/python");
        assert!(python.exists(), "no reference venv at {}: run ./setup.sh --tests", python.display());
        let frames = root.join("data/frames/mujoco-3.3.7");
        let picks = ["libero_10__00__init0__s040__agentview.png", "libero_10__00__init0__s040__robot0_eye_in_hand.png"];
        for p in picks {
            assert!(frames.join(p).exists(), "no reference frame {p} in {}: run ./setup.sh --tests", frames.display());
        }
        // an ALOHA-sim `top` frame (upright 480x640) of the ALOHA bundle's golden episodes
        let top = root.join("data/aloha/golden/transfer_cube_seed1000/top_s050.npy");
        assert!(top.exists(), "no ALOHA-sim golden frame {}: run ./setup.sh --tests", top.display());
        let out = std::env::temp_dir().join(format!("libero-preprocess-parity-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let run = Command::new(python)
            .arg(root.join("scripts/reference/preprocess_fixtures.py"))
            .arg(&out)
            .args(picks.map(|p| frames.join(p)))
            .arg(&top)
            .output()
            .expect("run the reference python");
        assert!(
            run.status.success(),
            "preprocess_fixtures.py failed:\n{}\n{}",
            String::from_utf8_lossy(&run.stdout),
            String::from_utf8_lossy(&run.stderr)
        );
        out
    })
}

/// A uint8 H×W×3 `.npy` (C order) as an image.
fn read_image(path: &Path) -> RgbImage {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&bytes[..6], b"\x93NUMPY", "{}", path.display());
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        _ => (u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize, 12),
    };
    let header = std::str::from_utf8(&bytes[start..start + header_len]).unwrap();
    assert!(header.contains("'descr': '|u1'") && header.contains("'fortran_order': False"), "{header}");
    let shape = &header[header.find("'shape': (").unwrap() + 10..];
    let dims: Vec<u32> = shape[..shape.find(')').unwrap()].split(',').filter_map(|s| s.trim().parse().ok()).collect();
    assert_eq!(dims.len(), 3, "{header}");
    assert_eq!(dims[2], 3, "{header}");
    RgbImage::new(dims[1], dims[0], bytes[start + header_len..].to_vec()).unwrap()
}

fn json(name: &str) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(fixtures().join(name)).unwrap()).unwrap()
}

fn image_names() -> Vec<String> {
    json("meta.json")["images"].as_array().unwrap().iter().map(|v| v.as_str().unwrap().to_string()).collect()
}

fn load(name: &str, step: &str) -> RgbImage {
    read_image(&fixtures().join(format!("{name}__{step}.npy")))
}

/// (max |Δ|, mean |Δ|, pixels-channels with |Δ| > 1)
fn diff(ours: &RgbImage, theirs: &RgbImage) -> (u8, f64, usize) {
    assert_eq!((ours.width, ours.height), (theirs.width, theirs.height));
    let d: Vec<u8> = ours.rgb.iter().zip(&theirs.rgb).map(|(a, b)| a.abs_diff(*b)).collect();
    let max = d.iter().copied().max().unwrap_or(0);
    let mean = d.iter().map(|&x| x as f64).sum::<f64>() / d.len() as f64;
    (max, mean, d.iter().filter(|&&x| x > 1).count())
}

/// Compare one step on every image: `ours` from the reference's previous step.
fn check_step(
    step: &str,
    from: &str,
    max_frame: u8,
    max_synthetic: u8,
    max_mean: f64,
    f: impl Fn(&RgbImage) -> RgbImage,
) {
    let mut failures = Vec::new();
    for name in image_names() {
        let ours = f(&load(&name, from));
        let theirs = load(&name, step);
        let (max, mean, over1) = diff(&ours, &theirs);
        println!("{step:>20} {name:<45} max {max} mean {mean:.4} |Δ|>1: {over1}");
        let limit = if name.starts_with("synthetic") { max_synthetic } else { max_frame };
        if max > limit || mean > max_mean {
            failures.push(format!("{name}: max {max} (limit {limit}), mean {mean:.4} (limit {max_mean})"));
        }
    }
    assert!(failures.is_empty(), "{step} differs from the reference:\n{}", failures.join("\n"));
}

#[test]
fn rotate_180_is_exact() {
    check_step("rot180", "input", 0, 0, 0.0, image::rotate_180);
}

#[test]
fn pil_lanczos_resize_is_exact() {
    check_step("lanczos224", "rot180", 0, 0, 0.0, |x| image::resize(x, 224, 224, Filter::Lanczos));
}

/// Non-square sizes: Pillow's pass order (vertical first when it shrinks more) reproduced.
#[test]
fn pil_resize_to_other_sizes_is_exact() {
    let shapes = json("meta.json")["resize_shapes"].as_array().unwrap().clone();
    assert!(shapes.len() >= 6);
    let input = load("synthetic256", "rot180");
    for s in shapes {
        let (w, h) = (s[0].as_u64().unwrap() as u32, s[1].as_u64().unwrap() as u32);
        for (filter, tag) in [(Filter::Lanczos, "lanczos"), (Filter::Bilinear, "bilinear")] {
            let (max, mean, _) =
                diff(&image::resize(&input, w, h, filter), &load("synthetic256", &format!("{tag}_{w}x{h}")));
            assert_eq!(max, 0, "{tag} 256x256 -> {w}x{h}: max {max} mean {mean}");
        }
    }
}

#[test]
fn pil_bilinear_resize_is_exact() {
    check_step("bilinear224", "rot180", 0, 0, 0.0, |x| image::resize(x, 224, 224, Filter::Bilinear));
}

#[test]
fn openpi_resize_with_pad_is_exact() {
    check_step("resize_with_pad224", "rot180", 0, 0, 0.0, |x| image::resize_with_pad(x, 224, 224, Filter::Bilinear));
    // The openpi preset is rot180 + this.
    for name in image_names() {
        let ours = ImagePipeline::OPENPI.apply(&load(&name, "input")).unwrap();
        assert_eq!(ours, load(&name, "resize_with_pad224"), "{name}");
    }
}

/// openpi's ALOHA-sim `cam_high` (`resize_with_pad` 224 of the upright 480 × 640 `top` frame,
/// then channels first), on a synthetic frame and a rendered one: exact.
#[test]
fn openpi_aloha_cam_high_is_exact() {
    let names: Vec<String> =
        json("meta.json")["aloha_images"].as_array().unwrap().iter().map(|v| v.as_str().unwrap().to_string()).collect();
    assert_eq!(names.len(), 2, "{names:?}");
    for name in names {
        let input = load(&name, "input");
        let top = libero_policies::CameraImage { width: input.width, height: input.height, rgb: input.rgb };
        let chw = libero_policies::remote::openpi_aloha::cam_high(&top).unwrap();
        let plane = 224 * 224;
        let hwc: Vec<u8> = (0..plane).flat_map(|i| [chw[i], chw[plane + i], chw[2 * plane + i]]).collect();
        let theirs = load(&name, "pad224");
        assert_eq!((theirs.width, theirs.height), (224, 224));
        assert!(hwc == theirs.rgb, "{name}: {:?}", diff(&RgbImage::new(224, 224, hwc.clone()).unwrap(), &theirs));
    }
}

/// float32 like TensorFlow's kernel; a last-bit difference can move a value across the
/// truncation of `convert_image_dtype` by one level.
#[test]
fn tf_center_crop_matches_the_float32_transcription() {
    check_step("crop09", "lanczos224", 1, 1, 0.001, |x| image::center_crop(x, 0.9));
}

/// Same encoder output as libjpeg-turbo on camera frames; the decoder's IDCT and chroma
/// upsampling are not libjpeg-turbo's.
#[test]
fn jpeg_round_trip_is_close_to_libjpeg() {
    check_step("jpeg95", "rot180", 3, 6, 0.15, |x| image::jpeg_round_trip(x, 95).unwrap());
}

#[test]
fn openvla_chain_is_close() {
    check_step("openvla", "input", 3, 4, 0.15, |x| ImagePipeline::OPENVLA.apply(x).unwrap());
    // Without the JPEG step the chain is the exact steps above, composed.
    let no_jpeg = ImagePipeline { jpeg_quality: None, ..ImagePipeline::OPENVLA };
    assert_eq!(no_jpeg.resize, Resize::Stretch { size: 224, filter: Filter::Lanczos });
    check_step("crop09", "input", 1, 1, 0.001, |x| no_jpeg.apply(x).unwrap());
}

fn f64s(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

/// float64 values stored as IEEE bit patterns.
fn arr<const N: usize>(v: &serde_json::Value) -> [f64; N] {
    let bits: Vec<f64> = v.as_array().unwrap().iter().map(|x| f64::from_bits(x.as_u64().unwrap())).collect();
    bits.try_into().unwrap()
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs().max(1e-300) || a == b
}

#[test]
fn quat2axisangle_matches_robosuite() {
    let doc = json("proprio.json");
    let rows = doc["quat2axisangle"].as_array().unwrap();
    assert!(rows.len() >= 20);
    let mut worst = 0.0f64;
    for r in rows {
        let q = arr::<4>(&r["quat_xyzw"]);
        let want = arr::<3>(&r["axisangle"]);
        let got = quat2axisangle(q);
        for i in 0..3 {
            assert!(close(got[i], want[i], 1e-15), "{q:?}: ours {got:?} robosuite {want:?}");
            worst = worst.max((got[i] - want[i]).abs());
        }
    }
    println!("quat2axisangle: {} quaternions, max |Δ| {worst:e}", rows.len());

    // The antipodal case: robosuite gives different vectors for q and -q near π. The hemisphere
    // normalisation maps the antipode of robosuite's LIBERO quaternion (x > 0, w < 0) back.
    let find = |q: [f64; 4]| rows.iter().find(|r| arr::<4>(&r["quat_xyzw"]) == q).map(|r| arr::<3>(&r["axisangle"]));
    let (near, anti) = ([0.9995, 0.0, 0.0, 0.0316], [-0.9995, 0.0, 0.0, -0.0316]);
    assert!(find(near).unwrap()[0] > 3.0 && find(anti).unwrap()[0] < -3.0);
    let libero = [0.9925, 0.05, -0.1, -0.05];
    let want = find(libero).unwrap();
    let flipped = libero.map(|v| -v);
    let s = libero_state([0.0; 3], flipped, [0.0; 2], QuatSign::Hemisphere(LIBERO_EEF_HEMISPHERE));
    assert_eq!(&s[3..6], &want, "hemisphere normalisation must restore robosuite's vector");
    let s = libero_state([0.0; 3], flipped, [0.0; 2], QuatSign::AsGiven);
    assert!((s[3] - want[0]).abs() > 6.0, "as given, the antipode is the other vector: {s:?}");

    let st = &doc["state"];
    let ours = libero_state(
        arr(&st["eef_pos"]),
        arr(&st["eef_quat_xyzw"]),
        arr(&st["gripper_qpos"]),
        QuatSign::Hemisphere(LIBERO_EEF_HEMISPHERE),
    );
    let want = arr::<8>(&st["state"]);
    for i in 0..8 {
        assert!(close(ours[i], want[i], 1e-15), "state {ours:?} vs {want:?}");
    }
}

#[test]
fn unnormalisation_and_gripper_match_openvla() {
    let doc = json("actions.json");
    let stats = NormStats::from_value(&doc["norm_stats"]).unwrap();
    let normalized: Vec<Vec<f64>> = doc["normalized"].as_array().unwrap().iter().map(f64s).collect();
    let mut checked = 0;
    for (key, exp) in doc["expected"].as_object().unwrap() {
        let a = stats.action(Some(key)).unwrap();
        for (i, n) in normalized.iter().enumerate() {
            let un = a.unnormalize(n);
            let want_un = f64s(&exp["unnormalized"][i]);
            let want_env = f64s(&exp["openvla_env"][i]);
            let want_sym = f64s(&exp["gripper_env"][i]);
            for d in 0..7 {
                assert!(close(un[d], want_un[d], 1e-12), "{key} row {i} dim {d}: {} vs {}", un[d], want_un[d]);
            }
            let no_invert = Gripper { invert: false, ..Gripper::OPENVLA };
            assert_eq!(no_invert.apply(un[6]), want_sym[6], "{key} row {i}");
            let env = postprocess_action(n, a, Gripper::OPENVLA).unwrap();
            for d in 0..7 {
                // f32 (the env action type) of the f64 reference; the JSON floats are parsed to
                // within an ulp, hence not bit equality.
                assert!(
                    (env[d] as f64 - want_env[d]).abs() <= 1e-6,
                    "{key} row {i} dim {d}: {} vs {}",
                    env[d],
                    want_env[d]
                );
            }
            assert_eq!(env[6] as f64, want_env[6], "{key} row {i}: the gripper is -1, 0 or 1 exactly");
            checked += 1;
        }
    }
    assert_eq!(checked, 32);
    // The masked gripper dimension of the LIBERO statistics passes through un-normalisation.
    let a = stats.action(Some("libero_spatial_no_noops")).unwrap();
    assert!(!a.mask[6]);
    assert_eq!(a.unnormalize(&normalized[0])[6], normalized[0][6]);
    // Row 0's gripper is 0.5: 2·0.5 − 1 = 0, np.sign(0) = 0, inverted -0.
    assert_eq!(postprocess_action(&normalized[0], a, Gripper::OPENVLA).unwrap()[6], 0.0);

    // A wrong key names the keys the checkpoint has; the suite falls back to `_no_noops`.
    let e = stats.action(Some("libero_spatial")).unwrap_err();
    assert_eq!(
        e,
        PostprocessError::UnknownKey {
            key: "libero_spatial".into(),
            available: vec!["bridge_orig".into(), "libero_spatial_no_noops".into()]
        }
    );
    assert!(e.to_string().ends_with("it has: bridge_orig, libero_spatial_no_noops"), "{e}");
    assert_eq!(stats.libero_unnorm_key("libero_spatial").unwrap(), "libero_spatial_no_noops");
    let e = stats.libero_unnorm_key("libero_object").unwrap_err();
    assert!(e.to_string().contains("\"libero_object\"") && e.to_string().contains("bridge_orig"), "{e}");
    let e = stats.action(None).unwrap_err();
    assert!(matches!(e, PostprocessError::KeyRequired { .. }), "{e}");
}
