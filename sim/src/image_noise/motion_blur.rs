//! Motion blur (levels 1–10): ImageMagick's `MotionBlurImage(radius, sigma, angle)` through Wand,
//! with a PNG round trip on either side, angle `uniform(-45, 45)` drawn on every call.
//!
//! The reference binds (ctypes) whatever libMagickWand Wand finds; LIBERO-Plus's README installs
//! `libmagickwand-dev`, which is ImageMagick 6 Q16 (non-HDRI) on Debian and Ubuntu. This is
//! IM 6.9.11-60's `MotionBlurImageChannel` (magick/effect.c), operation for operation:
//! - width `w = 2·ceil(radius) + 1`; a one-sided kernel `k_i = exp(-i²/(2σ²)) / (√(2π)·σ)`,
//!   `i = 0..w`, divided by its sequential sum;
//! - offsets `(ceil(i·w·cos θ / hypot - 0.5), ceil(i·w·sin θ / hypot - 0.5))` in (x, y),
//!   `hypot = hypot(w·sin θ, w·cos θ)`, y down the rows as given (robosuite's raw order);
//! - each channel `Σ_i k_i · q(x + ox_i, y + oy_i)` in double from 0, q the 16-bit quantum
//!   `257·v` of the PNG's 8-bit value, pixels outside repeated from the edge;
//! - `ClampToQuantum` (round half up to 16 bits); then the PNG writer, which first calls
//!   `SetImageDepth(image, 8)` (coders/png.c): `(unsigned) (255.0·q / 65535)`, i.e. `q / 257`
//!   rounded down (not `ScaleQuantumToChar`'s rounding, which would differ in ~45% of values).
//!
//! ImageMagick 7 (the spec's reading of `MotionBlurImage`; HDRI by default) keeps the sum as a
//! float, without the 16-bit rounding, and scales it to 8 bits its own way: its bytes may differ
//! by 1. It is not what `libmagickwand-dev` installs on Debian or Ubuntu, and was not measured.

use super::NoiseDraws;

/// `(radius, sigma)` per severity.
const PARAMS: [(f64, f64); 10] = [
    (5.0, 2.0),
    (8.0, 3.0),
    (10.0, 4.0),
    (12.0, 5.0),
    (15.0, 6.0),
    (18.0, 8.0),
    (20.0, 10.0),
    (25.0, 12.0),
    (30.0, 15.0),
    (35.0, 20.0),
];

/// `MagickSQ2PI` of ImageMagick's image-private.h.
const SQ2PI: f64 = 2.50662827463100024161235523934010416269302368164062;

/// The blur's taps: kernel weights and (x, y) offsets, as `MotionBlurImageChannel` makes them.
fn taps(radius: f64, sigma: f64, angle_deg: f64) -> (Vec<f64>, Vec<(isize, isize)>) {
    let width = (2.0 * radius.ceil() + 1.0) as usize; // GetOptimalKernelWidth1D, radius > 0
    let mut kernel: Vec<f64> =
        (0..width).map(|i| (-((i as f64) * i as f64) / (2.0 * sigma * sigma)).exp() / (SQ2PI * sigma)).collect();
    let normalize = kernel.iter().fold(0.0, |acc, k| acc + k);
    kernel.iter_mut().for_each(|k| *k /= normalize);
    let radians = std::f64::consts::PI * angle_deg / 180.0;
    let (px, py) = (width as f64 * radians.sin(), width as f64 * radians.cos());
    let offsets = (0..width)
        .map(|i| {
            let ox = ((i as f64 * py) / px.hypot(py) - 0.5).ceil();
            let oy = ((i as f64 * px) / px.hypot(py) - 0.5).ceil();
            (ox as isize, oy as isize)
        })
        .collect();
    (kernel, offsets)
}

/// The corruption, in place. Returns whether the result is grey (every pixel R = G = B): then
/// ImageMagick writes a greyscale PNG, which the reference handles only at 224×224 (the caller
/// decides what that means at other sizes).
pub(super) fn motion_blur(
    rgb: &mut [u8],
    width: usize,
    height: usize,
    severity: u8,
    draws: &mut dyn NoiseDraws,
) -> bool {
    super::vectorized(
        #[inline(always)]
        || blur(rgb, width, height, severity, draws),
    )
}

#[inline(always)]
fn blur(rgb: &mut [u8], width: usize, height: usize, severity: u8, draws: &mut dyn NoiseDraws) -> bool {
    let (radius, sigma) = PARAMS[usize::from(severity) - 1];
    let angle = draws.uniform(-45.0, 45.0);
    let (kernel, offsets) = taps(radius, sigma, angle);

    // Quanta with `pad` edge pixels either side of each row, so each tap adds a contiguous slice.
    let pad = offsets.iter().map(|&(ox, _)| ox.unsigned_abs()).max().unwrap_or(0);
    let padded = (width + 2 * pad) * 3;
    let mut quanta = vec![0.0f64; height * padded];
    for (src, dst) in rgb.chunks_exact(width * 3).zip(quanta.chunks_exact_mut(padded)) {
        for (k, px) in dst.chunks_exact_mut(3).enumerate() {
            let x = k.saturating_sub(pad).min(width - 1) * 3;
            px.iter_mut().zip(&src[x..x + 3]).for_each(|(q, &v)| *q = 257.0 * f64::from(v));
        }
    }

    let mut sum = vec![0.0f64; width * 3];
    for (y, out) in rgb.chunks_exact_mut(width * 3).enumerate() {
        sum.fill(0.0);
        for (&k, &(ox, oy)) in kernel.iter().zip(&offsets) {
            let row = (y as isize + oy).clamp(0, height as isize - 1) as usize;
            let start = row * padded + (pad as isize + ox) as usize * 3;
            sum.iter_mut().zip(&quanta[start..start + width * 3]).for_each(|(s, &q)| *s += k * q);
        }
        for (o, &s) in out.iter_mut().zip(&sum) {
            // ClampToQuantum (non-HDRI Q16), then SetImageDepth's ScaleQuantumToAny(q, 255).
            let q = if s <= 0.0 {
                0.0
            } else if s >= 65535.0 {
                65535.0
            } else {
                (s + 0.5).trunc()
            };
            *o = (255.0 * q / 65535.0) as u8;
        }
    }
    rgb.chunks_exact(3).all(|p| p[0] == p[1] && p[1] == p[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_are_one_sided_and_offsets_follow_the_angle() {
        let (kernel, offsets) = taps(5.0, 2.0, 0.0);
        assert_eq!(kernel.len(), 11);
        assert!(kernel.windows(2).all(|w| w[0] > w[1]), "decreasing from the pixel itself");
        assert_eq!(offsets, (0..11).map(|i| (i, 0)).collect::<Vec<_>>(), "angle 0: along +x");
        let (_, offsets) = taps(5.0, 2.0, 45.0);
        assert_eq!(offsets[10], (7, 7), "45°: down and right (ceil(10·cos 45° - 0.5))");
        let (_, offsets) = taps(5.0, 2.0, -45.0);
        assert_eq!(offsets[10], (7, -7), "-45°: up and right");
    }

    #[test]
    fn a_flat_image_stays_flat_and_grey_is_reported() {
        // Σ k_i = 1 up to rounding and 257·v / 257 = v: every byte survives.
        let mut draws = crate::image_noise::SeededDraws::new(0);
        for v in [0u8, 1, 127, 128, 254, 255] {
            let mut img = vec![v; 6 * 5 * 3];
            assert!(motion_blur(&mut img, 6, 5, 10, &mut draws));
            assert!(img.iter().all(|&p| p == v), "{v}");
        }
        let mut red: Vec<u8> = [200u8, 10, 10].repeat(6 * 5);
        assert!(!motion_blur(&mut red, 6, 5, 4, &mut draws));
        assert_eq!(&red[..3], &[200, 10, 10]);
    }
}
