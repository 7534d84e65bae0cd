//! The Llama-2 language model as transformers' `LlamaForCausalLM` computes it: RMSNorm in f32,
//! rotary embeddings on the `rotate_half` layout of the HF weights, grouped-query attention when
//! `num_key_value_heads < num_attention_heads`, a SiLU-gated MLP, no biases, and a key/value cache
//! for greedy decoding; and [`Llama::forward_full`], one bidirectional forward of whole sequences
//! (OpenVLA-OFT). The attention is transformers' eager or SDPA implementation ([`Attention`]),
//! whichever the model's own loading code picks, so that bf16 results follow its reference.

use super::OpenVlaError;
use super::config::LlamaConfig;
use super::kernels::Kernels;
use super::weights::Weights;
use crate::models::quant::Linear;
use tch::{Device, Kind, Tensor};

/// One decoder layer. The query, key and value projections are one matrix (their weights stacked
/// by output at load time), and so are the gate and up projections: one matmul where
/// transformers runs three or two, the same products per output up to the order of the GEMM's
/// sums. The decode steps of a small batch are bound by kernel launches, not by the GPU's
/// arithmetic, so each launch saved counts.
struct Layer {
    input_norm: Tensor,
    /// `[(heads + 2 · kv_heads) · head_dim, hidden]`: q, then k, then v.
    qkv: Linear,
    o: Linear,
    post_norm: Tensor,
    /// `[2 · intermediate, hidden]`: gate, then up.
    gate_up: Linear,
    down: Linear,
}

/// Most rows (positions × sequences) of a forward for which [`Fusion::qkv`] and [`Fusion::gate_up`]
/// stack their projections: at B = 1 and 8 the stacked GEMMs measured as fast or faster (B = 1:
/// 70.6 ms a call with q/k/v stacked, 97.3 without), at B = 64 slower.
pub const FUSED_PROJECTION_MAX_ROWS: i64 = 8;

/// Most sequences of a decode step (one position each) for which [`Fusion::qkv`] stacks q, k and
/// v when the cache is preallocated ([`Fusion::static_cache`]): cuBLAS's one GEMM of 64 rows × 12288
/// took 0.042 ms on the H100, its three of 4096 0.091 ms (`data/benchmarks/gpu-static-cache-h100-2026-11-27`).
pub const FUSED_QKV_DECODE_MAX_ROWS: i64 = 64;

/// Fewest sequences of a generation whose KV cache is preallocated ([`Fusion::static_cache`]):
/// on the H100 it made a call of 8 sequences 124 ms instead of 146 and one of 64 647 ms instead of
/// 701, but one sequence 96 ms instead of 67, where the copies `torch.cat` saves are small and
/// the attention over a view of the buffer costs more than over a tensor of its own.
pub const STATIC_CACHE_MIN_ROWS: i64 = 8;

/// Fewer, larger kernels where transformers runs several: the decode steps of a small batch are
/// bound by kernel launches on the GPU, not by its arithmetic. Each is a switch of its own so that
/// the bench can measure what each buys (`policies/benches/openvla.rs --fusion`). Off, the forward
/// is transformers' operations one by one (separate GEMMs on the stacked weights' row blocks,
/// which are the original matrices), what its reference computes; on, products are the same up
/// to the order of sums and roundings, so logits move within bf16 rounding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fusion {
    /// torch's fused RMSNorm kernel (f32 inside, one rounding to the dtype as transformers rounds)
    /// and one multiply by the weight, instead of seven kernels. CUDA only: the CPU keeps
    /// transformers' operations, on which the parity tests compare.
    pub norm: bool,
    /// One GEMM for q, k and v, and the rotary embedding once over the queries and keys, where a
    /// forward has at most `FUSED_PROJECTION_MAX_ROWS` (8) rows (positions × sequences): the decode
    /// steps of a small batch, bound by launches. Larger forwards keep three GEMMs on the row
    /// blocks: fused in every forward, OpenVLA-7B took 892 ms a call at B = 64 instead of 776, and
    /// fused in the decode steps only, still 818 instead of 707
    /// (`data/benchmarks/gpu-fusion-h100-2026-11-26`). Dense weights only: a quantised layer
    /// converts its whole weight per call, so one stacked product saves little time, and its
    /// larger temporaries cost a small card ~1 GB at B = 1 (int8 10.6 GB, int4 7.1 GB instead of
    /// 9.7 and 6.0).
    pub qkv: bool,
    /// One GEMM for the MLP's gate and up projections, for as many rows as `qkv`.
    pub gate_up: bool,
    /// The rotary embedding's `x·cos + rotate_half(x)·sin` as a multiply and a fused multiply-add
    /// (one rounding fewer than transformers').
    pub rotary_fma: bool,
    /// Keys and values written in place into buffers preallocated for the whole generation
    /// (`Llama::new_cache_with_capacity`), the attention reading a view of the filled part,
    /// instead of transformers' `torch.cat` of the cache at every decode step, which copies every
    /// layer's keys and values (B = 64: 0.33 ms a layer and step with the copy, 0.15 without).
    /// The same values in the same order: a layout change, not an arithmetic one.
    pub static_cache: bool,
    /// The rotary embedding of q and k in one kernel of ours ([`super::kernels`]) that reads the
    /// projection's output and writes the queries in the attention's layout and the keys straight
    /// into the KV cache's buffer, instead of five operators and a copy (CUDA and bf16 only; else
    /// `rotary_fma` or transformers' operators).
    pub rotary_kernel: bool,
    /// The residual add and the following RMSNorm with its weight in one kernel of ours, instead of
    /// three operators (CUDA and bf16 only; else `norm` or transformers' operators).
    pub norm_kernel: bool,
    /// `silu(gate) · up` in one kernel of ours instead of two operators (CUDA and bf16 only).
    pub swiglu_kernel: bool,
}

impl Fusion {
    pub const NONE: Fusion = Fusion {
        norm: false,
        qkv: false,
        gate_up: false,
        rotary_fma: false,
        static_cache: false,
        rotary_kernel: false,
        norm_kernel: false,
        swiglu_kernel: false,
    };
    pub const ALL: Fusion = Fusion {
        norm: true,
        qkv: true,
        gate_up: true,
        rotary_fma: true,
        static_cache: true,
        rotary_kernel: true,
        norm_kernel: true,
        swiglu_kernel: true,
    };

    /// Each part's name and switch, in the order they print.
    fn parts(&mut self) -> [(&'static str, &mut bool); 8] {
        [
            ("norm", &mut self.norm),
            ("qkv", &mut self.qkv),
            ("gate_up", &mut self.gate_up),
            ("rotary_fma", &mut self.rotary_fma),
            ("static_cache", &mut self.static_cache),
            ("rotary_kernel", &mut self.rotary_kernel),
            ("norm_kernel", &mut self.norm_kernel),
            ("swiglu_kernel", &mut self.swiglu_kernel),
        ]
    }
}

impl std::fmt::Display for Fusion {
    /// `none`, `all`, or the parts on joined by `+` (`norm+qkv`), as its `FromStr` reads them.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut copy = *self;
        let parts = copy.parts();
        let on: Vec<&str> = parts.iter().filter(|(_, on)| **on).map(|(name, _)| *name).collect();
        match on.len() {
            0 => write!(f, "none"),
            n if n == parts.len() => write!(f, "all"),
            _ => write!(f, "{}", on.join("+")),
        }
    }
}

impl std::str::FromStr for Fusion {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => return Ok(Fusion::NONE),
            "all" => return Ok(Fusion::ALL),
            _ => {}
        }
        let mut f = Fusion::NONE;
        for part in s.split('+') {
            let mut parts = f.parts();
            let names: Vec<&str> = parts.iter().map(|(name, _)| *name).collect();
            match parts.iter_mut().find(|(name, _)| *name == part) {
                Some((_, on)) => **on = true,
                None => {
                    return Err(format!("{part:?} is not a fusion: none, all, or {} joined by +", names.join(", ")));
                }
            }
        }
        Ok(f)
    }
}

pub use crate::placement::Attention;

pub struct Llama {
    cfg: LlamaConfig,
    attention: Attention,
    /// The launch-saving kernels ([`Llama::set_fusion`]): all on by default on CUDA.
    fusion: Fusion,
    embed: Tensor,
    layers: Vec<Layer>,
    norm: Tensor,
    lm_head: Tensor,
    inv_freq: Tensor,
    /// Our kernels for this device ([`Fusion::rotary_kernel`] and the other `_kernel` parts), or
    /// why there are none (not CUDA, or NVRTC missing: those parts then fall back to libtorch's).
    kernels: Result<Kernels, String>,
}

/// Keys and values of the positions seen so far, per layer (`[B, kv_heads, T, head_dim]`), and
/// each row's left padding.
///
/// A batch of prompts of different lengths is left-padded to one length, as transformers pads for
/// generation: a row's first `pad` positions are masked out as keys, and its positions count from
/// its first real token (transformers' `position_ids = cumsum(attention_mask) - 1`), so each row
/// computes what it would alone, up to the order of floating-point sums.
pub struct KvCache {
    kv: Vec<Option<(Tensor, Tensor)>>,
    len: i64,
    /// `[B]` int64 left padding per row; `None` when no row is padded.
    pad: Option<Tensor>,
    /// Positions the per-layer buffers hold ([`Fusion::static_cache`]): `kv` are then
    /// `[B, kv_heads, capacity, head_dim]` buffers of which the first `len` positions are filled.
    capacity: Option<i64>,
}

impl Llama {
    pub fn load(w: &mut Weights, cfg: &LlamaConfig, device: Device) -> Result<Self, OpenVlaError> {
        let p = "language_model.model.";
        let mut layers = Vec::new();
        for i in 0..cfg.num_hidden_layers {
            let name = |s: &str| format!("{p}layers.{i}.{s}.weight");
            layers.push(Layer {
                input_norm: w.take(&name("input_layernorm"))?,
                qkv: w.take_linear_stacked(&[
                    &name("self_attn.q_proj"),
                    &name("self_attn.k_proj"),
                    &name("self_attn.v_proj"),
                ])?,
                o: w.take_linear(&name("self_attn.o_proj"))?,
                post_norm: w.take(&name("post_attention_layernorm"))?,
                gate_up: w.take_linear_stacked(&[&name("mlp.gate_proj"), &name("mlp.up_proj")])?,
                down: w.take_linear(&name("mlp.down_proj"))?,
            });
        }
        let head_dim = cfg.hidden_size / cfg.num_attention_heads;
        // transformers: 1.0 / (base ** (arange(0, dim, 2).float() / dim)), in f32
        let exponent =
            Tensor::arange_start_step(0, head_dim, 2, (Kind::Int64, device)).to_kind(Kind::Float) / head_dim as f64;
        let inv_freq = Tensor::pow_scalar(cfg.rope_theta, &exponent).reciprocal();
        let embed = w.take(&format!("{p}embed_tokens.weight"))?;
        let lm_head = match w.take_opt("language_model.lm_head.weight") {
            Some(h) => h,
            None if cfg.tie_word_embeddings => embed.shallow_clone(),
            None => w.take("language_model.lm_head.weight")?,
        };
        Ok(Llama {
            cfg: cfg.clone(),
            attention: Attention::model_default(false, device.is_cuda()),
            fusion: if device.is_cuda() { Fusion::ALL } else { Fusion::NONE },
            embed,
            layers,
            norm: w.take(&format!("{p}norm.weight"))?,
            lm_head,
            inv_freq,
            kernels: if device.is_cuda() {
                Kernels::load(device).inspect_err(|why| {
                    eprintln!("openvla: our CUDA kernels are unavailable ({why}); libtorch's operators run instead")
                })
            } else {
                Err("a CPU has no CUDA kernels".into())
            },
        })
    }

    /// Our CUDA kernels, or why this model has none.
    pub fn kernels(&self) -> Result<&Kernels, &str> {
        self.kernels.as_ref().map_err(String::as_str)
    }

    /// The attention implementation of the following forwards.
    pub fn set_attention(&mut self, attention: Attention) {
        self.attention = attention;
    }

    pub fn attention(&self) -> Attention {
        self.attention
    }

    /// Which launch-saving kernels the forwards use ([`Fusion`]; all on CUDA by default, none on a CPU).
    pub fn set_fusion(&mut self, fusion: Fusion) {
        self.fusion = fusion;
    }

    pub fn fusion(&self) -> Fusion {
        self.fusion
    }

    /// A cache for rows whose first `left_pad[b]` positions are padding (all zero: no padding).
    pub fn new_cache(&self, left_pad: &[i64]) -> KvCache {
        let device = self.embed.device();
        let pad = left_pad.iter().any(|&p| p > 0).then(|| Tensor::from_slice(left_pad).to_device(device));
        KvCache { kv: (0..self.layers.len()).map(|_| None).collect(), len: 0, pad, capacity: None }
    }

    /// [`Self::new_cache`] for a generation of at most `capacity` positions (prompt and generated
    /// tokens): with [`Fusion::static_cache`] and at least [`STATIC_CACHE_MIN_ROWS`] sequences, its
    /// keys and values go into buffers of that length.
    pub fn new_cache_with_capacity(&self, left_pad: &[i64], capacity: i64) -> KvCache {
        let mut cache = self.new_cache(left_pad);
        let rows = left_pad.len() as i64;
        cache.capacity = (self.fusion.static_cache && rows >= STATIC_CACHE_MIN_ROWS).then_some(capacity);
        cache
    }

    /// `[B, T]` token ids → `[B, T, hidden]`.
    pub fn embed(&self, ids: &Tensor) -> Tensor {
        Tensor::embedding(&self.embed, ids, -1, false, false)
    }

    /// transformers' `LlamaRMSNorm`: `w · (x / rms(x)).to(dtype)`, the normalisation in f32 (with
    /// [`Fusion::norm`] on CUDA, torch's fused kernel).
    fn rms_norm(&self, x: &Tensor, w: &Tensor) -> Tensor {
        let kind = x.kind();
        if self.fusion.norm && x.device().is_cuda() {
            let hidden = *x.size().last().expect("x has a last dim");
            return w * x.rms_norm([hidden], None::<Tensor>, Some(self.cfg.rms_norm_eps));
        }
        let h = x.to_kind(Kind::Float);
        let var = h.pow_tensor_scalar(2).mean_dim(-1, true, Kind::Float);
        let h = &h * (var + self.cfg.rms_norm_eps).rsqrt();
        w * h.to_kind(kind)
    }

    /// The residual step and the RMSNorm after it: `x + delta` (or `x` without a delta) and its
    /// normalisation with `w`, in one kernel of ours with [`Fusion::norm_kernel`].
    // tch's `x += y` is in place (`add_`); this new tensor is built without touching x
    #[allow(clippy::assign_op_pattern)]
    fn add_norm(&self, x: &Tensor, delta: Option<&Tensor>, w: &Tensor) -> (Tensor, Tensor) {
        if let Some(k) = self.own_kernel(self.fusion.norm_kernel, x)
            && x.is_contiguous()
            && delta.is_none_or(Tensor::is_contiguous)
            && Kernels::takes_width(w.size()[0])
        {
            return k.add_rms_norm(x, delta, w, self.cfg.rms_norm_eps);
        }
        let x = match delta {
            Some(d) => x + d,
            None => x.shallow_clone(),
        };
        let h = self.rms_norm(&x, w);
        (x, h)
    }

    /// Our kernels where `part` is on and `x` is a bf16 tensor on their device.
    fn own_kernel(&self, part: bool, x: &Tensor) -> Option<&Kernels> {
        self.kernels.as_ref().ok().filter(|_| part && x.kind() == Kind::BFloat16 && x.device().is_cuda())
    }

    /// Runs `embeds` `[B, T, hidden]` after the cached positions; returns the logits of each row's
    /// last position (`[B, vocab]`, f32).
    pub fn forward(&self, embeds: &Tensor, cache: &mut KvCache) -> Tensor {
        let t = embeds.size()[1];
        let x = self.layers_forward(embeds, cache, true);
        let last = x.narrow(1, t - 1, 1);
        let last = self.rms_norm(&last, &self.norm);
        last.linear(&self.lm_head, None::<Tensor>).to_kind(Kind::Float).view([embeds.size()[0], -1])
    }

    /// One forward of whole sequences with **bidirectional** attention and no cache (OpenVLA-OFT's
    /// parallel decoding): every position attends to every real position of its row; a row's
    /// first `left_pad[b]` positions are padding, masked as keys, and its positions count from its
    /// first real token. Returns the last hidden states after the final RMSNorm (transformers'
    /// `hidden_states[-1]`), `[B, T, hidden]` in the model's dtype.
    pub fn forward_full(&self, embeds: &Tensor, left_pad: &[i64]) -> Tensor {
        let mut cache = self.new_cache(left_pad);
        let x = self.layers_forward(embeds, &mut cache, false);
        self.rms_norm(&x, &self.norm)
    }

    /// The decoder layers on `embeds` after the cached positions (causal, or bidirectional among
    /// the real positions), the cache extended; the output before the final norm.
    // tch's `x += y` is in place (`add_`); these new tensors are built without touching their inputs
    #[allow(clippy::assign_op_pattern)]
    fn layers_forward(&self, embeds: &Tensor, cache: &mut KvCache, causal: bool) -> Tensor {
        let (b, t) = (embeds.size()[0], embeds.size()[1]);
        let device = embeds.device();
        let (nh, nkv) = (self.cfg.num_attention_heads, self.cfg.num_key_value_heads);
        let hd = self.cfg.hidden_size / nh;
        let total = cache.len + t;
        // positions `[B, T]`: from each row's first real token (padding positions clamp to 0)
        let pos = Tensor::arange_start(cache.len, total, (Kind::Int64, device)).unsqueeze(0);
        let pos = match &cache.pad {
            Some(pad) => (pos - pad.unsqueeze(1)).clamp_min(0),
            None => pos.expand([b, t], false),
        }
        .to_kind(Kind::Float);
        let freqs = pos.unsqueeze(-1) * self.inv_freq.view([1, 1, -1]);
        let emb = Tensor::cat(&[&freqs, &freqs], -1).unsqueeze(1);
        let (cos, sin) = (emb.cos().to_kind(embeds.kind()), emb.sin().to_kind(embeds.kind()));
        // `x · cos + rotate_half(x) · sin`
        let rope = |x: &Tensor| {
            let x1 = x.narrow(-1, 0, hd / 2);
            let rotated = Tensor::cat(&[&x.narrow(-1, hd / 2, hd / 2).neg(), &x1], -1);
            if self.fusion.rotary_fma { (x * &cos).addcmul(&rotated, &sin) } else { x * &cos + rotated * &sin }
        };
        // `[B or 1, 1, T, total]`: a later key, or a row's padding, gets torch.finfo(dtype).min as
        // transformers adds it (filled once per position, so a fully masked padding row stays finite)
        let mask = ((causal && t > 1) || cache.pad.is_some()).then(|| {
            let min = match embeds.kind() {
                Kind::BFloat16 => -3.3895313892515355e38,
                Kind::Half => -65504.0,
                Kind::Double => f64::MIN,
                _ => f64::from(f32::MIN),
            };
            let keys = Tensor::arange(total, (Kind::Int64, device));
            let queries = Tensor::arange_start(cache.len, total, (Kind::Int64, device));
            let mut masked = if causal {
                keys.unsqueeze(0).gt_tensor(&queries.unsqueeze(1)).unsqueeze(0)
            } else {
                Tensor::zeros([1, t, total], (Kind::Bool, device))
            };
            if let Some(pad) = &cache.pad {
                masked = masked.logical_or(&keys.view([1, 1, -1]).lt_tensor(&pad.view([-1, 1, 1])));
            }
            Tensor::zeros(masked.size(), (embeds.kind(), device)).masked_fill(&masked, min).unsqueeze(1)
        });
        let mut x = embeds.shallow_clone();
        // the previous layer's MLP output, added to the residual stream with the next norm
        let mut pending: Option<Tensor> = None;
        let rotary_kernel = self.own_kernel(self.fusion.rotary_kernel, embeds).filter(|_| Kernels::takes_head_dim(hd));
        let swiglu_kernel = self
            .own_kernel(self.fusion.swiglu_kernel, embeds)
            .filter(|_| Kernels::takes_width(self.cfg.intermediate_size));
        for (li, l) in self.layers.iter().enumerate() {
            let (x_in, h) = self.add_norm(&x, pending.take().as_ref(), &l.input_norm);
            x = x_in;
            // few rows of dense weights only (see `Fusion::qkv`); a decode step of up to 64
            // sequences when its keys and values go into the preallocated buffers
            let few = b * t <= FUSED_PROJECTION_MAX_ROWS;
            let decode_in_place = t == 1 && b <= FUSED_QKV_DECODE_MAX_ROWS && cache.capacity.is_some();
            let fuse_qkv = self.fusion.qkv && (few || decode_in_place) && l.qkv.is_dense();
            let fuse_gate_up = self.fusion.gate_up && few && l.gate_up.is_dense();
            // the projections as `[B, T, heads, head_dim]` views
            let qkv = fuse_qkv.then(|| l.qkv.forward(&h, None).view([b, t, nh + 2 * nkv, hd]));
            let heads = |start: i64, n: i64| match &qkv {
                Some(qkv) => qkv.narrow(2, start, n),
                None => l.qkv.rows(start * hd, n * hd).forward(&h, None).view([b, t, n, hd]),
            };
            let (q_in, k_in) = (heads(0, nh), heads(nh, nkv));
            let v = heads(nh + nkv, nkv).transpose(1, 2);
            // `[B, heads, T, head_dim]`: the queries rotated; the keys rotated, or left for our
            // kernel to write where they go
            let (q, keys) = match (rotary_kernel, &qkv) {
                (Some(kernel), _) => {
                    let q = Tensor::empty([b, nh, t, hd], (embeds.kind(), device));
                    kernel.rotary(&q_in, &cos, &sin, &q);
                    (q, Keys::Pending(kernel, k_in))
                }
                // the rotation once over the queries and keys
                (None, Some(qkv)) => {
                    let qk = rope(&qkv.narrow(2, 0, nh + nkv).transpose(1, 2));
                    (qk.narrow(1, 0, nh), Keys::Rotated(qk.narrow(1, nh, nkv)))
                }
                (None, None) => (rope(&q_in.transpose(1, 2)), Keys::Rotated(rope(&k_in.transpose(1, 2)))),
            };
            let (k, v) = match (cache.kv[li].take(), cache.capacity) {
                // in place: this forward's positions written into the buffers, a view of the filled part read
                (previous, Some(capacity)) => {
                    assert!(total <= capacity, "the KV cache holds {capacity} positions, the forward needs {total}");
                    let (bk, bv) = previous.unwrap_or_else(|| {
                        let buffer = || Tensor::empty([b, nkv, capacity, hd], (v.kind(), device));
                        (buffer(), buffer())
                    });
                    keys.write_into(&bk.narrow(2, cache.len, t), &cos, &sin);
                    bv.narrow(2, cache.len, t).copy_(&v);
                    let filled = (bk.narrow(2, 0, total), bv.narrow(2, 0, total));
                    cache.kv[li] = Some((bk, bv));
                    filled
                }
                (Some((pk, pv)), None) => {
                    let k = keys.into_tensor(&cos, &sin);
                    let (k, v) = (Tensor::cat(&[&pk, &k], 2), Tensor::cat(&[&pv, &v], 2));
                    cache.kv[li] = Some((k.shallow_clone(), v.shallow_clone()));
                    (k, v)
                }
                (None, None) => {
                    // copies of their own: views would keep the whole projection alive in the cache
                    let k = keys.into_tensor(&cos, &sin);
                    let (k, v) = if fuse_qkv { (k.contiguous(), v.contiguous()) } else { (k, v) };
                    cache.kv[li] = Some((k.shallow_clone(), v.shallow_clone()));
                    (k, v)
                }
            };
            let (k, v) = if nkv < nh {
                (k.repeat_interleave_self_int(nh / nkv, 1, None), v.repeat_interleave_self_int(nh / nkv, 1, None))
            } else {
                (k, v)
            };
            let o = match self.attention {
                Attention::Eager => {
                    let mut att = q.matmul(&k.transpose(2, 3)) / (hd as f64).sqrt();
                    if let Some(m) = &mask {
                        att = att + m;
                    }
                    att.softmax(-1, Kind::Float).to_kind(q.kind()).matmul(&v)
                }
                Attention::Sdpa => {
                    Tensor::scaled_dot_product_attention(&q, &k, &v, mask.as_ref(), 0.0, false, None, false)
                }
            };
            let o = o.transpose(1, 2).reshape([b, t, nh * hd]);
            let (x_mid, h) = self.add_norm(&x, Some(&l.o.forward(&o, None)), &l.post_norm);
            x = x_mid;
            let inter = l.gate_up.size()[0] / 2;
            let (gate, up) = if fuse_gate_up {
                let gate_up = l.gate_up.forward(&h, None);
                (gate_up.narrow(-1, 0, inter), gate_up.narrow(-1, inter, inter))
            } else {
                (l.gate_up.rows(0, inter).forward(&h, None), l.gate_up.rows(inter, inter).forward(&h, None))
            };
            let g = match swiglu_kernel {
                Some(kernel) => kernel.swiglu(&gate, &up),
                None => gate.silu() * up,
            };
            pending = Some(l.down.forward(&g, None));
        }
        if let Some(delta) = pending {
            x = x + delta;
        }
        cache.len = total;
        x
    }
}

/// A layer's rotated keys `[B, kv_heads, T, head_dim]`: computed by libtorch's operators, or the
/// projection's `[B, T, kv_heads, head_dim]` for our kernel to rotate into wherever they go (the
/// KV cache's buffer, without a copy).
enum Keys<'a> {
    Rotated(Tensor),
    Pending(&'a Kernels, Tensor),
}

impl Keys<'_> {
    fn write_into(self, dest: &Tensor, cos: &Tensor, sin: &Tensor) {
        match self {
            // `copy_` takes `&mut self` but writes the shared storage a view shows
            Keys::Rotated(k) => dest.shallow_clone().copy_(&k),
            Keys::Pending(kernel, k) => kernel.rotary(&k, cos, sin, dest),
        }
    }

    fn into_tensor(self, cos: &Tensor, sin: &Tensor) -> Tensor {
        match self {
            Keys::Rotated(k) => k,
            Keys::Pending(kernel, k) => {
                let size = k.size();
                let out = Tensor::empty([size[0], size[2], size[1], size[3]], (k.kind(), k.device()));
                kernel.rotary(&k, cos, sin, &out);
                out
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fusion_parts_print_and_parse_back() {
        for f in [
            Fusion::NONE,
            Fusion::ALL,
            Fusion { static_cache: true, ..Fusion::NONE },
            Fusion { qkv: false, ..Fusion::ALL },
            Fusion { rotary_kernel: true, swiglu_kernel: true, ..Fusion::NONE },
        ] {
            assert_eq!(f.to_string().parse::<Fusion>().unwrap(), f, "{f}");
        }
        assert_eq!(Fusion::ALL.to_string(), "all");
        assert_eq!(
            "norm+static_cache".parse::<Fusion>().unwrap(),
            Fusion { norm: true, static_cache: true, ..Fusion::NONE }
        );
        assert!("norm+cache".parse::<Fusion>().unwrap_err().contains("static_cache"));
        assert_eq!(
            "rotary_kernel+norm_kernel".parse::<Fusion>().unwrap(),
            Fusion { rotary_kernel: true, norm_kernel: true, ..Fusion::NONE }
        );
    }
}
