//! CUDA kernels of our own for the language model's elementwise work, compiled when the model
//! loads with NVRTC (through `cudarc`, which opens `libcuda` and `libnvrtc` at run time).
//!
//! Why: at B = 64 the prefill's GEMMs run at 730–800 TFLOP/s, but between them libtorch's operators
//! pass over every activation several times: the rotary embedding of q and k (`narrow`, `neg`,
//! `cat`, a multiply and a multiply-add, then a copy into the KV cache) took 1.7 ms a layer, the
//! residual add with the RMSNorm and its weight 0.3 ms each, `silu(g) · u` 0.65 ms
//! (`data/benchmarks/gpu-static-cache-h100-2026-11-27`). Each kernel here reads its inputs once
//! and writes its outputs once. None is in libtorch's operator set, and a CUDA compiler at build
//! time would tie the binary to one toolkit; NVRTC comes with the CUDA wheels torch needs anyway.
//!
//! The arithmetic is transformers' in bf16 (f32 inside, the same roundings to bf16 where its
//! operators round), so the values differ from libtorch's only by the order of the RMSNorm's sum
//! and by contraction into fused multiply-adds; [`self_check`] measures that against libtorch's
//! operators on the device (the bench prints it).
//!
//! The kernels run on the device's legacy default stream, the one libtorch's operators use
//! unless a caller sets another (this crate never does), so they are ordered with them.

use cudarc::driver::{CudaContext, CudaFunction, CudaStream, LaunchConfig, PushKernelArg};
use std::sync::Arc;
use tch::{Device, Kind, Tensor};

const SOURCE: &str = r#"
typedef unsigned short bf16;

__device__ __forceinline__ float ld(const bf16* p) { return __uint_as_float(((unsigned int)*p) << 16); }

// round to nearest even, as torch's BFloat16 conversion (NaN stays NaN)
__device__ __forceinline__ bf16 to_bf16(float f) {
    unsigned int u = __float_as_uint(f);
    if ((u & 0x7fffffffu) > 0x7f800000u) return (bf16)((u >> 16) | 0x40u);
    u += 0x7fffu + ((u >> 16) & 1u);
    return (bf16)(u >> 16);
}

__device__ __forceinline__ float round_bf16(float f) { return __uint_as_float(((unsigned int)to_bf16(f)) << 16); }

// 2 bf16 per 32-bit word, the first in the low half (little-endian)
__device__ __forceinline__ void unpack2(unsigned int w, float* f) {
    f[0] = __uint_as_float(w << 16);
    f[1] = __uint_as_float(w & 0xffff0000u);
}
__device__ __forceinline__ unsigned int pack2(const float* f) {
    return (unsigned int)to_bf16(f[0]) | ((unsigned int)to_bf16(f[1]) << 16);
}
__device__ __forceinline__ void unpack4(uint2 v, float* f) { unpack2(v.x, f); unpack2(v.y, f + 2); }
__device__ __forceinline__ uint2 pack4(const float* f) { return make_uint2(pack2(f), pack2(f + 2)); }
__device__ __forceinline__ void unpack8(uint4 v, float* f) {
    unpack2(v.x, f); unpack2(v.y, f + 2); unpack2(v.z, f + 4); unpack2(v.w, f + 6);
}
__device__ __forceinline__ uint4 pack8(const float* f) {
    return make_uint4(pack2(f), pack2(f + 2), pack2(f + 4), pack2(f + 6));
}

// x: [B, T, H, D] (strides xb, xt, xh, 1), cos and sin: [B or 1, T, D] (strides cb (0 when shared),
// ct, 1), out: [B, H, T, D] (strides ob, oh, ot, 1). out = x cos + rotate_half(x) sin, where
// rotate_half(x) = (-x[D/2:], x[:D/2]); as libtorch's `(x * cos).addcmul(rotated, sin)`: the
// product x cos rounded to bf16, the multiply-add in f32, one rounding. A block per position
// (b, t); a thread per 4 pairs (i, i + D/2) of a head (D/2 a multiple of 4, 8-byte aligned rows).
extern "C" __global__ void rotary(const bf16* x, const bf16* cos, const bf16* sin, bf16* out,
        int T, int H, int D, long long xb, long long xt, long long xh, long long cb, long long ct,
        long long ob, long long oh, long long ot) {
    int b = blockIdx.x / T, t = blockIdx.x % T;
    int half = D / 2, quads = half / 4;
    const bf16* cr = cos + b * cb + t * ct;
    const bf16* sr = sin + b * cb + t * ct;
    for (int p = threadIdx.x; p < H * quads; p += blockDim.x) {
        int h = p / quads, i = (p % quads) * 4;
        const bf16* xr = x + b * xb + t * xt + h * xh;
        bf16* o = out + b * ob + h * oh + t * ot;
        float x1[4], x2[4], c1[4], c2[4], s1[4], s2[4], o1[4], o2[4];
        unpack4(*(const uint2*)(xr + i), x1);
        unpack4(*(const uint2*)(xr + i + half), x2);
        unpack4(*(const uint2*)(cr + i), c1);
        unpack4(*(const uint2*)(cr + i + half), c2);
        unpack4(*(const uint2*)(sr + i), s1);
        unpack4(*(const uint2*)(sr + i + half), s2);
        for (int k = 0; k < 4; k++) {
            o1[k] = round_bf16(x1[k] * c1[k]) + (-x2[k]) * s1[k];
            o2[k] = round_bf16(x2[k] * c2[k]) + x1[k] * s2[k];
        }
        *(uint2*)(o + i) = pack4(o1);
        *(uint2*)(o + i + half) = pack4(o2);
    }
}

// One block per row of n elements (x, delta, h, x_out: [rows, n] contiguous, 16-byte aligned rows;
// w: [n]; n a multiple of 8): x_out = x + delta rounded to bf16 (when delta is given; else x_out
// is x and not written), h = w * bf16(x_out * rsqrt(mean(x_out^2) + eps)) rounded to bf16, the mean
// in f32. 8 values per load.
extern "C" __global__ void add_rms_norm(const bf16* x, const bf16* delta, const bf16* w, bf16* h,
        bf16* x_out, int n, float eps) {
    __shared__ float partial[32];
    size_t row = blockIdx.x;
    int nv = n / 8;
    const uint4* xr = (const uint4*)(x + row * n);
    uint4* hr = (uint4*)(h + row * n);
    const uint4* wr = (const uint4*)w;
    float sum = 0.f;
    if (delta) {
        const uint4* dr = (const uint4*)(delta + row * n);
        uint4* xo = (uint4*)(x_out + row * n);
        for (int i = threadIdx.x; i < nv; i += blockDim.x) {
            float a[8], d[8];
            unpack8(xr[i], a);
            unpack8(dr[i], d);
            for (int k = 0; k < 8; k++) {
                a[k] = round_bf16(a[k] + d[k]);
                sum += a[k] * a[k];
            }
            xo[i] = pack8(a);
        }
        xr = xo;
    } else {
        for (int i = threadIdx.x; i < nv; i += blockDim.x) {
            float a[8];
            unpack8(xr[i], a);
            for (int k = 0; k < 8; k++) sum += a[k] * a[k];
        }
    }
    for (int o = 16; o > 0; o >>= 1) sum += __shfl_xor_sync(0xffffffffu, sum, o);
    int warp = threadIdx.x / 32, lane = threadIdx.x % 32;
    if (lane == 0) partial[warp] = sum;
    __syncthreads();
    if (warp == 0) {
        sum = lane < (blockDim.x + 31) / 32 ? partial[lane] : 0.f;
        for (int o = 16; o > 0; o >>= 1) sum += __shfl_xor_sync(0xffffffffu, sum, o);
        if (lane == 0) partial[0] = sum;
    }
    __syncthreads();
    float rstd = rsqrtf(partial[0] / (float)n + eps);
    for (int i = threadIdx.x; i < nv; i += blockDim.x) {
        float a[8], ww[8], o[8];
        unpack8(xr[i], a);
        unpack8(wr[i], ww);
        for (int k = 0; k < 8; k++) o[k] = ww[k] * round_bf16(a[k] * rstd);
        hr[i] = pack8(o);
    }
}

// out[r, j] = bf16(bf16(silu(g[r, j])) * u[r, j]); g and u rows at strides gs and us, out
// [rows, n] contiguous; n, gs and us multiples of 8, rows 16-byte aligned: libtorch's
// `g.silu() * u`. A block row per row r, 8 values per thread.
extern "C" __global__ void swiglu(const bf16* g, const bf16* u, bf16* out, int n, long long gs, long long us) {
    size_t r = blockIdx.x;
    int j = blockIdx.y * blockDim.x + threadIdx.x;
    if (j >= n / 8) return;
    float gv[8], uv[8], o[8];
    unpack8(((const uint4*)(g + r * gs))[j], gv);
    unpack8(((const uint4*)(u + r * us))[j], uv);
    for (int k = 0; k < 8; k++) o[k] = round_bf16(gv[k] / (1.0f + expf(-gv[k]))) * uv[k];
    ((uint4*)(out + r * n))[j] = pack8(o);
}
"#;

/// The compiled kernels of one device.
pub struct Kernels {
    stream: Arc<CudaStream>,
    rotary: CudaFunction,
    add_rms_norm: CudaFunction,
    swiglu: CudaFunction,
}

/// Threads per block of the rotary and SwiGLU kernels.
const THREADS: u32 = 256;

fn ptr(t: &Tensor) -> u64 {
    t.data_ptr() as u64
}

impl Kernels {
    /// Compiles the kernels for `device` (CUDA only). An error says what is missing: the driver
    /// library, NVRTC (`libnvrtc.so.13`, in the `nvidia-cuda-nvrtc` wheel torch installs), or a
    /// compile failure.
    pub fn load(device: Device) -> Result<Kernels, String> {
        let Device::Cuda(ordinal) = device else {
            return Err(format!("{device:?} is not a CUDA device"));
        };
        // cudarc panics where a library is missing: ask first
        if !unsafe { cudarc::driver::sys::is_culib_present() } {
            return Err("libcuda (the NVIDIA driver's library) cannot be opened".into());
        }
        if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
            return Err("libnvrtc.so.13 cannot be opened: put CUDA 13's NVRTC (torch's nvidia/cu13/lib) on \
                        LD_LIBRARY_PATH"
                .into());
        }
        let ctx = CudaContext::new(ordinal).map_err(|e| format!("cuda:{ordinal}: {e}"))?;
        // the kernels take no cudarc allocations, so there is nothing for its events to track
        unsafe { ctx.disable_event_tracking() };
        let (major, minor) = ctx.compute_capability().map_err(|e| format!("cuda:{ordinal}: {e}"))?;
        let options = cudarc::nvrtc::CompileOptions {
            options: vec![format!("--gpu-architecture=compute_{major}{minor}")],
            ..Default::default()
        };
        let ptx = cudarc::nvrtc::compile_ptx_with_opts(SOURCE, options).map_err(|e| format!("NVRTC: {e}"))?;
        let module = ctx.load_module(ptx).map_err(|e| format!("loading the kernels' PTX: {e}"))?;
        let function = |name: &str| module.load_function(name).map_err(|e| format!("kernel {name}: {e}"));
        Ok(Kernels {
            stream: ctx.default_stream(),
            rotary: function("rotary")?,
            add_rms_norm: function("add_rms_norm")?,
            swiglu: function("swiglu")?,
        })
    }

    /// Writes the rotary embedding of `x` (`[B, T, H, D]`, any strides but a unit last one) into
    /// `out` (`[B, H, T, D]`, the same; a view into the KV cache's buffer, say), with `cos` and `sin`
    /// `[B or 1, 1, T, D]` contiguous. All bf16 on this device; D a multiple of 8 and every row
    /// 8-byte aligned (as [`Kernels::takes_head_dim`] and fresh allocations make them).
    pub fn rotary(&self, x: &Tensor, cos: &Tensor, sin: &Tensor, out: &Tensor) {
        let [b, t, h, d] = x.size()[..] else { panic!("rotary: x is {:?}, not [B, T, H, D]", x.size()) };
        assert_eq!(out.size(), [b, h, t, d], "rotary: out");
        let [cb_, one, ct_, cd] = cos.size()[..] else { panic!("rotary: cos is {:?}", cos.size()) };
        assert!(cos.size() == sin.size() && one == 1 && ct_ == t && cd == d && (cb_ == 1 || cb_ == b));
        assert!(cos.is_contiguous() && sin.is_contiguous(), "rotary: cos and sin contiguous");
        assert!(Self::takes_head_dim(d), "rotary: head_dim {d} is not a multiple of 8");
        for a in [x, cos, sin, out] {
            assert_eq!(a.kind(), Kind::BFloat16, "rotary: bf16 only");
            assert_aligned("rotary", a, 4);
        }
        let (xs, os) = (x.stride(), out.stride());
        let cb = if cb_ == 1 { 0 } else { t * d };
        let dims = [t as i32, h as i32, d as i32];
        let strides = [xs[0], xs[1], xs[2], cb, d, os[0], os[1], os[2]];
        let ptrs = [ptr(x), ptr(cos), ptr(sin), ptr(out)];
        let mut launch = self.stream.launch_builder(&self.rotary);
        for p in &ptrs {
            launch.arg(p);
        }
        for a in &dims {
            launch.arg(a);
        }
        for a in &strides {
            launch.arg(a);
        }
        let cfg = LaunchConfig { grid_dim: ((b * t) as u32, 1, 1), block_dim: (THREADS, 1, 1), shared_mem_bytes: 0 };
        // SAFETY: the pointers are live bf16 tensors of the shapes, strides and alignment checked
        // above, and the kernel reads and writes only within them
        unsafe { launch.launch(cfg) }.expect("launching the rotary kernel");
    }

    /// Whether [`Kernels::rotary`] takes heads of `head_dim` (4 pairs a thread).
    pub fn takes_head_dim(head_dim: i64) -> bool {
        head_dim % 8 == 0
    }

    /// Whether [`Kernels::add_rms_norm`] and [`Kernels::swiglu`] take rows of `n` (8 values a load).
    pub fn takes_width(n: i64) -> bool {
        n % 8 == 0
    }

    /// transformers' residual step and RMSNorm in one pass: with `delta`, `x + delta` (returned),
    /// and `w · rms_norm(x + delta)`; without, `x` and `w · rms_norm(x)`. `x` and `delta`
    /// `[..., n]` contiguous, `w` `[n]`, all bf16, n a multiple of 8.
    pub fn add_rms_norm(&self, x: &Tensor, delta: Option<&Tensor>, w: &Tensor, eps: f64) -> (Tensor, Tensor) {
        let n = *x.size().last().expect("x has a last dim");
        assert!(x.is_contiguous() && w.size() == [n] && w.is_contiguous(), "add_rms_norm: shapes");
        assert!(Self::takes_width(n), "add_rms_norm: width {n} is not a multiple of 8");
        let rows = x.numel() as i64 / n;
        let x_out = match delta {
            Some(dl) => {
                assert!(dl.size() == x.size() && dl.is_contiguous(), "add_rms_norm: delta");
                assert_aligned("add_rms_norm", dl, 8);
                x.empty_like()
            }
            None => x.shallow_clone(),
        };
        let h = x.empty_like();
        for a in [x, w, &h, &x_out] {
            assert_eq!(a.kind(), Kind::BFloat16, "add_rms_norm: bf16 only");
            assert_aligned("add_rms_norm", a, 8);
        }
        let ptrs = [ptr(x), delta.map_or(0, ptr), ptr(w), ptr(&h), ptr(&x_out)];
        let (n32, eps) = (n as i32, eps as f32);
        let mut launch = self.stream.launch_builder(&self.add_rms_norm);
        for p in &ptrs {
            launch.arg(p);
        }
        launch.arg(&n32).arg(&eps);
        // a thread per 8 values, up to 1024
        let threads = ((n as u64 / 8).div_ceil(32) * 32).clamp(32, 1024) as u32;
        let cfg = LaunchConfig { grid_dim: (rows as u32, 1, 1), block_dim: (threads, 1, 1), shared_mem_bytes: 0 };
        // SAFETY: x, delta, h and x_out hold rows × n contiguous, aligned bf16 values, w n; one block a row
        unsafe { launch.launch(cfg) }.expect("launching the RMSNorm kernel");
        (x_out, h)
    }

    /// `silu(g) · u` of `g` and `u` `[..., n]` (rows at any stride, unit last stride; the halves
    /// of a stacked gate/up product, say), a new contiguous tensor; bf16, n a multiple of 8.
    pub fn swiglu(&self, g: &Tensor, u: &Tensor) -> Tensor {
        let size = g.size();
        assert_eq!(size, u.size(), "swiglu: g and u");
        let n = *size.last().expect("g has a last dim");
        assert!(Self::takes_width(n), "swiglu: width {n} is not a multiple of 8");
        let rows = g.numel() as i64 / n;
        let row_stride = |a: &Tensor| {
            let s = a.stride();
            // rows evenly spaced: every dim but the last collapses into one
            for k in 0..s.len().saturating_sub(2) {
                assert_eq!(s[k], s[k + 1] * a.size()[k + 1], "swiglu: rows evenly spaced");
            }
            if s.len() >= 2 { s[s.len() - 2] } else { n }
        };
        let (gs, us) = (row_stride(g), row_stride(u));
        let out = Tensor::empty(&size[..], (Kind::BFloat16, g.device()));
        for a in [g, u, &out] {
            assert_eq!(a.kind(), Kind::BFloat16, "swiglu: bf16 only");
            assert_aligned("swiglu", a, 8);
        }
        let ptrs = [ptr(g), ptr(u), ptr(&out)];
        let n32 = n as i32;
        let mut launch = self.stream.launch_builder(&self.swiglu);
        for p in &ptrs {
            launch.arg(p);
        }
        launch.arg(&n32).arg(&gs).arg(&us);
        let cfg = LaunchConfig {
            grid_dim: (rows as u32, (n as u32 / 8).div_ceil(THREADS), 1),
            block_dim: (THREADS, 1, 1),
            shared_mem_bytes: 0,
        };
        // SAFETY: g and u hold rows rows of n aligned bf16 at the checked strides, out rows × n
        unsafe { launch.launch(cfg) }.expect("launching the SwiGLU kernel");
        out
    }
}

/// The kernels load `elems` bf16 at a time: the data pointer and every stride but the last must
/// be multiples of that.
fn assert_aligned(kernel: &str, t: &Tensor, elems: i64) {
    let stride = t.stride();
    assert!(
        ptr(t).is_multiple_of(2 * elems as u64) && stride[..stride.len() - 1].iter().all(|s| s % elems == 0),
        "{kernel}: a tensor not aligned to {elems} values (pointer {:#x}, strides {stride:?})",
        ptr(t)
    );
}

/// Each kernel against libtorch's operators on random bf16 inputs of OpenVLA's shapes on
/// `device`: the largest difference in bf16 ulps of the result's magnitude and the fraction of
/// values that are bit-equal, per kernel (the bench prints them).
pub fn self_check(kernels: &Kernels, device: Device) -> serde_json::Value {
    let _guard = tch::no_grad_guard();
    let opts = (Kind::BFloat16, device);
    let compare = |ours: &Tensor, theirs: &Tensor| {
        let (a, b) = (ours.to_kind(Kind::Float), theirs.to_kind(Kind::Float));
        let diff = (&a - &b).abs();
        // one bf16 ulp at the reference's magnitude: 2^(exponent - 7)
        let ulp = b.abs().clamp_min(1e-30).log2().floor().exp2() / 128.0;
        serde_json::json!({
            "max_ulps": (&diff / ulp).max().double_value(&[]),
            "bit_equal": a.eq_tensor(&b).to_kind(Kind::Float).mean(Kind::Float).double_value(&[]),
        })
    };
    let (b, t, h, d) = (4i64, 37i64, 32i64, 128i64);
    // q as the projection leaves it, cos/sin as the forward makes them
    let x = Tensor::randn([b, t, h, d], opts);
    let angles = Tensor::rand([b, 1, t, d], (Kind::Float, device)) * 100.0;
    let (cos, sin) = (angles.cos().to_kind(Kind::BFloat16), angles.sin().to_kind(Kind::BFloat16));
    let out = Tensor::empty([b, h, t, d], opts);
    kernels.rotary(&x, &cos, &sin, &out);
    let xt = x.transpose(1, 2);
    let rotated = Tensor::cat(&[&xt.narrow(-1, d / 2, d / 2).neg(), &xt.narrow(-1, 0, d / 2)], -1);
    let rotary = compare(&out, &(&xt * &cos).addcmul(&rotated, &sin));

    let (x, delta, w) =
        (Tensor::randn([b, t, 4096], opts), Tensor::randn([b, t, 4096], opts), Tensor::randn([4096], opts));
    let (x_out, normed) = kernels.add_rms_norm(&x, Some(&delta), &w, 1e-6);
    let sum = &x + &delta;
    let norm = compare(&normed, &(&w * sum.rms_norm([4096], None::<Tensor>, Some(1e-6))));
    let add = compare(&x_out, &sum);

    let gate_up = Tensor::randn([b, t, 2 * 1000], opts);
    let (g, u) = (gate_up.narrow(-1, 0, 1000), gate_up.narrow(-1, 1000, 1000));
    let swiglu = compare(&kernels.swiglu(&g, &u), &(g.silu() * &u));
    serde_json::json!({"rotary": rotary, "residual_add": add, "rms_norm": norm, "swiglu": swiglu})
}
