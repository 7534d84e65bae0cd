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

/// One source row read at the kept output columns' taps, in float64: `g[m·3 + c]` is channel c of
/// the pixel at column `i0(m)`, `h[..]` at `i1(m)`. Gathering once per source row and zoom factor
/// lets the arithmetic run over contiguous arrays (vectorised), in the same order as scipy's.
struct Gathered {
    source: Option<usize>,
    g: Vec<f64>,
    h: Vec<f64>,
}

impl Gathered {
    fn new(len: usize) -> Self {
        Gathered { source: None, g: vec![0.0; len], h: vec![0.0; len] }
    }

    fn fill(&mut self, row: &[f32], columns: &[Option<Taps>], source: usize) {
        for ((g, h), c) in self.g.chunks_exact_mut(3).zip(self.h.chunks_exact_mut(3)).zip(columns) {
            // A constant-0 column has weight 0 here; any pixel will do.
            let (i0, i1) = c.map_or((0, 0), |c| (c.i0, c.i1));
            g.iter_mut().zip(&row[i0 * 3..i0 * 3 + 3]).for_each(|(g, &v)| *g = f64::from(v));
            h.iter_mut().zip(&row[i1 * 3..i1 * 3 + 3]).for_each(|(h, &v)| *h = f64::from(v));
        }
        self.source = Some(source);
    }
}

/// The corruption on a square `size`×`size` image.
pub(super) fn zoom_blur(rgb: &mut [u8], size: usize, severity: u8) {
    super::vectorized(
        #[inline(always)]
        || blur(rgb, size, severity),
    )
}

#[inline(always)]
fn blur(rgb: &mut [u8], size: usize, severity: u8) {
    let stride = size * 3;
    let x: Vec<f32> = rgb.iter().map(|&v| (f64::from(v) / 255.0) as f32).collect();
    let mut sum = vec![0f32; x.len()];
    // Column weights per value; 0 for a column scipy leaves at the constant 0: it adds an exact 0.
    let (mut wc0, mut wc1) = (vec![0.0f64; stride], vec![0.0f64; stride]);
    let mut rows = [Gathered::new(stride), Gathered::new(stride)];
    let factors = zoom_factors(severity);
    for &z in &factors {
        let taps = axis_taps(size, z); // rows and columns alike: the image is square
        for ((w0, w1), t) in wc0.chunks_exact_mut(3).zip(wc1.chunks_exact_mut(3)).zip(&taps) {
            let (a, b) = t.map_or((0.0, 0.0), |t| (t.w0, t.w1));
            w0.fill(a);
            w1.fill(b);
        }
        rows.iter_mut().for_each(|r| r.source = None);
        for (out, r) in sum.chunks_exact_mut(stride).zip(&taps) {
            // A constant-0 row adds exact zeros: nothing to do.
            let Some(r) = r else { continue };
            let a = match rows.iter().position(|g| g.source == Some(r.i0)) {
                Some(a) => a,
                None => {
                    let a = usize::from(rows[0].source == Some(r.i1));
                    rows[a].fill(&x[r.i0 * stride..][..stride], &taps, r.i0);
                    a
                }
            };
            let b = if rows[a].source == Some(r.i1) { a } else { 1 - a };
            if rows[b].source != Some(r.i1) {
                rows[b].fill(&x[r.i1 * stride..][..stride], &taps, r.i1);
            }
            let n = out.len(); // slices of one length: no bounds checks, the loop vectorises
            let (g0, h0, g1, h1) = (&rows[a].g[..n], &rows[a].h[..n], &rows[b].g[..n], &rows[b].h[..n]);
            let (wc0, wc1) = (&wc0[..n], &wc1[..n]);
            for k in 0..n {
                let t = (g0[k] * r.w0) * wc0[k]
                    + (h0[k] * r.w0) * wc1[k]
                    + (g1[k] * r.w1) * wc0[k]
                    + (h1[k] * r.w1) * wc1[k];
                out[k] += t as f32;
            }
        }
    }
    let n = (factors.len() + 1) as f32;
    for (o, (&v, &s)) in rgb.iter_mut().zip(x.iter().zip(&sum)) {
        *o = (((v + s) / n).clamp(0.0, 1.0) * 255.0) as u8;
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
    fn a_flat_image_stays_flat() {
        let mut img = vec![77u8; 32 * 32 * 3];
        zoom_blur(&mut img, 32, 3);
        assert!(img.iter().all(|&v| v == 76 || v == 77), "{:?}", &img[..6]);
    }
}
