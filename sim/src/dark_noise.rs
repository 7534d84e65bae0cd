//! LIBERO-PRO's `dark_noise` observation transform (`perturbation-spec.md` §C2, `observation`
//! block): every camera image the policy sees is dimmed and given Gaussian noise,
//! `uint8(clip(float32(img) · brightness + N(0, σ), 0, 255))`, truncating as numpy's `astype` does.
//!
//! The reference draws the noise from `default_rng(seed + camera index + brightness)` with a seed
//! its caller holds constant across steps, so each camera's noise pattern is frozen for the whole
//! episode. We keep that: one field per (episode, camera), drawn from a generator seeded by the
//! caller (the episode key), so the pattern is deterministic and paired across policies; numpy's
//! PCG64 stream itself is not reproduced (the parity test injects the reference's draws instead).

use crate::image_noise::{NoiseDraws, SeededDraws};

/// The shipped `dark_noise` of LIBERO-PRO's `visual_noise_glare` case.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DarkNoise {
    /// Multiplies every channel (0.68 shipped).
    pub brightness: f32,
    /// Standard deviation of the additive noise, in 8-bit levels (12.0 shipped).
    pub std: f64,
}

impl DarkNoise {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.brightness.is_finite() && (0.0..=4.0).contains(&self.brightness)) {
            return Err(format!("image_brightness = {} is out of range [0, 4]", self.brightness));
        }
        if !(self.std.is_finite() && (0.0..=255.0).contains(&self.std)) {
            return Err(format!("image_noise_std = {} is out of range [0, 255] (8-bit levels)", self.std));
        }
        Ok(())
    }

    /// The noise field of one camera: `len` standard normals scaled by σ (Box–Muller on the
    /// seeded generator's uniforms).
    pub fn field(&self, seed: u64, len: usize) -> Vec<f64> {
        let mut draws = SeededDraws::new(seed);
        let mut u = vec![0.0; len + len % 2];
        draws.uniform_batch(0.0, 1.0, &mut u);
        let mut out = Vec::with_capacity(u.len());
        for pair in u.chunks_exact(2) {
            // 1 - u lies in (0, 1]: its log is finite
            let r = (-2.0 * (1.0 - pair[0]).ln()).sqrt();
            let t = std::f64::consts::TAU * pair[1];
            out.push(self.std * r * t.cos());
            out.push(self.std * r * t.sin());
        }
        out.truncate(len);
        out
    }

    /// Dim `rgb` and add `noise` (one value per byte, as [`field`](Self::field) draws it or as the
    /// reference drew it).
    pub fn apply(&self, rgb: &mut [u8], noise: &[f64]) -> Result<(), String> {
        if noise.len() != rgb.len() {
            return Err(format!("dark noise: {} noise values for an image of {} bytes", noise.len(), rgb.len()));
        }
        for (px, n) in rgb.iter_mut().zip(noise) {
            // float32(img) * b stays float32 (a Python float is weak); + float64 noise is float64
            let v = f64::from(f32::from(*px) * self.brightness) + n;
            *px = v.clamp(0.0, 255.0) as u8;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_field_has_the_requested_spread_and_is_seeded() {
        let d = DarkNoise { brightness: 0.68, std: 12.0 };
        let f = d.field(7, 100_001);
        assert_eq!(f.len(), 100_001);
        let mean = f.iter().sum::<f64>() / f.len() as f64;
        let sd = (f.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / f.len() as f64).sqrt();
        assert!(mean.abs() < 0.2 && (sd - 12.0).abs() < 0.2, "mean {mean}, sd {sd}");
        assert_eq!(f, d.field(7, 100_001));
        assert_ne!(f[..10], d.field(8, 10)[..]);
    }

    #[test]
    fn dimming_truncates_and_clips_like_numpy() {
        let d = DarkNoise { brightness: 0.68, std: 0.0 };
        let mut img = [0u8, 1, 100, 255, 255, 10];
        d.apply(&mut img, &[0.0, 0.0, 0.0, 0.0, 200.0, -100.0]).unwrap();
        // 100 * 0.68f32 = 68.0000030517578 -> 68; 255 * 0.68 = 173.4 -> 173; clipped at 255 and 0
        assert_eq!(img, [0, 0, 68, 173, 255, 0]);
    }
}
