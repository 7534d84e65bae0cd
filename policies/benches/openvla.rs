//! OpenVLA's (or OpenVLA-OFT's) per-query latency and batched throughput, in process on libtorch.
//!
//! ```text
//! cargo bench -p libero-policies --bench openvla -- --checkpoint DIR [--oft] [--batch 1,8,32]
//!     [--iters 10] [--warmup 2] [--device cuda|cpu] [--attention eager|sdpa] [--json OUT.json]
//! ```
//!
//! `--attention` overrides the model's attention implementation (OpenVLA: eager, as its parity
//! reference; OFT: SDPA, as openvla-oft loads it), to time the other one. `--quant int8|int4`
//! stores the linear layers quantised (`models::quant`); the bench then also prints the weights'
//! resident size, and with `--agreement` the tokens of the quantised model against the same
//! checkpoint in the model's dtype on the same inputs (loaded second, after the timings).
//! `--quantize-block N` quantises N weights at a time in every format, in whole rows (at least
//! one; default: int8 in blocks of `quant::INT8_QUANTIZE_BLOCK`, int4 whole layers), for an A/B
//! of the load's peak GPU memory.
//! `--fusion SETS` times the language model with each of the `/`-separated launch-saving kernel
//! sets (`Fusion`: `none`, `all`, or parts joined by `+`: `norm+qkv`) in turn, the model loaded
//! once (default: its own, all on CUDA); for each set but `none` it also reports the tokens and
//! first-step logits against `none` (transformers' operations one by one) on 32 random inputs.
//!
//! `--phases` (OpenVLA) then times each phase of a call at each B with the device synchronised
//! at the phase's end (`models::openvla::PHASES`: the inputs' upload and normalisation, the vision
//! tower, the language model's input, the prefill, the decode steps, the read-back), and the
//! host-side normalisation the device's replaced, checking that both give the same bits.
//!
//! **Serving** (`--serve WORKERS --devices cuda:0,cuda:1 --seconds S`, OpenVLA): the path a run
//! takes, timed without the simulator: WORKERS threads, each a rollout worker's
//! [`BatchedPolicy`] on the shared replicas (one per device, `batching::shared_replicas`), each
//! preparing a 256² camera image with OpenVLA's preprocessing and asking for one action, episode
//! after episode (an episode is `--episode-steps` actions); the actions per second over S seconds
//! after a warm-up, and each replica's forwards. The same command with one device and with two
//! gives the scaling over GPUs.
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

use libero_policies::batching::{BatchedPolicy, shared_replicas};
use libero_policies::models::openvla::oft::{OftModel, OftQuery, PROPRIO_DIM};
use libero_policies::models::openvla::{Attention, Fusion, OpenVlaBatchModel, OpenVlaModel};
use libero_policies::placement::{ModelDevice, Quantization, parse_devices};
use libero_policies::preprocess::RgbImage;
use libero_policies::{CameraImage, CameraImages, Observation, Policy};
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
    quant: Quantization,
    agreement: bool,
    serve: Option<usize>,
    fusions: Vec<Fusion>,
    devices: Vec<ModelDevice>,
    seconds: f64,
    episode_steps: usize,
    phases: bool,
    quantize_block: Option<i64>,
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
        quant: Quantization::None,
        agreement: false,
        serve: None,
        fusions: vec![],
        devices: vec![ModelDevice::Cuda(0)],
        seconds: 60.0,
        episode_steps: 220,
        phases: false,
        quantize_block: None,
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
            "--quant" => a.quant = value()?.parse()?,
            "--agreement" => a.agreement = true,
            "--quantize-block" => {
                a.quantize_block = Some(
                    value()?
                        .parse()
                        .ok()
                        .filter(|&n: &i64| n >= 1)
                        .ok_or("--quantize-block: a number of weights >= 1")?,
                )
            }
            "--phases" => a.phases = true,
            "--fusion" => {
                a.fusions = value()?
                    .split('/')
                    .map(str::parse)
                    .collect::<Result<_, _>>()
                    .map_err(|e| format!("--fusion: {e}"))?
            }
            "--serve" => a.serve = Some(value()?.parse().map_err(|e| format!("--serve: {e}"))?),
            "--devices" => a.devices = parse_devices(&value()?)?,
            "--seconds" => a.seconds = value()?.parse().map_err(|e| format!("--seconds: {e}"))?,
            "--episode-steps" => {
                a.episode_steps = value()?.parse().ok().filter(|&n: &usize| n >= 1).ok_or("--episode-steps >= 1")?
            }
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

/// The serving path's throughput (see the module doc): `workers` threads through the shared
/// replicas on `args.devices`, `args.seconds` timed after a warm-up of a tenth of that.
fn serve(args: &Args, dir: &std::path::Path, workers: usize) -> serde_json::Value {
    let unnorm = libero_policies::models::openvla::OpenVlaConfig::load(dir)
        .expect("config")
        .norm_stats
        .keys()
        .into_iter()
        .next();
    let t0 = Instant::now();
    let devices = args.devices.clone();
    let replicas = shared_replicas("bench", devices.len(), |i| {
        let model = OpenVlaBatchModel::load(dir, unnorm.clone(), Some(devices[i]), args.quant)?;
        Ok((model, workers, std::time::Duration::from_millis(20)))
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let load_s = t0.elapsed().as_secs_f64();
    println!(
        "openvla serve: {} replica(s) on {:?}, {:?} weights, loaded in {load_s:.1} s",
        devices.len(),
        devices,
        args.quant
    );
    let warmup = std::time::Duration::from_secs_f64(args.seconds / 10.0);
    let timed = std::time::Duration::from_secs_f64(args.seconds);
    let start = Instant::now() + warmup;
    let end = start + timed;
    let counts: Vec<usize> = std::thread::scope(|scope| {
        let threads: Vec<_> = (0..workers)
            .map(|w| {
                let replicas = replicas.clone();
                let steps = args.episode_steps;
                scope.spawn(move || {
                    let image = random_images(1, 256, 1000 + w as u64).remove(0);
                    let camera = CameraImage { width: 256, height: 256, rgb: image.rgb.clone() };
                    let obs = Observation {
                        images: Some(CameraImages { agentview: camera, wrist: CameraImage::default() }),
                        ..Default::default()
                    };
                    let mut policy = BatchedPolicy::on_replicas(replicas, "openvla");
                    let mut counted = 0;
                    'episodes: for episode in 0.. {
                        policy.reset(INSTRUCTIONS[(w + episode) % INSTRUCTIONS.len()], episode as u64);
                        for _ in 0..steps {
                            policy.act(&obs).unwrap_or_else(|e| panic!("{e}"));
                            let now = Instant::now();
                            if now >= end {
                                break 'episodes;
                            }
                            if now >= start {
                                counted += 1;
                            }
                        }
                        policy.end_episode();
                    }
                    policy.end_episode();
                    counted
                })
            })
            .collect();
        threads.into_iter().map(|t| t.join().expect("worker")).collect()
    });
    let actions: usize = counts.iter().sum();
    let per_s = actions as f64 / args.seconds;
    let stats = replicas.stats();
    let replica_rows: Vec<serde_json::Value> = stats
        .iter()
        .zip(&devices)
        .map(|(s, d)| serde_json::json!({"device": d.to_string(), "forwards": s.batches.len(), "summary": s.summary()}))
        .collect();
    println!("  {workers} workers: {actions} actions in {:.0} s = {per_s:.1} actions/s", args.seconds);
    for r in &replica_rows {
        println!("  {}: {}", r["device"], r["summary"]);
    }
    serde_json::json!({
        "mode": "serve", "workers": workers, "devices": devices.iter().map(|d| d.to_string()).collect::<Vec<_>>(),
        "quant": args.quant.to_string(), "seconds": args.seconds, "episode_steps": args.episode_steps,
        "load_s": load_s, "actions": actions, "actions_per_s": per_s, "replicas": replica_rows,
    })
}

/// The action tokens of `quantized` against the same checkpoint in `kind`, loaded now, on
/// `images` with every instruction: how many of the 7 tokens are equal, and the first step's
/// logits' largest difference against their range.
fn token_agreement(
    quantized: &OpenVlaModel,
    dir: &std::path::Path,
    device: Device,
    kind: Kind,
    unnorm: Option<&str>,
    images: &[RgbImage],
) -> serde_json::Value {
    let reference = OpenVlaModel::load_on(dir, device, kind).unwrap_or_else(|e| panic!("{e}"));
    let queries = queries_of(images);
    let summary = agreement(&predict_all(quantized, &queries, unnorm), &predict_all(&reference, &queries, unnorm));
    println!("  tokens vs the unquantised model on {} inputs: {summary}", queries.len());
    summary
}

/// `fusion` against transformers' operations one by one (`Fusion::NONE`), on the same model and
/// inputs: the tokens and first-step logits of both, in batches of 8 (the preallocated cache) and,
/// on the first 8 inputs, one query a call (`torch.cat`'s cache; a B = 1 forward's own paths).
fn fusion_agreement(
    model: &mut OpenVlaModel,
    fusion: Fusion,
    unnorm: Option<&str>,
    images: &[RgbImage],
) -> serde_json::Value {
    let (queries, before) = (queries_of(images), model.fusion());
    let one_by_one = |model: &OpenVlaModel| -> Vec<Prediction> {
        queries[..8.min(queries.len())]
            .iter()
            .flat_map(|q| predict_all(model, std::slice::from_ref(q), unnorm))
            .collect()
    };
    model.set_fusion(fusion);
    let (fused, fused_alone) = (predict_all(model, &queries, unnorm), one_by_one(model));
    model.set_fusion(Fusion::NONE);
    let (plain, plain_alone) = (predict_all(model, &queries, unnorm), one_by_one(model));
    model.set_fusion(before);
    let (batched, alone) = (agreement(&fused, &plain), agreement(&fused_alone, &plain_alone));
    println!("  fusion {fusion} vs none on {} inputs: {batched}; one query a call: {alone}", queries.len());
    serde_json::json!({"batches_of_8": batched, "one_query_a_call": alone})
}

fn queries_of(images: &[RgbImage]) -> Vec<(&RgbImage, &'static str)> {
    images.iter().enumerate().map(|(i, im)| (im, INSTRUCTIONS[i % INSTRUCTIONS.len()])).collect()
}

type Prediction = libero_policies::models::openvla::OpenVlaPrediction;

fn predict_all(model: &OpenVlaModel, queries: &[(&RgbImage, &str)], unnorm: Option<&str>) -> Vec<Prediction> {
    queries.chunks(8).flat_map(|chunk| model.predict_actions(chunk, unnorm).unwrap_or_else(|e| panic!("{e}"))).collect()
}

/// Tokens equal (all and per action) and the largest first-step logit difference of `ours`
/// against `theirs`, the same queries in the same order.
fn agreement(ours: &[Prediction], theirs: &[Prediction]) -> serde_json::Value {
    let (mut equal, mut total, mut all_equal, mut max_diff, mut range) = (0, 0, 0, 0f64, 0f64);
    for (q, r) in ours.iter().zip(theirs) {
        let same = q.tokens.iter().zip(&r.tokens).filter(|(a, b)| a == b).count();
        equal += same;
        total += r.tokens.len();
        all_equal += usize::from(same == r.tokens.len());
        let first = |p: &Prediction| p.step_logits.get(0).to_device(Device::Cpu).to_kind(Kind::Double);
        max_diff = max_diff.max((first(q) - first(r)).abs().max().double_value(&[]));
        range = range.max(first(r).abs().max().double_value(&[]));
    }
    serde_json::json!({
        "inputs": theirs.len(), "tokens_equal": equal, "tokens": total, "actions_all_equal": all_equal,
        "first_step_logits_max_abs_diff": max_diff, "first_step_logits_range": range,
    })
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// The processor's normalisation as the host computed it before `pixel_values_of` (f32 on the CPU,
/// one image at a time, each uploaded): its time, and the device's values checked against it.
fn host_pixel_values(m: &OpenVlaModel, images: &[&RgbImage]) -> tch::Tensor {
    let config = m.config();
    let size = config.backbones[0].image_size;
    let parts: Vec<tch::Tensor> = images
        .iter()
        .map(|image| {
            let x = tch::Tensor::from_slice(&image.rgb).view([size, size, 3]).permute([2, 0, 1]).to_kind(Kind::Float)
                / 255.0;
            let per_backbone: Vec<tch::Tensor> = config
                .backbones
                .iter()
                .map(|b| {
                    let mean = tch::Tensor::from_slice(&b.mean.map(|v| v as f32)).view([3, 1, 1]);
                    let std = tch::Tensor::from_slice(&b.std.map(|v| v as f32)).view([3, 1, 1]);
                    (&x - mean) / std
                })
                .collect();
            tch::Tensor::cat(&per_backbone, 0).unsqueeze(0).to_device(m.device())
        })
        .collect();
    tch::Tensor::cat(&parts, 0)
}

/// `--phases`: each phase's median over `iters` calls of B queries, the device synchronised at
/// each phase's end (so the phases add up to a slower call than the unsynchronised one).
fn phases(m: &OpenVlaModel, b: usize, size: u32, args: &Args, unnorm: Option<&str>) -> serde_json::Value {
    use libero_policies::models::openvla::PHASES;
    let images = random_images(b, size, 3 + b as u64);
    let queries: Vec<(&RgbImage, &str)> = (0..b).map(|i| (&images[i], INSTRUCTIONS[i % INSTRUCTIONS.len()])).collect();
    let sync = || {
        if let Device::Cuda(i) = args.device {
            tch::Cuda::synchronize(i as i64)
        }
    };
    let mut per_phase: Vec<Vec<f64>> = vec![Vec::new(); PHASES.len() + 1];
    let mut host = Vec::new();
    let refs: Vec<&RgbImage> = images.iter().collect();
    for i in 0..args.warmup + args.iters {
        sync();
        let t = Instant::now();
        let mut last = t;
        let mut k = 0;
        m.predict_actions_marked(&queries, unnorm, &mut |name| {
            sync();
            assert_eq!(name, PHASES[k], "the phases come in PHASES' order");
            let now = Instant::now();
            if i >= args.warmup {
                per_phase[k].push((now - last).as_secs_f64());
            }
            (last, k) = (now, k + 1);
        })
        .unwrap_or_else(|e| panic!("{e}"));
        sync();
        if i >= args.warmup {
            per_phase[PHASES.len()].push(last.elapsed().as_secs_f64());
        }
        let t = Instant::now();
        let on_host = host_pixel_values(m, &refs);
        sync();
        host.push(t.elapsed().as_secs_f64());
        if i == 0 {
            let on_device = m.pixel_values_of(&refs).expect("pixel values").to_kind(Kind::Float);
            let host_kind = on_host.to_kind(m.kind()).to_kind(Kind::Float);
            assert!(
                on_device.equal(&host_kind),
                "the device's pixel values differ from the host's: max |d| = {}",
                (&on_device - &host_kind).abs().max().double_value(&[])
            );
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        percentile(v, 0.5) * 1e3
    };
    let names: Vec<&str> = PHASES.iter().copied().chain(["results"]).collect();
    let ms: Vec<f64> = per_phase.iter_mut().map(median).collect();
    let host_ms = median(&mut host);
    let line: Vec<String> = names.iter().zip(&ms).map(|(n, t)| format!("{n} {t:.1}")).collect();
    println!(
        "  phases B={b:>3} (ms, synchronised): {}; sum {:.1}; the host's normalisation it replaced {host_ms:.1}",
        line.join(", "),
        ms.iter().sum::<f64>()
    );
    let mut row = serde_json::Map::new();
    row.insert("batch".into(), b.into());
    for (n, t) in names.iter().zip(&ms) {
        row.insert(format!("{n}_ms"), (*t).into());
    }
    row.insert("host_normalisation_ms".into(), host_ms.into());
    row.into()
}

fn main() {
    // what `pipeline run` does: libtorch's CUDA backend beside the CPU libraries, before any tch call
    libero_policies::cuda_backend::load();
    // what `pipeline run` does, so the bench times the attention kernels runs use
    libero_policies::placement::keep_cudnn_attention_last();
    let args = parse_args().unwrap_or_else(|e| {
        eprintln!("openvla bench: {e}");
        std::process::exit(2)
    });
    libero_policies::models::quant::override_quantize_block(args.quantize_block);
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
    if let Some(workers) = args.serve {
        let report = serve(&args, &dir, workers);
        if let Some(out) = &args.json {
            std::fs::write(out, serde_json::to_string_pretty(&report).expect("json")).expect("write --json");
        }
        return;
    }
    let kind = if args.device.is_cuda() { Kind::BFloat16 } else { Kind::Float };
    let t0 = Instant::now();
    let (mut openvla, mut oft) = if args.oft {
        let mut m = OftModel::load_quantized(&dir, args.device, kind, args.quant).unwrap_or_else(|e| panic!("{e}"));
        if let Some(a) = args.attention {
            m.set_attention(a);
        }
        (None, Some(m))
    } else {
        let mut m = OpenVlaModel::load_quantized(&dir, args.device, kind, args.quant).unwrap_or_else(|e| panic!("{e}"));
        if let Some(a) = args.attention {
            m.set_attention(a);
        }
        (Some(m), None)
    };
    let load_s = t0.elapsed().as_secs_f64();
    let tinygemm_check = (args.quant == Quantization::Int4 && args.device.is_cuda()).then(|| {
        let worst = libero_policies::models::quant::tinygemm_self_check(args.device);
        println!(
            "  int4: tinygemm's product vs the dequantised weight's (1, 8, 64 rows): max |d| / max |y| = {worst:.2e}"
        );
        worst
    });
    // our CUDA kernels against libtorch's operators (OpenVLA on CUDA)
    let kernel_check = match openvla.as_ref().filter(|_| args.device.is_cuda()).map(|m| m.kernels()) {
        Some(Ok(kernels)) => {
            let check = libero_policies::models::openvla::kernels::self_check(kernels, args.device);
            println!("  our kernels vs libtorch's operators (max bf16 ulps, fraction bit-equal): {check}");
            check
        }
        Some(Err(why)) => {
            println!("  our kernels: none ({why}); the fusions that need them use libtorch's operators");
            serde_json::json!({"unavailable": why})
        }
        None => serde_json::Value::Null,
    };
    let config = openvla.as_ref().map(|m| m.config()).or(oft.as_ref().map(|m| m.config())).expect("a model");
    let unnorm = config.norm_stats.keys().into_iter().next();
    let size = config.backbones[0].image_size as u32;
    let what = if args.oft { "openvla-oft" } else { "openvla" };
    let attention = openvla.as_ref().map(|m| m.attention()).or(oft.as_ref().map(|m| m.attention())).expect("a model");
    let default_fusion = openvla.as_ref().map(|m| m.fusion()).or(oft.as_ref().map(|m| m.fusion())).expect("a model");
    println!(
        "{what} bench: {} on {:?} in {kind:?}, {attention:?} attention, {:?} weights; loaded in {load_s:.1} s",
        dir.display(),
        args.device,
        args.quant
    );
    let reference_agreement = match (&openvla, &oft) {
        (Some(m), _) => compare_with_reference(m, &dir, unnorm.as_deref()),
        (_, Some(m)) => compare_oft_with_reference(m, &dir, unnorm.as_deref()),
        _ => unreachable!(),
    };
    // what one query returns: an action, or OFT's chunk of 8
    let actions_per_query = if args.oft { 8 } else { 1 };
    let flop_model = FlopModel::new(&dir, config);
    let prompt_lens_per_instruction: Vec<usize> = (0..INSTRUCTIONS.len())
        .map(|i| match (&openvla, &oft) {
            (Some(m), _) => m.input_ids(INSTRUCTIONS[i % INSTRUCTIONS.len()]).expect("prompt").len(),
            (_, Some(m)) => m.input_ids(INSTRUCTIONS[i % INSTRUCTIONS.len()]).expect("prompt").len(),
            _ => unreachable!(),
        })
        .collect();
    let mut rows = Vec::new();
    let mut fusion_agreements = Vec::new();
    let fusions = if args.fusions.is_empty() { vec![default_fusion] } else { args.fusions.clone() };
    for &fusion in &fusions {
        if let Some(m) = openvla.as_mut() {
            m.set_fusion(fusion);
        }
        if let Some(m) = oft.as_mut() {
            m.set_fusion(fusion);
        }
        println!("  fusion {fusion}:");
        for &b in &args.batches {
            let images = random_images(2 * b, size, b as u64);
            let instruction = |i: usize| INSTRUCTIONS[i % INSTRUCTIONS.len()];
            let call: Box<dyn Fn() -> usize + '_> = match (&openvla, &oft) {
                (Some(m), _) => {
                    let queries: Vec<(&RgbImage, &str)> = (0..b).map(|i| (&images[i], instruction(i))).collect();
                    let unnorm = unnorm.clone();
                    Box::new(move || {
                        m.predict_actions(&queries, unnorm.as_deref()).unwrap_or_else(|e| panic!("{e}")).len()
                    })
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
                    Box::new(move || {
                        m.predict_chunks(&queries, unnorm.as_deref()).unwrap_or_else(|e| panic!("{e}")).len()
                    })
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
            let prompt_lens: Vec<usize> = (0..b).map(|i| prompt_lens_per_instruction[i % INSTRUCTIONS.len()]).collect();
            let flops = if args.oft { flop_model.oft(&prompt_lens) } else { flop_model.openvla(&prompt_lens, 7) };
            let tflops = flops / median / 1e12;
            let row = serde_json::json!({
                "fusion": fusion.to_string(), "batch": b, "iters": times.len(),
                "call_ms_median": median * 1e3, "call_ms_p90": percentile(&times, 0.9) * 1e3,
                "call_ms_min": times[0] * 1e3,
                "ms_per_query": median * 1e3 / b as f64, "actions_per_s": actions / median,
                "tflop_per_call": flops / 1e12, "tflop_per_s": tflops, "fraction_of_peak": tflops / PEAK_TFLOPS,
            });
            println!(
                "  B={b:>3}: {:>8.1} ms per call (min {:.1}, p90 {:.1}), {:>7.2} ms per query, {:>7.1} actions/s ({actions_per_query} per \
                 query); {:.1} GFLOP per call, {tflops:.1} TFLOP/s = {:.1}% of {PEAK_TFLOPS}",
                median * 1e3,
                times[0] * 1e3,
                percentile(&times, 0.9) * 1e3,
                median * 1e3 / b as f64,
                actions / median,
                flops / 1e9,
                100.0 * tflops / PEAK_TFLOPS
            );
            rows.push(row);
        }
        // against transformers' operations one by one (OpenVLA on CUDA); for `none`, the same
        // operations in batches of 8 against each query alone: how far bf16 rounding alone moves
        // this checkpoint's tokens (its noise floor)
        // (only when asked: the memory of a B = 1 run must be B = 1's)
        if let Some(m) = openvla.as_mut().filter(|_| args.device.is_cuda() && !args.fusions.is_empty()) {
            let images = random_images(32, size, 11);
            let summary = if fusion == Fusion::NONE {
                let queries = queries_of(&images);
                let alone: Vec<Prediction> =
                    queries.iter().flat_map(|q| predict_all(m, std::slice::from_ref(q), unnorm.as_deref())).collect();
                let s = agreement(&predict_all(m, &queries, unnorm.as_deref()), &alone);
                println!("  none, batches of 8 vs each query alone on {} inputs (the noise floor): {s}", queries.len());
                s
            } else {
                fusion_agreement(m, fusion, unnorm.as_deref(), &images)
            };
            fusion_agreements.push(serde_json::json!({"fusion": fusion.to_string(), "agreement": summary}));
        }
    }
    let phase_rows: Vec<serde_json::Value> = match (&openvla, args.phases) {
        (Some(m), true) => args.batches.iter().map(|&b| phases(m, b, size, &args, unnorm.as_deref())).collect(),
        _ => Vec::new(),
    };
    // after the timings: the unquantised model then shares the device
    let quant_agreement = match (&openvla, args.agreement && args.quant != Quantization::None) {
        (Some(m), true) => token_agreement(m, &dir, args.device, kind, unnorm.as_deref(), &random_images(32, size, 7)),
        _ => serde_json::Value::Null,
    };
    if let Some(out) = &args.json {
        let report = serde_json::json!({
            "implementation": "rust (tch, libtorch)", "model": what, "attention": format!("{attention:?}"), "checkpoint": dir.display().to_string(),
            "device": format!("{:?}", args.device), "dtype": format!("{kind:?}"), "quant": args.quant.to_string(),
            "quantize_block": args.quantize_block, "load_s": load_s, "reference_agreement": reference_agreement, "quant_agreement": quant_agreement,
            "fusion_agreement": fusion_agreements, "kernel_check": kernel_check,
            "tinygemm_vs_dequantised": tinygemm_check, "results": rows, "phases": phase_rows,
        });
        std::fs::write(out, serde_json::to_string_pretty(&report).expect("json")).expect("write --json");
    }
}
