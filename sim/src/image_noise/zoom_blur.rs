//! Zoom blur (levels 21–30): the mean of the image and centre crops of it zoomed back to full
//! size, `(x + Σ_z clipped_zoom(x, z)) / (len + 1)`, x in float32 in [0, 1].
//!
//! Bit-exactness follows the reference's types and scipy's C code:
//! - the factors are `np.arange` values (its length and `start + i·delta` fill, [`zoom_factors`]);
//! - `clipped_zoom`: `ch = ceil(h / z)`, crop `[top, top + ch)` on both axes, then
//!   `scipy.ndimage.zoom(crop, (z, z, 1), order=1)` to `round(ch·z)` (half to even), then the
//!   centred `h` of it. scipy maps output k to `k·(ch - 1)/(out - 1)`; a point past `ch - 1` by
//!   rounding is outside for mode `constant` and gives 0; the weights are `1 - f` and
//!   `1 - (1 - f)`; the value is `(((v00·wr0)·wc0 + (v01·wr0)·wc1) + (v10·wr1)·wc0) + (v11·wr1)·wc1`
//!   in float64 (the channel axis adds exact zeros), stored as float32;
//! - the sum over factors, the mean, `clip` and `·255` in float32, then truncation.
//!
//! Speed (severity 7, 41 factors, is ~2.9 ms a 256 px frame on AVX-512, was 4.9): each factor's
//! taps and weights are tabled once per thread and size ([`FactorPlan`]); `z = 1` adds `x`
//! exactly; on AVX-512 each block of 8 output values reads its four taps by permuting 16-value
//! windows of the two source rows in registers, on other CPUs from source rows gathered once per
//! factor. Both keep the reference's per-value operations and order (`paths_agree`).
//!
//! Square images only: the reference crops both axes with the height's bounds and its sum fails
//! to broadcast otherwise.

/// `np.arange(start, stop, step)` per severity, as in `zoom_blur`.
const ARANGES: [(f64, f64, f64); 10] = [
    (1.0, 1.11, 0.01),
    (1.0, 1.16, 0.01),
    (1.0, 1.21, 0.02),
    (1.0, 1.26, 0.02),
    (1.0, 1.31, 0.03),
    (1.0, 1.36, 0.01),
    (1.0, 1.41, 0.01),
    (1.0, 1.46, 0.02),
    (1.0, 1.51, 0.02),
    (1.0, 1.56, 0.03),
];

/// The zoom factors of a severity, as numpy's `arange` makes them: `ceil((stop - start) / step)`
/// values `start + i·delta` with `delta = (start + step) - start` (so severity 1 has 12 factors,
/// 1.11 included).
pub(super) fn zoom_factors(severity: u8) -> Vec<f64> {
    let (start, stop, step) = ARANGES[usize::from(severity) - 1];
    let len = ((stop - start) / step).ceil() as usize;
    let delta = (start + step) - start;
    (0..len).map(|i| start + i as f64 * delta).collect()
}

/// Where one kept output index of `clipped_zoom` reads: two source indices (of the full image)
/// and their weights.
#[derive(Debug, Clone, Copy)]
struct Taps {
    i0: usize,
    i1: usize,
    w0: f64,
    w1: f64,
}

/// One axis of `clipped_zoom(img, z)` on an image of side `h`: for each of the `h` output
/// indices kept after the trim, its taps, or `None` where scipy gives the constant 0.
fn axis_taps(h: usize, z: f64) -> Vec<Option<Taps>> {
    let ch = (h as f64 / z).ceil() as usize;
    let top = (h - ch) / 2;
    let out = (ch as f64 * z).round_ties_even() as usize;
    let step = if out > 1 { (ch - 1) as f64 / (out - 1) as f64 } else { 1.0 };
    let trim = (out - h) / 2;
    (trim..trim + h)
        .map(|k| {
            let cc = k as f64 * step;
            if cc > (ch - 1) as f64 {
                return None;
            }
            let start = cc.floor();
            let w0 = 1.0 - (cc - start);
            let i0 = start as usize;
            // At the last index w1 is exactly 0 and scipy reads a mirrored neighbour: any will do.
            Some(Taps { i0: top + i0, i1: top + (i0 + 1).min(ch - 1), w0, w1: 1.0 - w0 })
        })
        .collect()
}

/// Values of padding after the float64 image: an AVX-512 window reads 16 values from where a
/// row's taps start, past the end of the last row.
const PAD: usize = 16;

/// One zoom factor's resampling at one image size (rows and columns alike: the image is square),
/// computed once per thread and kept (the tables depend on the size and the factor only).
struct FactorPlan {
    /// `z = 1`: every output value is its own pixel with weights 1 and 0, so `t` is `x` exactly
    /// (the other three terms are exact zeros) and the factor adds `x` to the sum.
    identity: bool,
    /// Per output row: the two source rows and their weights, `None` where scipy gives 0.
    rows: Vec<Option<Taps>>,
    /// Per output value (pixel × channel): the column weights, 0 for a constant-0 column (it
    /// adds an exact 0).
    wc0: Vec<f64>,
    wc1: Vec<f64>,
    /// Per output pixel: where its two source pixels start in a source row (`i0·3`, `i1·3`); a
    /// constant-0 column reads its kept neighbour's (weight 0: any finite value adds 0).
    cols: Vec<(usize, usize)>,
    /// The same reads as in-register permutations of 16-value windows, where every window fits.
    #[cfg(target_arch = "x86_64")]
    windows: Option<avx512::Windows>,
}

impl FactorPlan {
    fn new(size: usize, z: f64) -> Self {
        let taps = axis_taps(size, z);
        let identity = taps.iter().enumerate().all(|(k, t)| t.is_some_and(|t| t.i0 == k && t.w0 == 1.0 && t.w1 == 0.0));
        let (mut wc0, mut wc1) = (Vec::with_capacity(size * 3), Vec::with_capacity(size * 3));
        for t in &taps {
            let (a, b) = t.map_or((0.0, 0.0), |t| (t.w0, t.w1));
            wc0.extend([a; 3]);
            wc1.extend([b; 3]);
        }
        // Constant-0 columns lie at the ends; they borrow the nearest kept column's reads, which
        // keeps the reads in order (and windows small).
        let kept: Vec<usize> = taps.iter().flatten().map(|t| t.i0 * 3).collect();
        let kept1: Vec<usize> = taps.iter().flatten().map(|t| t.i1 * 3).collect();
        let first = taps.iter().position(Option::is_some).unwrap_or(0);
        let cols = (0..size)
            .map(|m| {
                let j = m.saturating_sub(first).min(kept.len().saturating_sub(1));
                if kept.is_empty() { (0, 0) } else { (kept[j], kept1[j]) }
            })
            .collect();
        let mut plan = FactorPlan {
            identity,
            rows: taps,
            wc0,
            wc1,
            cols,
            #[cfg(target_arch = "x86_64")]
            windows: None,
        };
        #[cfg(target_arch = "x86_64")]
        {
            plan.windows = avx512::Windows::new(&plan.cols);
        }
        plan
    }
}

/// A severity at one size: its factors' plans.
struct Plan {
    size: usize,
    severity: u8,
    factors: Vec<FactorPlan>,
}

/// Per-thread buffers, reused from frame to frame: the image in float64 (with [`PAD`] zeros
/// after it), the float32 sum, and two gathered source rows.
#[derive(Default)]
struct Buffers {
    x64: Vec<f64>,
    sum: Vec<f32>,
    rows: [Gathered; 2],
}

/// One source row read at the output columns' taps, in float64: `g[m·3 + c]` is channel c of the
/// pixel at column `i0(m)`, `h[..]` at `i1(m)`. Gathering once per source row and zoom factor
/// lets the arithmetic run over contiguous arrays (vectorised), in the same order as scipy's.
/// The path for CPUs without AVX-512.
#[derive(Default)]
struct Gathered {
    source: Option<usize>,
    g: Vec<f64>,
    h: Vec<f64>,
}

impl Gathered {
    /// Each pixel is copied as 4 values (its 3 channels and the next pixel's first, one vector),
    /// in increasing column order, so the 4th lands where the next pixel's copy overwrites it, or
    /// in the one value of padding.
    #[inline(always)]
    fn fill(&mut self, row: &[f64], cols: &[(usize, usize)], source: usize) {
        let n = cols.len() * 3 + 1;
        self.g.resize(n, 0.0);
        self.h.resize(n, 0.0);
        let (g, h) = (&mut self.g[..n], &mut self.h[..n]);
        for (m, &(i0, i1)) in cols.iter().enumerate() {
            g[m * 3..m * 3 + 4].copy_from_slice(&row[i0..i0 + 4]);
            h[m * 3..m * 3 + 4].copy_from_slice(&row[i1..i1 + 4]);
        }
        self.source = Some(source);
    }
}

thread_local! {
    static PLANS: std::cell::RefCell<(Vec<std::rc::Rc<Plan>>, Buffers)> = Default::default();
}

/// The corruption on a square `size`×`size` image.
pub(super) fn zoom_blur(rgb: &mut [u8], size: usize, severity: u8) {
    zoom_blur_with(rgb, size, severity, avx512::available())
}

fn zoom_blur_with(rgb: &mut [u8], size: usize, severity: u8, use_avx512: bool) {
    PLANS.with_borrow_mut(|(plans, buffers)| {
        let plan = match plans.iter().find(|p| p.size == size && p.severity == severity) {
            Some(p) => p.clone(),
            None => {
                let factors = zoom_factors(severity).into_iter().map(|z| FactorPlan::new(size, z)).collect();
                let p = std::rc::Rc::new(Plan { size, severity, factors });
                plans.push(p.clone());
                p
            }
        };
        super::vectorized(
            #[inline(always)]
            || blur(rgb, &plan, buffers, use_avx512),
        )
    })
}

#[inline(always)]
fn blur(rgb: &mut [u8], plan: &Plan, buf: &mut Buffers, use_avx512: bool) {
    let size = plan.size;
    let stride = size * 3;
    let len = stride * size;
    // x = img / 255 in float32, held as float64 for the arithmetic: 256 possible values.
    let lut: [f64; 256] = std::array::from_fn(|v| f64::from((v as f64 / 255.0) as f32));
    buf.x64.clear();
    buf.x64.extend(rgb.iter().map(|&v| lut[usize::from(v)]));
    buf.x64.extend([0.0; PAD]);
    buf.sum.clear();
    buf.sum.resize(len, 0.0);
    let (x64, sum, rows) = (&buf.x64[..], &mut buf.sum[..], &mut buf.rows);
    for f in &plan.factors {
        if f.identity {
            for (s, &v) in sum.iter_mut().zip(&x64[..len]) {
                *s += v as f32;
            }
            continue;
        }
        rows.iter_mut().for_each(|r| r.source = None);
        for (out, r) in sum.chunks_exact_mut(stride).zip(&f.rows) {
            // A constant-0 row adds exact zeros: nothing to do.
            let Some(r) = r else { continue };
            #[cfg(target_arch = "x86_64")]
            if let (true, Some(w)) = (use_avx512, &f.windows) {
                w.row(out, &x64[r.i0 * stride..], &x64[r.i1 * stride..], r, f);
                continue;
            }
            let a = match rows.iter().position(|g| g.source == Some(r.i0)) {
                Some(a) => a,
                None => {
                    let a = usize::from(rows[0].source == Some(r.i1));
                    rows[a].fill(&x64[r.i0 * stride..][..stride + 1], &f.cols, r.i0);
                    a
                }
            };
            let b = if rows[a].source == Some(r.i1) { a } else { 1 - a };
            if rows[b].source != Some(r.i1) {
                rows[b].fill(&x64[r.i1 * stride..][..stride + 1], &f.cols, r.i1);
            }
            let n = out.len(); // slices of one length: no bounds checks, the loop vectorises
            let (g0, h0, g1, h1) = (&rows[a].g[..n], &rows[a].h[..n], &rows[b].g[..n], &rows[b].h[..n]);
            let (wc0, wc1) = (&f.wc0[..n], &f.wc1[..n]);
            for k in 0..n {
                let t = (g0[k] * r.w0) * wc0[k]
                    + (h0[k] * r.w0) * wc1[k]
                    + (g1[k] * r.w1) * wc0[k]
                    + (h1[k] * r.w1) * wc1[k];
                out[k] += t as f32;
            }
        }
    }
    let n = (plan.factors.len() + 1) as f32;
    for (o, (&v, &s)) in rgb.iter_mut().zip(x64.iter().zip(sum.iter())) {
        *o = (((v as f32 + s) / n).clamp(0.0, 1.0) * 255.0) as u8;
    }
}

/// The AVX-512 path: no gathered rows. Each 8 output values of a row read their 4 taps by
/// permuting a 16-value window of each source row in registers (`vpermt2pd`), then compute the
/// same products and sums as [`blur`]'s loop, lane for lane (no FMA): the result is the same bit
/// for bit, which `paths_agree` checks.
mod avx512 {
    /// Whether this CPU runs the AVX-512 path.
    pub(super) fn available() -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            std::arch::is_x86_feature_detected!("avx512f")
        }
        #[cfg(not(target_arch = "x86_64"))]
        false
    }

    #[cfg(target_arch = "x86_64")]
    pub(super) use imp::Windows;

    #[cfg(target_arch = "x86_64")]
    mod imp {
        use super::super::{FactorPlan, PAD, Taps};
        use std::arch::x86_64::*;

        /// Per block of 8 output values: where its window starts in a source row, and which
        /// window values its `i0` and `i1` reads are (indices 0..16).
        pub(in super::super) struct Windows {
            start: Vec<usize>,
            i0: Vec<[i64; 8]>,
            i1: Vec<[i64; 8]>,
        }

        impl Windows {
            /// `None` if some block's reads span more than 16 values (never for zoom factors ≥ 1,
            /// whose reads advance by at most one pixel per output pixel).
            pub(in super::super) fn new(cols: &[(usize, usize)]) -> Option<Self> {
                let reads = |v: usize| {
                    let (i0, i1) = cols[v / 3];
                    (i0 + v % 3, i1 + v % 3)
                };
                let blocks = cols.len() * 3 / 8;
                let mut w = Windows { start: vec![], i0: vec![], i1: vec![] };
                for b in 0..blocks {
                    let vals: Vec<(usize, usize)> = (8 * b..8 * b + 8).map(reads).collect();
                    let start = vals.iter().map(|&(a, b)| a.min(b)).min()?;
                    let end = vals.iter().map(|&(a, b)| a.max(b)).max()?;
                    if end - start >= PAD || start + PAD > cols.len() * 3 + PAD {
                        return None;
                    }
                    w.start.push(start);
                    w.i0.push(std::array::from_fn(|l| (vals[l].0 - start) as i64));
                    w.i1.push(std::array::from_fn(|l| (vals[l].1 - start) as i64));
                }
                Some(w)
            }

            /// Adds one output row's values to `out` (a row of the float32 sum): `x0`, `x1` are
            /// the image from the row's two source rows on, to the end of the padding.
            pub(in super::super) fn row(&self, out: &mut [f32], x0: &[f64], x1: &[f64], r: &Taps, f: &FactorPlan) {
                let stride = out.len();
                assert!(x0.len() >= stride + PAD && x1.len() >= stride + PAD && f.wc0.len() == stride);
                assert!(self.start.len() == stride / 8 && f.wc1.len() == stride);
                // SAFETY: `available()` was checked by the caller's `use_avx512`; the windows
                // were checked (`new`) to lie within a row plus the padding, asserted above.
                unsafe { self.row_avx512(out, x0, x1, r.w0, r.w1, &f.wc0, &f.wc1) };
                // The values past the last whole block, as the portable loop computes them.
                let done = self.start.len() * 8;
                for (k, o) in out.iter_mut().enumerate().skip(done) {
                    let (i0, i1) = f.cols[k / 3];
                    let (i0, i1) = (i0 + k % 3, i1 + k % 3);
                    let t = (x0[i0] * r.w0) * f.wc0[k]
                        + (x0[i1] * r.w0) * f.wc1[k]
                        + (x1[i0] * r.w1) * f.wc0[k]
                        + (x1[i1] * r.w1) * f.wc1[k];
                    *o += t as f32;
                }
            }

            #[target_feature(enable = "avx512f")]
            #[allow(clippy::too_many_arguments)]
            unsafe fn row_avx512(
                &self,
                out: &mut [f32],
                x0: &[f64],
                x1: &[f64],
                w0: f64,
                w1: f64,
                wc0: &[f64],
                wc1: &[f64],
            ) {
                let (a0, a1) = (_mm512_set1_pd(w0), _mm512_set1_pd(w1));
                for (b, ((&s, i0), i1)) in self.start.iter().zip(&self.i0).zip(&self.i1).enumerate() {
                    // SAFETY (all loads and the store): s + 16 <= x0.len(), x1.len() and
                    // 8·b + 8 <= the row's length (checked by the caller).
                    unsafe {
                        let (p0, p1) = (x0.as_ptr().add(s), x1.as_ptr().add(s));
                        let (lo0, hi0) = (_mm512_loadu_pd(p0), _mm512_loadu_pd(p0.add(8)));
                        let (lo1, hi1) = (_mm512_loadu_pd(p1), _mm512_loadu_pd(p1.add(8)));
                        let j0 = _mm512_loadu_si512(i0.as_ptr().cast());
                        let j1 = _mm512_loadu_si512(i1.as_ptr().cast());
                        let g0 = _mm512_permutex2var_pd(lo0, j0, hi0);
                        let h0 = _mm512_permutex2var_pd(lo0, j1, hi0);
                        let g1 = _mm512_permutex2var_pd(lo1, j0, hi1);
                        let h1 = _mm512_permutex2var_pd(lo1, j1, hi1);
                        let c0 = _mm512_loadu_pd(wc0.as_ptr().add(8 * b));
                        let c1 = _mm512_loadu_pd(wc1.as_ptr().add(8 * b));
                        let t = _mm512_add_pd(
                            _mm512_add_pd(
                                _mm512_add_pd(
                                    _mm512_mul_pd(_mm512_mul_pd(g0, a0), c0),
                                    _mm512_mul_pd(_mm512_mul_pd(h0, a0), c1),
                                ),
                                _mm512_mul_pd(_mm512_mul_pd(g1, a1), c0),
                            ),
                            _mm512_mul_pd(_mm512_mul_pd(h1, a1), c1),
                        );
                        let o = out.as_mut_ptr().add(8 * b);
                        _mm256_storeu_ps(o, _mm256_add_ps(_mm256_loadu_ps(o), _mm512_cvtpd_ps(t)));
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn factor_counts_and_ends_are_numpys() {
        let lens: Vec<usize> = (1..=10).map(|s| zoom_factors(s).len()).collect();
        assert_eq!(lens, [12, 16, 11, 13, 11, 37, 41, 23, 26, 19]);
        // Values numpy 1.26 prints for these aranges.
        assert_eq!(*zoom_factors(1).last().unwrap(), 1.11);
        assert_eq!(*zoom_factors(2).last().unwrap(), 1.1500000000000001);
        assert_eq!(*zoom_factors(10).last().unwrap(), 1.5400000000000005);
        assert_eq!(zoom_factors(5)[5], 1.1500000000000001);
        assert!((1..=10).all(|s| zoom_factors(s)[0] == 1.0));
    }

    #[test]
    fn zoom_one_reads_each_pixel_in_place() {
        let taps = axis_taps(224, 1.0);
        assert!(taps.iter().enumerate().all(|(k, t)| {
            let t = t.unwrap();
            t.i0 == k && t.w0 == 1.0 && t.w1 == 0.0
        }));
    }

    #[test]
    fn paths_agree() {
        // The AVX-512 path (where the CPU has it) and the portable one, bit for bit, at sizes
        // whose rows end mid-block too.
        for size in [31usize, 64, 100, 224, 255, 256] {
            let img: Vec<u8> = (0..size * size * 3).map(|i| (i * 7919 % 251) as u8 ^ (i / 97) as u8).collect();
            for s in 1..=10 {
                let (mut a, mut b) = (img.clone(), img.clone());
                zoom_blur_with(&mut a, size, s, avx512::available());
                zoom_blur_with(&mut b, size, s, false);
                assert!(a == b, "size {size} severity {s}");
                assert_ne!(a, img, "size {size} severity {s}");
            }
        }
    }

    #[test]
    fn the_avx512_windows_cover_every_factor_at_policy_sizes() {
        for size in [128, 224, 256] {
            for s in 1..=10 {
                for z in zoom_factors(s) {
                    let plan = FactorPlan::new(size, z);
                    #[cfg(target_arch = "x86_64")]
                    assert!(plan.windows.is_some(), "size {size} zoom {z}");
                    assert!(plan.identity == (z == 1.0), "size {size} zoom {z}");
                }
            }
        }
    }

    #[test]
    fn a_flat_image_stays_flat() {
        let mut img = vec![77u8; 32 * 32 * 3];
        zoom_blur(&mut img, 32, 3);
        assert!(img.iter().all(|&v| v == 76 || v == 77), "{:?}", &img[..6]);
    }
}
