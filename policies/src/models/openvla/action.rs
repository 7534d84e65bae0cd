//! OpenVLA's action tokens: the last `n_action_bins` ids of the Llama vocabulary (before OpenVLA's
//! padding) stand for the bins of `linspace(-1, 1, n_action_bins)`; token `t` decodes to bin
//! `clip(vocab_size - t - 1, 0, n_action_bins - 2)` and then to that bin's center (prismatic's
//! `predict_action`). Ids outside the action range saturate at the first or last bin, as in Python.

/// The bin centers and the vocabulary they sit at the end of.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionBins {
    vocab_size: i64,
    centers: Vec<f64>,
}

impl ActionBins {
    /// `vocab_size`: the unpadded vocabulary (32000 for Llama-2); `n_bins`: `n_action_bins` (256).
    pub fn new(vocab_size: i64, n_bins: usize) -> Self {
        // numpy's linspace: i * step + start, the last one set to stop
        let step = 2.0 / (n_bins as f64 - 1.0);
        let mut bins: Vec<f64> = (0..n_bins).map(|i| i as f64 * step - 1.0).collect();
        if let Some(last) = bins.last_mut() {
            *last = 1.0;
        }
        let centers = bins.windows(2).map(|w| (w[0] + w[1]) / 2.0).collect();
        ActionBins { vocab_size, centers }
    }

    /// The bin index of a generated token.
    pub fn bin(&self, token: i64) -> usize {
        (self.vocab_size - token - 1).clamp(0, self.centers.len() as i64 - 1) as usize
    }

    /// The normalized action value of a bin, in [-1, 1].
    pub fn center(&self, bin: usize) -> f64 {
        self.centers[bin]
    }

    pub fn num_centers(&self) -> usize {
        self.centers.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn llama2_action_tokens_decode_to_bin_centers() {
        let bins = ActionBins::new(32000, 256);
        assert_eq!(bins.num_centers(), 255);
        assert_eq!(bins.bin(31999), 0);
        assert!((bins.center(0) - (-1.0 + 1.0 / 255.0)).abs() < 1e-15);
        assert_eq!(bins.bin(31744), 254, "the 256th action token clips to the last of the 255 centers");
        assert_eq!(bins.bin(31745), 254);
        assert_eq!(bins.bin(31746), 253);
        assert!((bins.center(254) - (1.0 - 1.0 / 255.0)).abs() < 1e-15);
        // tokens outside the action range saturate, as numpy's clip does
        assert_eq!(bins.bin(32000), 0);
        assert_eq!(bins.bin(32063), 0);
        assert_eq!(bins.bin(29871), 254);
        assert_eq!(bins.bin(0), 254);
    }

    #[test]
    fn centers_match_numpy_linspace() {
        // (linspace(-1, 1, 256)[:-1] + linspace(-1, 1, 256)[1:]) / 2, numpy's values
        let bins = ActionBins::new(32000, 256);
        assert_eq!(bins.center(25), -0.8);
        assert_eq!(bins.center(169), 0.3294117647058823);
        assert_eq!(bins.center(111), -0.12549019607843137);
        assert_eq!(bins.center(127), 0.0);
        assert_eq!(bins.center(0), -0.996078431372549);
        assert_eq!(bins.center(254), 0.996078431372549);
    }
}
