//! A linear layer's weight, dense or quantised weight-only ([`Quantization`]), and its product.
//!
//! Why these kernels (measured on the H100 with torch 2.11, `data/benchmarks/gpu-forward-h100-2026-11-25`):
//! libtorch's int8 weight-only matmul (`_weight_int8pack_mm`) is not a tensor-core kernel, 4–8×
//! slower than bf16 at one row and 40–60× at 32, so int8 here converts the weight to the
//! activations' dtype per call and runs the bf16 matmul, scaling its output per channel
//! (`x · (q·s)ᵀ = (x · qᵀ) · s`): the weight is read at 1 byte, written and read again at 2, for
//! half the resident memory. torch's int4 kernel (tinygemm, `_weight_int4pack_mm`) is 1.6–2.2×
//! *faster* than bf16 at one row and ~2× slower at 32, so int4 uses it for few rows (the decode
//! steps of a small batch) and dequantises for many (a prefill, the vision towers). Its packed
//! layout is opaque, so the resident weight is plain nibbles, repacked per call (a pass over
//! half a byte per weight).
//!
//! The quantisation itself runs where the weight is (the GPU at load time), in f32; int8's a block
//! of rows at a time ([`INT8_QUANTIZE_BLOCK`]).

use crate::placement::Quantization;
use std::sync::atomic::{AtomicI64, Ordering};
use tch::{Device, Kind, Tensor};

/// Inputs per int4 group: 128 (the common choice; bitsandbytes' NF4 blocks, OpenVLA's 4-bit path,
/// are 64) where the layer's input width allows, else 64 or 32 (tinygemm takes 32–256); a width
/// none of them divides is stored int8.
pub const INT4_GROUPS: [i64; 3] = [128, 64, 32];
/// Most rows for which int4 takes tinygemm on CUDA rather than dequantising: every decode step of
/// a batch of up to 64 episodes (tinygemm is 1.6–2.2x faster than bf16 at one row and ~2x slower
/// at 32, `scripts/bench/weight_only_kernels.py`, still far cheaper than dequantising the weight
/// for a few rows; with 16 the decode steps of a 32-episode batch dequantised and took 1.3 s per
/// call instead of bf16's 0.43, `data/benchmarks/gpu-quant-h100-2026-11-26`).
pub const INT4_TINYGEMM_MAX_ROWS: i64 = 64;

/// Most weights int8 quantises at once: a block of a layer's rows (levels are per row or per group
/// of a row's inputs, so blocks quantise as the whole layer does). The f32 temporaries are a few
/// copies of the block (64 MB each at this size) rather than of the layer (180 MB for each of
/// Llama-2-7B's MLP projections), and the caching allocator keeps what the load's largest
/// temporaries took. OpenVLA-7B int8's peak GPU memory at one episode went from 9,707 MiB (whole
/// layers, 2026-11-26) to 9,229 MiB in blocks (2026-11-27, another machine of the same kind).
/// int4 quantises whole layers: in blocks its peak went from 5,989 to 6,461 MiB in the same two
/// measurements (`data/benchmarks/gpu-two-h100-one-gl-thread-2026-11-27`). An A/B on one machine
/// (the bench's `--quantize-block`, [`override_quantize_block`]; whole, blocks, blocks, whole)
/// confirmed both: int8 9,229 MiB in blocks against 9,621 whole, int4 5,893 whole against 6,461
/// in blocks, each repeat identical (`data/benchmarks/gpu-quant-blocks-h100-2026-11-28`).
pub const INT8_QUANTIZE_BLOCK: i64 = 1 << 24;

/// Weights every format quantises at once where set (> 0), instead of each format's own
/// ([`INT8_QUANTIZE_BLOCK`], whole layers for int4): for the bench's A/B of the peak memory of
/// one format both ways on one machine. Blocks quantise as the whole layer does (a unit test), so
/// only the memory and the load time can differ.
static QUANTIZE_BLOCK_OVERRIDE: AtomicI64 = AtomicI64::new(0);

/// Quantise `block` weights at a time in every format from now on (`None`: each format's own).
pub fn override_quantize_block(block: Option<i64>) {
    QUANTIZE_BLOCK_OVERRIDE.store(block.filter(|&b| b > 0).unwrap_or(0), Ordering::SeqCst);
}

/// The weight of a linear layer `[out, in]` (no bias: callers add theirs).
pub enum Linear {
    Dense(Tensor),
    /// `q` int8 `[out, in]`, `scale` `[out]` in the model's dtype.
    Int8 {
        q: Tensor,
        scale: Tensor,
    },
    /// `nibbles` uint8 `[out, in / 2]` (input 2j in the high nibble, 2j + 1 in the low one: the
    /// order tinygemm's `_convert_weight_to_int4pack` reads); `scale_and_zero` `[in / group, out, 2]`
    /// in the model's dtype, each group's scale and zero in the layout tinygemm takes, made once
    /// here rather than stacked per call (two kernels per layer per decode step).
    Int4 {
        nibbles: Tensor,
        scale_and_zero: Tensor,
        group: i64,
    },
}

impl Linear {
    /// `weight` `[out, in]` (already on its device, in the model's dtype) stored as `quant` asks.
    pub fn new(weight: Tensor, quant: Quantization) -> Linear {
        let block = match (QUANTIZE_BLOCK_OVERRIDE.load(Ordering::SeqCst), quant) {
            (set, _) if set > 0 => set,
            (_, Quantization::Int8) => INT8_QUANTIZE_BLOCK,
            _ => i64::MAX,
        };
        Self::quantized_in_blocks(weight, quant, block)
    }

    /// `weight` stored as `quant` asks, quantising `block` weights (whole rows, at least one) at a
    /// time.
    fn quantized_in_blocks(weight: Tensor, quant: Quantization, block: i64) -> Linear {
        let quantize: fn(&Tensor) -> Linear = match quant {
            Quantization::None => return Linear::Dense(weight),
            Quantization::Int8 => int8,
            Quantization::Int4 => |w| match INT4_GROUPS.into_iter().find(|g| w.size()[1] % g == 0) {
                Some(group) => int4(w, group),
                None => int8(w),
            },
        };
        let (out, inputs) = (weight.size()[0], weight.size()[1]);
        let rows = (block / inputs).max(1);
        if rows >= out {
            return quantize(&weight);
        }
        let blocks =
            (0..out).step_by(rows as usize).map(|start| quantize(&weight.narrow(0, start, rows.min(out - start))));
        Linear::stack(blocks.collect()).expect("the blocks of one layer are stored alike")
    }

    /// `x · wᵀ (+ bias)`, `x` `[..., in]` in the model's dtype.
    pub fn forward(&self, x: &Tensor, bias: Option<&Tensor>) -> Tensor {
        let y = match self {
            Linear::Dense(w) => return x.linear(w, bias),
            Linear::Int8 { q, scale } => x.linear(&q.to_kind(x.kind()), None::<Tensor>) * scale,
            Linear::Int4 { nibbles, scale_and_zero, group } => {
                let (out, inputs) = (nibbles.size()[0], nibbles.size()[1] * 2);
                let rows = x.numel() as i64 / inputs;
                if x.device().is_cuda() && x.kind() == Kind::BFloat16 && rows <= INT4_TINYGEMM_MAX_ROWS && out % 8 == 0
                {
                    // tinygemm's k-tiles of 16 inputs, 2, 4 or 8 of them innermost: as many as the width allows
                    let inner_k_tiles = [8, 4, 2].into_iter().find(|t| inputs % (16 * t) == 0).unwrap_or(2);
                    let packed = nibbles.internal_convert_weight_to_int4pack(inner_k_tiles);
                    let mut shape = x.size();
                    *shape.last_mut().expect("x has a last dim") = out;
                    x.reshape([rows, inputs])
                        .contiguous()
                        .internal_weight_int4pack_mm(&packed, *group, scale_and_zero)
                        .view(shape.as_slice())
                } else {
                    x.linear(&self.dequantized(x.kind()), None::<Tensor>)
                }
            }
        };
        match bias {
            Some(b) => y + b,
            None => y,
        }
    }

    /// The weight `[out, in]` in `kind`, as the quantised layer multiplies by it.
    pub fn dequantized(&self, kind: Kind) -> Tensor {
        match self {
            Linear::Dense(w) => w.to_kind(kind),
            Linear::Int8 { q, scale } => {
                (q.to_kind(Kind::Float) * scale.to_kind(Kind::Float).unsqueeze(1)).to_kind(kind)
            }
            Linear::Int4 { nibbles, group, .. } => {
                let (scale, zero) = self.int4_scale_and_zero().expect("int4");
                // small copies `[out, in / group]`, so that the product below comes out `[out, in]` in order
                let (scale, zero) = (scale.contiguous(), zero.contiguous());
                // in `kind`, in few passes (a prefill dequantises the whole model): the nibbles
                // apart, then `q · scale + (zero − 8 · scale)` in one fused multiply-add
                let out = nibbles.size()[0];
                let high = nibbles.bitwise_right_shift_tensor_scalar(4);
                let low = nibbles.bitwise_and(15);
                let q = Tensor::stack(&[high, low], -1).view([out, -1, *group]).to_kind(kind);
                let offset = (zero.to_kind(Kind::Float) - scale.to_kind(Kind::Float) * 8.0).to_kind(kind).unsqueeze(-1);
                offset.addcmul(&q, &scale.to_kind(kind).unsqueeze(-1)).view([out, -1])
            }
        }
    }

    /// Layers that read the same input, one after the other by output (`[Σ out, in]`), stored as
    /// they are. They must all be stored alike (dense, int8, or int4 with one group size).
    pub fn stack(parts: Vec<Linear>) -> Result<Linear, String> {
        let cat = |ts: Vec<&Tensor>, dim: i64| Tensor::cat(&ts, dim);
        let first = parts.first().ok_or("no layers to stack")?;
        let stacked = match first {
            Linear::Dense(_) => {
                let ws: Option<Vec<&Tensor>> =
                    parts.iter().map(|p| if let Linear::Dense(w) = p { Some(w) } else { None }).collect();
                ws.map(|ws| Linear::Dense(cat(ws, 0)))
            }
            Linear::Int8 { .. } => {
                let qs: Option<Vec<(&Tensor, &Tensor)>> = parts
                    .iter()
                    .map(|p| if let Linear::Int8 { q, scale } = p { Some((q, scale)) } else { None })
                    .collect();
                qs.map(|qs| Linear::Int8 {
                    q: cat(qs.iter().map(|x| x.0).collect(), 0),
                    scale: cat(qs.iter().map(|x| x.1).collect(), 0),
                })
            }
            Linear::Int4 { group, .. } => {
                let g = *group;
                let qs: Option<Vec<(&Tensor, &Tensor)>> = parts
                    .iter()
                    .map(|p| match p {
                        Linear::Int4 { nibbles, scale_and_zero, group } if *group == g => {
                            Some((nibbles, scale_and_zero))
                        }
                        _ => None,
                    })
                    .collect();
                qs.map(|qs| Linear::Int4 {
                    nibbles: cat(qs.iter().map(|x| x.0).collect(), 0),
                    scale_and_zero: cat(qs.iter().map(|x| x.1).collect(), 1),
                    group: g,
                })
            }
        };
        stacked.ok_or_else(|| "layers stored differently cannot be stacked".to_string())
    }

    /// Output rows `start .. start + len` as a layer of their own: views of this one's weight
    /// (an int4 layer's scales and zeros are copied into tinygemm's contiguous layout).
    pub fn rows(&self, start: i64, len: i64) -> Linear {
        match self {
            Linear::Dense(w) => Linear::Dense(w.narrow(0, start, len)),
            Linear::Int8 { q, scale } => {
                Linear::Int8 { q: q.narrow(0, start, len), scale: scale.narrow(0, start, len) }
            }
            Linear::Int4 { nibbles, scale_and_zero, group } => Linear::Int4 {
                nibbles: nibbles.narrow(0, start, len),
                scale_and_zero: scale_and_zero.narrow(1, start, len).contiguous(),
                group: *group,
            },
        }
    }

    pub fn is_dense(&self) -> bool {
        matches!(self, Linear::Dense(_))
    }

    /// `[out, in]`.
    pub fn size(&self) -> [i64; 2] {
        let s = match self {
            Linear::Dense(w) | Linear::Int8 { q: w, .. } => w.size(),
            Linear::Int4 { nibbles, .. } => vec![nibbles.size()[0], nibbles.size()[1] * 2],
        };
        [s[0], s[1]]
    }

    /// Bytes the layer keeps on its device.
    pub fn resident_bytes(&self) -> i64 {
        let bytes = |t: &Tensor| t.numel() as i64 * t.kind().elt_size_in_bytes() as i64;
        match self {
            Linear::Dense(w) => bytes(w),
            Linear::Int8 { q, scale } => bytes(q) + bytes(scale),
            Linear::Int4 { nibbles, scale_and_zero, .. } => bytes(nibbles) + bytes(scale_and_zero),
        }
    }

    /// An int4 layer's scales and zeros, each `[out, in / group]` (views of `scale_and_zero`).
    pub fn int4_scale_and_zero(&self) -> Option<(Tensor, Tensor)> {
        match self {
            Linear::Int4 { scale_and_zero, .. } => {
                Some((scale_and_zero.select(-1, 0).transpose(0, 1), scale_and_zero.select(-1, 1).transpose(0, 1)))
            }
            _ => None,
        }
    }

    pub fn device(&self) -> Device {
        match self {
            Linear::Dense(w) | Linear::Int8 { q: w, .. } | Linear::Int4 { nibbles: w, .. } => w.device(),
        }
    }
}

/// Per output channel, symmetric, the scale rounded to the model's dtype before the weights are
/// rounded against it (so that `q · scale` is what the product uses).
fn int8(weight: &Tensor) -> Linear {
    tch::no_grad(|| {
        let w = weight.to_kind(Kind::Float);
        let scale = (w.abs().amax([1], false) / 127.0).clamp_min(1e-12).to_kind(weight.kind());
        let q = (w / scale.to_kind(Kind::Float).unsqueeze(1)).round().clamp(-127.0, 127.0).to_kind(Kind::Int8);
        Linear::Int8 { q, scale }
    })
}

/// Groups of `group` inputs, asymmetric: `scale = (max − min) / 15`, `zero = min + 8·scale`
/// (tinygemm's convention, as torchao's int4 weight-only layout computes them), both rounded to
/// the model's dtype before the weights are rounded against them.
fn int4(weight: &Tensor, group: i64) -> Linear {
    tch::no_grad(|| {
        let (out, inputs) = (weight.size()[0], weight.size()[1]);
        let w = weight.to_kind(Kind::Float).view([out, inputs / group, group]);
        let (lo, hi) = (w.amin([-1], false), w.amax([-1], false));
        let scale = ((hi - &lo) / 15.0).clamp_min(1e-12).to_kind(weight.kind());
        let zero = (lo + scale.to_kind(Kind::Float) * 8.0).to_kind(weight.kind());
        let q = ((w - zero.to_kind(Kind::Float).unsqueeze(-1)) / scale.to_kind(Kind::Float).unsqueeze(-1) + 8.0)
            .round()
            .clamp(0.0, 15.0)
            .to_kind(Kind::Uint8)
            .view([out, inputs / 2, 2]);
        let nibbles = q.select(-1, 0).bitwise_left_shift_tensor_scalar(4).bitwise_or_tensor(&q.select(-1, 1));
        let scale_and_zero = Tensor::stack(&[scale, zero], -1).transpose(0, 1).contiguous();
        Linear::Int4 { nibbles: nibbles.contiguous(), scale_and_zero, group }
    })
}

/// tinygemm's product against the dequantised weight's, both in bf16 on `device` (a CUDA device),
/// at 1, 8 and 64 rows of a `[4096, 4096]` and a `[11008, 4096]` layer: the largest
/// `max |Δ| / max |y|`. Checks the nibble order and the scale/zero layout handed to the kernel.
pub fn tinygemm_self_check(device: Device) -> f64 {
    tch::no_grad(|| {
        tch::manual_seed(0);
        let mut worst = 0f64;
        for (out, inputs) in [(4096, 4096), (11008, 4096)] {
            let w =
                (Tensor::randn([out, inputs], (Kind::Float, device)) / (inputs as f64).sqrt()).to_kind(Kind::BFloat16);
            let layer = Linear::new(w, Quantization::Int4);
            for rows in [1, 8, 64] {
                let x = Tensor::randn([rows, inputs], (Kind::Float, device)).to_kind(Kind::BFloat16);
                let fast = layer.forward(&x, None).to_kind(Kind::Float);
                let plain = x.linear(&layer.dequantized(Kind::BFloat16), None::<Tensor>).to_kind(Kind::Float);
                let rel = (&fast - &plain).abs().max().double_value(&[]) / plain.abs().max().double_value(&[]);
                worst = worst.max(rel);
            }
        }
        worst
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random(out: i64, inputs: i64, seed: i64) -> Tensor {
        tch::manual_seed(seed);
        Tensor::randn([out, inputs], (Kind::Float, Device::Cpu)) / (inputs as f64).sqrt()
    }

    fn max_abs(t: &Tensor) -> f64 {
        t.abs().max().double_value(&[])
    }

    #[test]
    fn int8_rounds_each_weight_to_its_nearest_level_and_multiplies_by_it() {
        let w = random(48, 256, 0);
        let layer = Linear::new(w.shallow_clone(), Quantization::Int8);
        assert!(matches!(layer, Linear::Int8 { .. }));
        let deq = layer.dequantized(Kind::Float);
        // half a level of each row's scale at most
        let half_level = w.abs().amax([1], true) / 127.0 / 2.0;
        assert!((&deq - &w).abs().le_tensor(&(half_level * 1.0001)).all().int64_value(&[]) == 1);
        // the product is the dequantised weight's product
        let x = random(5, 256, 1);
        let diff = max_abs(&(layer.forward(&x, None) - x.linear(&deq, None::<Tensor>)));
        assert!(diff < 1e-5, "int8 product vs dequantised weight: {diff}");
        assert_eq!(layer.resident_bytes(), 48 * 256 + 48 * 4);
        assert_eq!(layer.size(), [48, 256]);
    }

    #[test]
    fn int4_keeps_every_group_within_half_a_level_and_packs_two_weights_a_byte() {
        let w = random(24, 512, 2);
        let layer = Linear::new(w.shallow_clone(), Quantization::Int4);
        let Linear::Int4 { nibbles, .. } = &layer else { panic!("not int4") };
        let (scale, zero) = layer.int4_scale_and_zero().unwrap();
        assert_eq!(nibbles.size(), [24, 256]);
        assert_eq!(scale.size(), [24, 4]);
        let deq = layer.dequantized(Kind::Float);
        let groups = w.view([24, 4, 128]);
        let half_level = (groups.amax([-1], true) - groups.amin([-1], true)) / 15.0 / 2.0;
        let err = (deq.view([24, 4, 128]) - &groups).abs();
        assert!(err.le_tensor(&(half_level * 1.0001 + 1e-7)).all().int64_value(&[]) == 1, "{}", max_abs(&err));
        // the nibble order: input 0 in the high nibble of byte 0
        let q0 = ((w.double_value(&[0, 0]) - zero.double_value(&[0, 0])) / scale.double_value(&[0, 0]) + 8.0).round();
        assert_eq!(nibbles.int64_value(&[0, 0]) >> 4, q0 as i64);
        let x = random(3, 512, 3);
        let diff = max_abs(
            &(layer.forward(&x, Some(&Tensor::ones([24], (Kind::Float, Device::Cpu))))
                - x.linear(&deq, None::<Tensor>)
                - 1.0),
        );
        assert!(diff < 1e-5, "int4 product vs dequantised weight: {diff}");
    }

    #[test]
    fn a_layer_quantised_in_blocks_of_rows_is_the_layer_quantised_whole() {
        for quant in [Quantization::Int8, Quantization::Int4] {
            let w = random(50, 256, 10);
            let whole = Linear::quantized_in_blocks(w.shallow_clone(), quant, 1 << 20);
            // blocks of 7 rows (the last one 1 row), and of one row
            for block in [7 * 256, 1] {
                let blocks = Linear::quantized_in_blocks(w.shallow_clone(), quant, block);
                assert_eq!(blocks.size(), [50, 256]);
                assert_eq!(blocks.resident_bytes(), whole.resident_bytes(), "{quant:?}");
                let diff = max_abs(&(blocks.dequantized(Kind::Float) - whole.dequantized(Kind::Float)));
                assert_eq!(diff, 0.0, "{quant:?}, block {block}");
            }
        }
    }

    #[test]
    fn stacked_layers_compute_each_part_and_give_their_rows_back() {
        for quant in [Quantization::None, Quantization::Int8, Quantization::Int4] {
            let (a, b) = (random(16, 256, 6), random(40, 256, 7));
            let (la, lb) = (Linear::new(a, quant), Linear::new(b, quant));
            let x = random(3, 256, 8);
            let (ya, yb) = (la.forward(&x, None), lb.forward(&x, None));
            let stacked = Linear::stack(vec![la, lb]).unwrap();
            assert_eq!(stacked.size(), [56, 256]);
            let y = stacked.forward(&x, None);
            assert!(max_abs(&(y.narrow(1, 0, 16) - &ya)) < 1e-5, "{quant:?}");
            assert!(max_abs(&(y.narrow(1, 16, 40) - &yb)) < 1e-5, "{quant:?}");
            assert_eq!(max_abs(&(stacked.rows(16, 40).forward(&x, None) - &yb)), 0.0, "{quant:?}");
        }
        let mixed =
            vec![Linear::new(random(8, 64, 9), Quantization::None), Linear::new(random(8, 64, 9), Quantization::Int8)];
        assert!(Linear::stack(mixed).is_err());
    }

    #[test]
    fn int4_groups_narrow_to_the_input_width_and_fall_back_to_int8() {
        let group = |inputs| match Linear::new(random(8, inputs, 4), Quantization::Int4) {
            Linear::Int4 { group, .. } => Some(group),
            _ => None,
        };
        assert_eq!([group(4096), group(1152), group(64), group(96)], [Some(128), Some(128), Some(64), Some(32)]);
        // SigLIP's MLP output layer takes 4304 inputs (16 x 269)
        assert_eq!(group(4304), None);
        assert!(matches!(Linear::new(random(8, 4304, 4), Quantization::Int4), Linear::Int8 { .. }));
        assert!(matches!(Linear::new(random(8, 64, 5), Quantization::None), Linear::Dense(_)));
    }
}
