//! Glass blur (levels 41–50): Gaussian blur, a local pixel shuffle, Gaussian blur again.
//!
//! 1. `x = uint8(gaussian(x / 255, sigma) · 255)` (truncated, not clipped first);
//! 2. `iterations` times, rows `h` from `last - δ` down to `δ + 1` and, in each, columns `w` from
//!    `last - δ` down to `δ + 1`: `dx, dy = randint(-δ, δ, size=2)`, then
//!    `x[h, w], x[h+dy, w+dx] = x[h+dy, w+dx], x[h, w]`. With numpy views this "swap" is a copy:
//!    the right-hand side holds views, the first assignment overwrites the one the second reads,
//!    so only `x[h, w] = x[h+dy, w+dx]` happens. `last` is 224 in revision lb2025 (hard-coded),
//!    the image's height and width in head.
//! 3. `clip(gaussian(x / 255, sigma), 0, 1) · 255`, truncated.
//!
//! Step 2 is sequential by nature (each copy reads what the previous ones wrote).

use super::NoiseDraws;
use super::gaussian::gaussian_filter;

/// `(sigma, δ, iterations)` per severity.
const PARAMS: [(f64, i64, usize); 10] = [
    (0.5, 1, 3),
    (0.7, 1, 3),
    (0.9, 2, 3),
    (1.0, 2, 2),
    (1.1, 3, 2),
    (1.3, 3, 2),
    (1.5, 4, 2),
    (1.8, 4, 2),
    (2.2, 5, 1),
    (2.5, 5, 1),
];

/// The corruption on a `width`×`height` image, shuffling rows and columns `δ+1 ..= end - δ`
/// (`end_h`/`end_w`: 224 in lb2025, the height and width in head; the caller checks they fit).
pub(super) fn glass_blur(
    rgb: &mut [u8],
    width: usize,
    height: usize,
    (end_h, end_w): (usize, usize),
    severity: u8,
    draws: &mut dyn NoiseDraws,
) {
    let (sigma, delta, iterations) = PARAMS[usize::from(severity) - 1];
    let mut x: Vec<f64> = rgb.iter().map(|&v| f64::from(v) / 255.0).collect();
    gaussian_filter(&mut x, width, height, sigma);
    rgb.iter_mut().zip(&x).for_each(|(o, v)| *o = (v * 255.0) as u8);

    let d = delta as usize;
    let columns: Vec<usize> = (d + 1..=end_w.saturating_sub(d)).rev().collect();
    let mut shifts = vec![0i64; 2 * columns.len()];
    for _ in 0..iterations {
        for h in (d + 1..=end_h.saturating_sub(d)).rev() {
            // One randint(size=2) call per pixel of the row, in the reference's order: (dx, dy).
            draws.randint_calls(-delta, delta, 2, &mut shifts);
            for (&w, dxdy) in columns.iter().zip(shifts.chunks_exact(2)) {
                let src = ((h as i64 + dxdy[1]) as usize * width + (w as i64 + dxdy[0]) as usize) * 3;
                let pixel = [rgb[src], rgb[src + 1], rgb[src + 2]];
                rgb[(h * width + w) * 3..][..3].copy_from_slice(&pixel);
            }
        }
    }

    x.iter_mut().zip(rgb.iter()).for_each(|(v, &p)| *v = f64::from(p) / 255.0);
    gaussian_filter(&mut x, width, height, sigma);
    rgb.iter_mut().zip(&x).for_each(|(o, v)| *o = (v.clamp(0.0, 1.0) * 255.0) as u8);
}
