//! Fog (levels 31–40): ImageNet-C's diamond-square plasma added to the image,
//! `clip((x + c0·plasma[:h, :w]) · max(x) / (max(x) + c0), 0, 1) · 255`, in float64, truncated.
//!
//! The plasma is `plasma_fractal(mapsize=256, wibbledecay=c1)`: 8 levels of squares then diamonds,
//! each fill `mean / 4 + wibble · U(-wibble, wibble)` with one `uniform` call per fill (3 a level,
//! 65,535 values in all), the map shifted and scaled to [0, 1]. Its sums are numpy's, element for
//! element: `np.roll` neighbours, `a + roll(a)` then `+ roll(...)`.

use super::NoiseDraws;

/// The plasma's side: the reference's default `mapsize`, whatever the image size.
pub(super) const MAPSIZE: usize = 256;

/// `(c0, c1)`: the plasma's weight and its wibble decay per severity.
const PARAMS: [(f64, f64); 10] = [
    (0.5, 3.0),
    (1.0, 2.8),
    (1.5, 2.5),
    (2.0, 2.2),
    (2.5, 2.0),
    (3.0, 1.8),
    (3.5, 1.6),
    (4.0, 1.5),
    (4.5, 1.4),
    (5.0, 1.3),
];

/// `plasma_fractal(256, wibbledecay)`, row-major. The draws, in order: per level (stepsize
/// 256, 128, …, 2; n = 256 / stepsize cells a side) `uniform(-wibble, wibble, (n, n))` for the
/// squares, then for the diamonds of the rows of the corners, then of the columns of the corners.
fn plasma_fractal(wibble_decay: f64, draws: &mut dyn NoiseDraws) -> Vec<f64> {
    const M: usize = MAPSIZE;
    let mut map = vec![0.0f64; M * M]; // every cell but [0, 0] is filled below
    let at = |i: usize, j: usize| i * M + j;
    let mut wibble = 100.0f64;
    let mut step = M;
    let mut noise = vec![0.0; (M / 2) * (M / 2)];
    while step >= 2 {
        let (n, half) = (M / step, step / 2);
        // n is a power of two: `& wrap` is numpy's roll wrap-around, `>> shift` a division by n.
        let (wrap, shift) = (n - 1, n.trailing_zeros());
        let noise = &mut noise[..n * n];
        // fillsquares: corner sums down (axis 0) then across (axis 1), the centre of each square.
        draws.uniform_batch(-wibble, wibble, noise);
        let corner = |map: &[f64], i: usize, j: usize| map[at((i & wrap) * step, (j & wrap) * step)];
        let down: Vec<f64> =
            (0..n * n).map(|k| corner(&map, k >> shift, k) + corner(&map, (k >> shift) + 1, k)).collect();
        for i in 0..n {
            for j in 0..n {
                let sum = down[i * n + j] + down[i * n + ((j + 1) & wrap)];
                map[at(i * step + half, j * step + half)] = sum / 4.0 + wibble * noise[i * n + j];
            }
        }
        // filldiamonds: the centres (dr) and corners (ul) just made and before, at stepsize.
        let dr = |map: &[f64], i: usize, j: usize| map[at(i * step + half, j * step + half)];
        let ul = |map: &[f64], i: usize, j: usize| map[at(i * step, j * step)];
        draws.uniform_batch(-wibble, wibble, noise);
        for i in 0..n {
            for j in 0..n {
                let ldr = dr(&map, i, j) + dr(&map, (i + wrap) & wrap, j);
                let lul = ul(&map, i, j) + ul(&map, i, (j + 1) & wrap);
                map[at(i * step, j * step + half)] = (ldr + lul) / 4.0 + wibble * noise[i * n + j];
            }
        }
        draws.uniform_batch(-wibble, wibble, noise);
        for i in 0..n {
            for j in 0..n {
                let tdr = dr(&map, i, j) + dr(&map, i, (j + wrap) & wrap);
                let tul = ul(&map, i, j) + ul(&map, (i + 1) & wrap, j);
                map[at(i * step + half, j * step)] = (tdr + tul) / 4.0 + wibble * noise[i * n + j];
            }
        }
        step /= 2;
        wibble /= wibble_decay;
    }
    let min = map.iter().copied().fold(f64::INFINITY, f64::min);
    map.iter_mut().for_each(|v| *v -= min);
    let max = map.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    map.iter_mut().for_each(|v| *v /= max);
    map
}

/// The corruption on a `width`×`height` image (both at most [`MAPSIZE`]; the caller checks what
/// the revision allows).
pub(super) fn fog(rgb: &mut [u8], width: usize, height: usize, severity: u8, draws: &mut dyn NoiseDraws) {
    let (c0, c1) = PARAMS[usize::from(severity) - 1];
    let max = f64::from(*rgb.iter().max().expect("an image")) / 255.0;
    let plasma = plasma_fractal(c1, draws);
    for (y, row) in rgb.chunks_exact_mut(width * 3).take(height).enumerate() {
        for (px, &p) in row.chunks_exact_mut(3).zip(&plasma[y * MAPSIZE..]) {
            let fog = c0 * p;
            for v in px {
                let x = f64::from(*v) / 255.0 + fog;
                *v = ((x * max / (max + c0)).clamp(0.0, 1.0) * 255.0) as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image_noise::{DrawRun, RecordingDraws, SeededDraws};

    #[test]
    fn the_plasma_makes_the_references_calls_and_spans_zero_to_one() {
        let mut draws = RecordingDraws::new(SeededDraws::new(3));
        let map = plasma_fractal(2.0, &mut draws);
        let sizes: Vec<usize> = draws
            .runs()
            .iter()
            .flat_map(|run| match run {
                DrawRun::Uniform { size: Some(n), calls, .. } => vec![*n; *calls],
                other => panic!("unexpected run {other:?}"),
            })
            .collect();
        let expected: Vec<usize> = (0..8).flat_map(|l| [4usize.pow(l); 3]).collect();
        assert_eq!(sizes, expected);
        assert_eq!(sizes.iter().sum::<usize>(), 65_535);
        let DrawRun::Uniform { low, high, .. } = &draws.runs()[1] else { unreachable!() };
        assert_eq!((*low, *high), (-50.0, 50.0), "wibble 100 / 2 at the second level");
        assert_eq!(map.iter().copied().fold(f64::INFINITY, f64::min), 0.0);
        assert_eq!(map.iter().copied().fold(f64::NEG_INFINITY, f64::max), 1.0);
    }
}
