//! OpenVLA's (or OpenVLA-OFT's) per-query latency and batched throughput, in process on libtorch.
//!
//! ```text
//! cargo bench -p libero-policies --bench openvla -- --checkpoint DIR [--oft] [--batch 1,8,32]
//!     [--iters 10] [--warmup 2] [--device cuda|cpu] [--attention eager|sdpa] [--json OUT.json]
//! ```
//!
//! `--attention` overrides the model's attention implementation (OpenVLA: eager, as its parity
//! reference; OFT: SDPA, as openvla-oft loads it), to time the other one.
//!
//! One timed call is [`OpenVlaModel::predict_actions`] on B (image, instruction) pairs: the fused
//! vision tower on B images, the prefill of B left-padded prompts (LIBERO instructions of different
//! lengths), and 7 greedy decode steps, the tokens read back to the host after each (as the rollout
//! needs them). Per-action latency is the call's time at B = 1; throughput is B actions per call.
//! The images are random (the arithmetic does not depend on pixel values), the weights are the
//! checkpoint's: the full-size run uses a random-weight bf16 checkpoint of the 7B architecture
//! written by `scripts/reference/openvla_bench.py`, which also times the Python reference's forward.
//! Without `--checkpoint` (as under a plain `cargo bench`) it says what it needs and exits.
//!
//! With `--oft` the checkpoint is an OpenVLA-OFT one and a timed call is
//! [`OftModel::predict_chunks`] on B queries (two random images, a state and an instruction each):
//! the vision tower on 2B images, the proprio projector, one bidirectional forward of B left-padded
//! sequences and the L1 head, the 8 × 7 chunks read back. The full-size checkpoint is written by
//! `scripts/reference/oft_bench.py`, which times the Python forward the same way.

use libero_policies::models::openvla::oft::{OftModel, OftQuery, PROPRIO_DIM};
use libero_policies::models::openvla::{Attention, OpenVlaModel};
use libero_policies::preprocess::RgbImage;
use std::path::PathBuf;
use std::time::Instant;
use tch::{Device, Kind};

/// LIBERO instructions of different lengths (one per suite and a long libero_10 one).
const INSTRUCTIONS: [&str; 4] = [
    "pick up the black bowl between the plate and the ramekin and place it on the plate",
    "pick up the alphabet soup and place it in the basket",
    "open the middle drawer of the cabinet",
    "put both the alphabet soup and the tomato sauce in the basket",
];

struct Args {
    checkpoint: Option<PathBuf>,
    oft: bool,
    attention: Option<Attention>,
    batches: Vec<usize>,
    iters: usize,
    warmup: usize,
    device: Device,
    json: Option<PathBuf>,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        checkpoint: std::env::var_os("LIBERO_OPENVLA_BENCH_CHECKPOINT").map(PathBuf::from),
        oft: false,
        attention: None,
        batches: vec![1, 8, 32],
        iters: 10,
        warmup: 2,
        device: Device::cuda_if_available(),
        json: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--checkpoint" => a.checkpoint = Some(value()?.into()),
            "--oft" => a.oft = true,
            "--attention" => {
                a.attention = Some(match value()?.as_str() {
                    "eager" => Attention::Eager,
                    "sdpa" => Attention::Sdpa,
                    other => return Err(format!("--attention: {other:?} is not eager or sdpa")),
                })
            }
            "--batch" => {
                a.batches = value()?
                    .split(',')
                    .map(|b| b.parse().ok().filter(|&b: &usize| b >= 1).ok_or(format!("--batch: bad size {b:?}")))
                    .collect::<Result<_, _>>()?
            }
            "--iters" => {
                a.iters = value()?.parse().ok().filter(|&n: &usize| n >= 1).ok_or("--iters must be at least 1")?
            }
            "--warmup" => a.warmup = value()?.parse().map_err(|e| format!("--warmup: {e}"))?,
            "--device" => {
                a.device = match value()?.as_str() {
                    "cuda" => Device::Cuda(0),
                    "cpu" => Device::Cpu,
                    d => return Err(format!("--device: {d:?} is not cuda or cpu")),
                }
            }
            "--json" => a.json = Some(value()?.into()),
            // cargo bench passes --bench to every bench binary
            "--bench" => {}
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    Ok(a)
}

/// A `[H, W, 3]` uint8 `.npy` image.
fn npy_image(path: &std::path::Path) -> RgbImage {
    let image = tch::Tensor::read_npy(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let size = image.size();
    let rgb: Vec<u8> = Vec::try_from(image.flatten(0, -1)).expect("uint8 image");
    RgbImage::new(size[1] as u32, size[0] as u32, rgb).expect("image")
}

/// `n` square images of random bytes (the arithmetic does not depend on pixel values).
fn random_images(n: usize, size: u32, seed: u64) -> Vec<RgbImage> {
    let mut seed = 0x9e3779b97f4a7c15u64 ^ seed;
    (0..n)
        .map(|_| {
            let rgb = (0..size * size * 3)
                .map(|_| {
                    seed ^= seed << 13;
                    seed ^= seed >> 7;
                    seed ^= seed << 17;
                    (seed >> 56) as u8
                })
                .collect();
            RgbImage::new(size, size, rgb).expect("image")
        })
        .collect()
}

/// Where the OFT checkpoint comes with the Python reference's B = 1 prediction (oft_bench.py's
/// `reference/`: primary.npy, wrist.npy, state.npy, normalized.npy, expected.json): the same
/// query here, the normalised chunks compared.
fn compare_oft_with_reference(model: &OftModel, dir: &std::path::Path, unnorm: Option<&str>) -> serde_json::Value {
    let reference = dir.join("reference");
    let Ok(text) = std::fs::read_to_string(reference.join("expected.json")) else {
        return serde_json::Value::Null;
    };
    let expected: serde_json::Value = serde_json::from_str(&text).expect("expected.json");
    let (primary, wrist) = (npy_image(&reference.join("primary.npy")), npy_image(&reference.join("wrist.npy")));
    let state: Vec<f64> =
        Vec::try_from(tch::Tensor::read_npy(reference.join("state.npy")).expect("state.npy")).expect("f64 state");
    let state: [f64; PROPRIO_DIM] = state.try_into().expect("an 8-dim state");
    let instruction = expected["instruction"].as_str().expect("instruction");
    let query = OftQuery { primary: &primary, wrist: &wrist, state, instruction };
    let p = model.predict_chunk(&query, unnorm).unwrap_or_else(|e| panic!("{e}"));
    let ours: Vec<f32> = p.normalized.iter().flatten().copied().collect();
    // oft_bench.py also writes the chunk under eager attention, for an eager pass here
    let file = match model.attention() {
        Attention::Eager if reference.join("normalized_eager.npy").exists() => "normalized_eager.npy",
        _ => "normalized.npy",
    };
    let theirs: Vec<f32> =
        Vec::try_from(tch::Tensor::read_npy(reference.join(file)).expect(file).flatten(0, -1)).expect("f32 chunk");
    let max_abs = ours.iter().zip(&theirs).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    let range = theirs.iter().map(|v| v.abs()).fold(0f32, f32::max);
    let summary = serde_json::json!({
        "reference_dtype": expected["dtype"], "reference": file, "attention": format!("{:?}", model.attention()),
        "chunk_max_abs_diff": max_abs, "chunk_range": range,
        "rust_first_action": &ours[..7], "python_first_action": &theirs[..7],
    });
    println!("  vs the Python reference (B=1, two images, one state): {summary}");
    summary
}

/// Where the checkpoint comes with the Python reference's prediction (`reference/expected.json`,
/// `image.npy`, `step_logits.npy`, as openvla_tiny.py and openvla_bench.py write them): the same
/// prediction here, tokens and logits compared.
fn compare_with_reference(model: &OpenVlaModel, dir: &std::path::Path, unnorm: Option<&str>) -> serde_json::Value {
    let reference = dir.join("reference");
    let Ok(text) = std::fs::read_to_string(reference.join("expected.json")) else {
        return serde_json::Value::Null;
    };
    let expected: serde_json::Value = serde_json::from_str(&text).expect("expected.json");
    let image = npy_image(&reference.join("image.npy"));
    let instruction = expected["instruction"].as_str().expect("instruction");
    let p = model.predict_action(&image, instruction, unnorm).unwrap_or_else(|e| panic!("{e}"));
    let tokens: Vec<i64> = expected["tokens"].as_array().expect("tokens").iter().filter_map(|t| t.as_i64()).collect();
    let ref_logits = tch::Tensor::read_npy(reference.join("step_logits.npy")).expect("step_logits.npy");
    let diff = (p.step_logits.to_device(Device::Cpu).to_kind(Kind::Double) - ref_logits.to_kind(Kind::Double)).abs();
    let same = p.tokens.iter().zip(&tokens).filter(|(a, b)| a == b).count();
    let summary = serde_json::json!({
        "reference_dtype": expected["dtype"], "tokens_equal": same, "tokens": tokens.len(),
        "first_step_logits_max_abs_diff": diff.get(0).max().double_value(&[]),
        "logits_max_abs_diff": diff.max().double_value(&[]),
        "logits_range": ref_logits.abs().max().double_value(&[]),
        "rust_tokens": p.tokens, "python_tokens": tokens,
    });
    println!("  vs the Python reference (B=1, one image): {summary}");
    summary
}

/// H100 SXM's dense bf16 tensor-core rate as measured on the device machine (issue 22's yardstick).
const PEAK_TFLOPS: f64 = 790.0;

/// Parameters under each name prefix of the checkpoint's safetensors shards (from their headers:
/// an 8-byte little-endian length, then JSON `{name: {dtype, shape, data_offsets}}`).
fn parameters_by_prefix(dir: &std::path::Path, prefixes: &[&str]) -> Vec<f64> {
    let mut counts = vec![0f64; prefixes.len()];
    let mut shards: Vec<_> = std::fs::read_dir(dir)
        .expect("checkpoint dir")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "safetensors"))
        .collect();
    shards.sort();
    for shard in shards {
        use std::io::Read;
        let mut f = std::fs::File::open(&shard).expect("shard");
        let mut len = [0u8; 8];
        f.read_exact(&mut len).expect("safetensors header length");
        let mut header = vec![0u8; u64::from_le_bytes(len) as usize];
        f.read_exact(&mut header).expect("safetensors header");
        let header: serde_json::Value = serde_json::from_slice(&header).expect("safetensors header json");
        for (name, t) in header.as_object().expect("header object") {
            let Some(shape) = t.get("shape").and_then(|s| s.as_array()) else { continue };
            let n: f64 = shape.iter().filter_map(|d| d.as_f64()).product();
            if let Some(i) = prefixes.iter().position(|p| name.starts_with(p)) {
                counts[i] += n;
            }
        }
    }
    counts
}

/// The floating-point operations one call executes (2 per multiply-add), padding included, from
/// the checkpoint's sizes: the vision towers and projector as 2 × parameters × patches per image
/// (their attention, under 4%, left out); per Llama layer its weights, 2 × parameters per
/// position, plus attention, 4 × hidden × keys per query position; OpenVLA: a prefill of the
/// padded prompts, logits at the last position, then `action_dim − 1` decode steps, each a
/// position per row with logits; OFT: one forward of the padded sequences and the L1 head on 8
/// readouts per row (no logits).
struct FlopModel {
    vision: f64,
    projector: f64,
    layer: f64,
    layers: f64,
    hidden: f64,
    vocab: f64,
    patches: f64,
}

impl FlopModel {
    fn new(dir: &std::path::Path, config: &libero_policies::models::openvla::OpenVlaConfig) -> Self {
        let c = &config.text;
        let (d, kv) = (c.hidden_size as f64, (c.hidden_size / c.num_attention_heads * c.num_key_value_heads) as f64);
        let p = parameters_by_prefix(dir, &["vision_backbone.", "projector."]);
        let side = (config.backbones[0].image_size / 14) as f64;
        FlopModel {
            vision: p[0],
            projector: p[1],
            layer: 2.0 * d * d + 2.0 * d * kv + 3.0 * d * c.intermediate_size as f64,
            layers: c.num_hidden_layers as f64,
            hidden: d,
            vocab: c.vocab_size as f64,
            patches: side * side,
        }
    }

    fn images(&self, n: f64) -> f64 {
        2.0 * n * (self.vision + self.projector) * self.patches
    }

    /// `queries` positions attending to `keys` positions each, per row.
    fn llm(&self, rows: f64, queries: f64, keys: f64) -> f64 {
        rows * self.layers * queries * (2.0 * self.layer + 4.0 * self.hidden * keys)
    }

    fn openvla(&self, prompt_lens: &[usize], action_dim: usize) -> f64 {
        let b = prompt_lens.len() as f64;
        let t0 = self.patches + *prompt_lens.iter().max().unwrap_or(&0) as f64;
        let logits = 2.0 * b * self.hidden * self.vocab;
        let decode: f64 = (1..action_dim).map(|k| self.llm(b, 1.0, t0 + k as f64) + logits).sum();
        self.images(b) + self.llm(b, t0, t0) + logits + decode
    }

    fn oft(&self, prompt_lens: &[usize]) -> f64 {
        let b = prompt_lens.len() as f64;
        // <s>, 2 images' patches, proprio, the rest of the prompt, 56 placeholders, </s>
        let t = 2.0 * self.patches + 1.0 + *prompt_lens.iter().max().unwrap_or(&0) as f64 + 56.0 + 1.0;
        let d = self.hidden;
        let head = 2.0 * b * 8.0 * (7.0 * d * d + 2.0 * d * d);
        self.images(2.0 * b) + self.llm(b, t, t) + head
    }
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn main() {
    let args = parse_args().unwrap_or_else(|e| {
        eprintln!("openvla bench: {e}");
        std::process::exit(2)
    });
    let Some(dir) = args.checkpoint.clone() else {
        println!(
            "openvla bench: needs a checkpoint (--checkpoint DIR or LIBERO_OPENVLA_BENCH_CHECKPOINT); the 7B run is \
             scripts/reference/openvla_bench.py's (see README, 'OpenVLA speed'); skipped"
        );
        return;
    };
    if args.device.is_cuda() && !tch::Cuda::is_available() {
        eprintln!("openvla bench: --device cuda, but libtorch sees no CUDA device (is libtorch_cuda.so loaded?)");
        std::process::exit(2);
    }
    let kind = if args.device.is_cuda() { Kind::BFloat16 } else { Kind::Float };
    let t0 = Instant::now();
    let (openvla, oft) = if args.oft {
        let mut m = OftModel::load_on(&dir, args.device, kind).unwrap_or_else(|e| panic!("{e}"));
        if let Some(a) = args.attention {
            m.set_attention(a);
        }
        (None, Some(m))
    } else {
        let mut m = OpenVlaModel::load_on(&dir, args.device, kind).unwrap_or_else(|e| panic!("{e}"));
        if let Some(a) = args.attention {
            m.set_attention(a);
        }
        (Some(m), None)
    };
    let load_s = t0.elapsed().as_secs_f64();
    let config = openvla.as_ref().map(|m| m.config()).or(oft.as_ref().map(|m| m.config())).expect("a model");
    let unnorm = config.norm_stats.keys().into_iter().next();
    let size = config.backbones[0].image_size as u32;
    let what = if args.oft { "openvla-oft" } else { "openvla" };
    let attention = openvla.as_ref().map(|m| m.attention()).or(oft.as_ref().map(|m| m.attention())).expect("a model");
    println!(
        "{what} bench: {} on {:?} in {kind:?}, {attention:?} attention; loaded in {load_s:.1} s",
        dir.display(),
        args.device
    );
    let agreement = match (&openvla, &oft) {
        (Some(m), _) => compare_with_reference(m, &dir, unnorm.as_deref()),
        (_, Some(m)) => compare_oft_with_reference(m, &dir, unnorm.as_deref()),
        _ => unreachable!(),
    };
    // what one query returns: an action, or OFT's chunk of 8
    let actions_per_query = if args.oft { 8 } else { 1 };
    let flop_model = FlopModel::new(&dir, config);
    let input_ids = |i: usize| match (&openvla, &oft) {
        (Some(m), _) => m.input_ids(INSTRUCTIONS[i % INSTRUCTIONS.len()]).expect("prompt").len(),
        (_, Some(m)) => m.input_ids(INSTRUCTIONS[i % INSTRUCTIONS.len()]).expect("prompt").len(),
        _ => unreachable!(),
    };
    let mut rows = Vec::new();
    for &b in &args.batches {
        let images = random_images(2 * b, size, b as u64);
        let instruction = |i: usize| INSTRUCTIONS[i % INSTRUCTIONS.len()];
        let call: Box<dyn Fn() -> usize + '_> = match (&openvla, &oft) {
            (Some(m), _) => {
                let queries: Vec<(&RgbImage, &str)> = (0..b).map(|i| (&images[i], instruction(i))).collect();
                let unnorm = unnorm.clone();
                Box::new(move || m.predict_actions(&queries, unnorm.as_deref()).unwrap_or_else(|e| panic!("{e}")).len())
            }
            (_, Some(m)) => {
                let queries: Vec<OftQuery> = (0..b)
                    .map(|i| OftQuery {
                        primary: &images[2 * i],
                        wrist: &images[2 * i + 1],
                        state: std::array::from_fn(|d| 0.01 * (i + d) as f64),
                        instruction: instruction(i),
                    })
                    .collect();
                let unnorm = unnorm.clone();
                Box::new(move || m.predict_chunks(&queries, unnorm.as_deref()).unwrap_or_else(|e| panic!("{e}")).len())
            }
            _ => unreachable!(),
        };
        let mut times = Vec::new();
        for i in 0..args.warmup + args.iters {
            let t = Instant::now();
            let answered = call();
            let s = t.elapsed().as_secs_f64();
            assert_eq!(answered, b);
            if i >= args.warmup {
                times.push(s);
            }
        }
        times.sort_by(f64::total_cmp);
        let median = percentile(&times, 0.5);
        let actions = (b * actions_per_query) as f64;
        let prompt_lens: Vec<usize> = (0..b).map(input_ids).collect();
        let flops = if args.oft { flop_model.oft(&prompt_lens) } else { flop_model.openvla(&prompt_lens, 7) };
        let tflops = flops / median / 1e12;
        let row = serde_json::json!({
            "batch": b, "iters": times.len(),
            "call_ms_median": median * 1e3, "call_ms_p90": percentile(&times, 0.9) * 1e3,
            "call_ms_min": times[0] * 1e3,
            "ms_per_query": median * 1e3 / b as f64, "actions_per_s": actions / median,
            "tflop_per_call": flops / 1e12, "tflop_per_s": tflops, "fraction_of_peak": tflops / PEAK_TFLOPS,
        });
        println!(
            "  B={b:>3}: {:>8.1} ms per call (p90 {:.1}), {:>7.2} ms per query, {:>7.1} actions/s ({actions_per_query} per \
             query); {:.1} GFLOP per call, {tflops:.1} TFLOP/s = {:.1}% of {PEAK_TFLOPS}",
            median * 1e3,
            percentile(&times, 0.9) * 1e3,
            median * 1e3 / b as f64,
            actions / median,
            flops / 1e9,
            100.0 * tflops / PEAK_TFLOPS
        );
        rows.push(row);
    }
    if let Some(out) = &args.json {
        let report = serde_json::json!({
            "implementation": "rust (tch, libtorch)", "model": what, "attention": format!("{attention:?}"), "checkpoint": dir.display().to_string(),
            "device": format!("{:?}", args.device), "dtype": format!("{kind:?}"), "load_s": load_s,
            "reference_agreement": agreement, "results": rows,
        });
        std::fs::write(out, serde_json::to_string_pretty(&report).expect("json")).expect("write --json");
    }
}
