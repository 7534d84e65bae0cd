//! Gaussian blur (levels 11–20), and the Gaussian filter glass blur also uses: scikit-image's
//! `gaussian(x, sigma, channel_axis=-1)`, i.e. `scipy.ndimage.gaussian_filter` with sigma
//! `(s, s, 0)`, mode `nearest`, truncate 4, in float64.
//!
//! Bit-exactness needs scipy's arithmetic, operation for operation:
//! - the kernel: `exp(-0.5 / s² · x²)` for x in `-r..=r`, `r = int(4·s + 0.5)`, divided by its
//!   numpy sum (pairwise summation, 8 accumulators), see [`kernel`];
//! - `NI_Correlate1D`'s symmetric loop: `out = x[0]·w0`, then `out += (x[-j] + x[j])·wj` from the
//!   outermost tap inwards; rows (axis 0) first, then columns, edges repeated (`nearest`).
//!
//! `exp` is libm's, as numpy takes it on CPUs without AVX512F; numpy's own AVX512F `exp` differs
//! in the last bit for some weights, which moves a few truncated pixels by one (the oracle pins
//! numpy to libm's; tests/noise.rs measures the other).

/// Sigma of severity s (`c = [1, ..., 10][s - 1]`).
pub(super) fn blur_sigma(severity: u8) -> f64 {
    f64::from(severity)
}

/// The corruption: `clip(gaussian(x / 255, s), 0, 1) · 255`, truncated to uint8.
pub(super) fn gaussian_blur(rgb: &mut [u8], width: usize, height: usize, severity: u8) {
    let mut x: Vec<f64> = rgb.iter().map(|&v| f64::from(v) / 255.0).collect();
    gaussian_filter(&mut x, width, height, blur_sigma(severity));
    for (o, v) in rgb.iter_mut().zip(&x) {
        *o = (v.clamp(0.0, 1.0) * 255.0) as u8;
    }
}

/// scipy's normalised Gaussian kernel, `_gaussian_kernel1d(sigma, 0, int(4·sigma + 0.5))`:
/// the weights of offsets `-r..=r` (symmetric, bit for bit).
pub(super) fn kernel(sigma: f64) -> Vec<f64> {
    let radius = (4.0 * sigma + 0.5) as i64;
    let a = -0.5 / (sigma * sigma);
    let phi: Vec<f64> = (-radius..=radius).map(|x| (a * (x * x) as f64).exp()).collect();
    let sum = numpy_sum(&phi);
    phi.iter().map(|p| p / sum).collect()
}

/// `np.sum` of a float64 array of at most 128 elements (the kernels here have at most 81):
/// below 8 elements a plain loop, else numpy's pairwise block of 8 accumulators, then the rest.
fn numpy_sum(a: &[f64]) -> f64 {
    let n = a.len();
    debug_assert!(n <= 128, "numpy splits longer arrays in halves first");
    if n < 8 {
        return a.iter().fold(0.0, |acc, v| acc + v);
    }
    let mut r = [0.0; 8];
    r.copy_from_slice(&a[..8]);
    let blocks = n - n % 8;
    for block in a[8..blocks].chunks_exact(8) {
        r.iter_mut().zip(block).for_each(|(r, v)| *r += v);
    }
    let res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
    a[blocks..].iter().fold(res, |acc, v| acc + v)
}

/// `gaussian_filter(img, (sigma, sigma, 0), mode='nearest', truncate=4)` in place, on an
/// H×W×3 float64 image (row-major, channels interleaved).
pub(super) fn gaussian_filter(img: &mut [f64], width: usize, height: usize, sigma: f64) {
    super::vectorized(
        #[inline(always)]
        || filter(img, width, height, sigma),
    )
}

#[inline(always)]
fn filter(img: &mut [f64], width: usize, height: usize, sigma: f64) {
    let w = kernel(sigma);
    let r = w.len() / 2;
    let (w0, taps) = (w[r], &w[r + 1..]); // taps[j - 1]: the weight at offset ±j
    let stride = width * 3;

    // Axis 0: each output row from whole input rows (the same per-element arithmetic as scipy's
    // column lines, in an order that vectorises).
    let mut rows = vec![0.0; img.len()];
    for (y, out) in rows.chunks_exact_mut(stride).enumerate() {
        let row = |i: usize| &img[i * stride..(i + 1) * stride];
        out.iter_mut().zip(row(y)).for_each(|(o, &c)| *o = c * w0);
        for j in (1..=r).rev() {
            let (up, down) = (row(y.saturating_sub(j)), row((y + j).min(height - 1)));
            let wj = taps[j - 1];
            out.iter_mut().zip(up).zip(down).for_each(|((o, &a), &b)| *o += (a + b) * wj);
        }
    }

    // Axis 1: each row, padded with its edge pixels, back into `img`.
    let mut line = vec![0.0; (width + 2 * r) * 3];
    for (src, out) in rows.chunks_exact(stride).zip(img.chunks_exact_mut(stride)) {
        for (k, px) in line.chunks_exact_mut(3).enumerate() {
            let x = k.saturating_sub(r).min(width - 1);
            px.copy_from_slice(&src[x * 3..x * 3 + 3]);
        }
        out.iter_mut().zip(&line[r * 3..]).for_each(|(o, &c)| *o = c * w0);
        for j in (1..=r).rev() {
            let (left, right) = (&line[(r - j) * 3..], &line[(r + j) * 3..]);
            let wj = taps[j - 1];
            out.iter_mut().zip(left).zip(right).for_each(|((o, &a), &b)| *o += (a + b) * wj);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_have_scipys_radius_and_are_normalised_and_symmetric() {
        for (sigma, radius) in [(0.5, 2), (0.7, 3), (1.0, 4), (2.5, 10), (10.0, 40)] {
            let k = kernel(sigma);
            assert_eq!(k.len(), 2 * radius + 1, "sigma {sigma}");
            assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            assert!(k.iter().zip(k.iter().rev()).all(|(a, b)| a == b));
        }
    }

    #[test]
    fn numpy_sum_uses_eight_accumulators_past_seven_elements() {
        // 1e16 absorbs a 1.0 added to it, so the grouping shows in the result; numpy 1.26's
        // `np.sum` of this array is 1.0000000000000014e16.
        let mut a = [1.0; 16];
        a[0] = 1e16;
        assert_eq!(a.iter().fold(0.0, |s, v| s + v), 1e16);
        assert_eq!(numpy_sum(&a), 1.0000000000000014e16);
        assert_eq!(numpy_sum(&a[..7]), 1e16, "below 8 elements: a plain loop");
    }

    #[test]
    fn a_flat_image_stays_flat_up_to_truncation() {
        let (w, h) = (16, 12);
        let mut img = vec![0.5; w * h * 3];
        gaussian_filter(&mut img, w, h, 3.0);
        assert!(img.iter().all(|v| (v - 0.5).abs() < 1e-15));
    }
}
