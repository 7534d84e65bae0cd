//! numpy's legacy `RandomState(seed).uniform(low, high)`, bit for bit.
//!
//! gym-aloha draws each episode's object poses with `np.random.RandomState(seed).uniform(...)`
//! (`gym_aloha/utils.py`), and lerobot's protocol seeds episode `i` with `1000 + i`. To start the
//! same episodes without Python, this is numpy's MT19937 (`mt19937_seed`, `mt19937_gen`) and its
//! legacy `random_sample` (`(a >> 5) · 2²⁶ + (b >> 6)) / 2⁵³` from two 32-bit outputs), with
//! `uniform` computed as numpy does: `low + (high − low) · u`, no fused multiply-add. The tests
//! check it against the poses numpy drew for every protocol seed (the bundle's `init_poses.json`).

/// MT19937 state size (`RK_STATE_LEN`).
const N: usize = 624;
const M: usize = 397;
const MATRIX_A: u32 = 0x9908_b0df;
const UPPER_MASK: u32 = 0x8000_0000;
const LOWER_MASK: u32 = 0x7fff_ffff;

/// numpy's `RandomState` seeded with an integer (its legacy seeding path).
#[derive(Clone)]
pub struct RandomState {
    key: [u32; N],
    pos: usize,
}

impl RandomState {
    /// `np.random.RandomState(seed)`: numpy accepts 0 ..= 2³² − 1, which `u32` spells.
    pub fn new(seed: u32) -> Self {
        let mut key = [0u32; N];
        let mut s = seed;
        for (pos, k) in key.iter_mut().enumerate() {
            *k = s;
            s = 1_812_433_253u32.wrapping_mul(s ^ (s >> 30)).wrapping_add(pos as u32 + 1);
        }
        RandomState { key, pos: N }
    }

    /// The next tempered 32-bit output (`mt19937_next`).
    pub fn next_u32(&mut self) -> u32 {
        if self.pos >= N {
            self.generate();
        }
        let mut y = self.key[self.pos];
        self.pos += 1;
        y ^= y >> 11;
        y ^= (y << 7) & 0x9d2c_5680;
        y ^= (y << 15) & 0xefc6_0000;
        y ^= y >> 18;
        y
    }

    /// `random_sample()`: a double in [0, 1) with 53 random bits (`mt19937_next_double`).
    pub fn next_double(&mut self) -> f64 {
        let a = (self.next_u32() >> 5) as f64;
        let b = (self.next_u32() >> 6) as f64;
        (a * 67_108_864.0 + b) / 9_007_199_254_740_992.0
    }

    /// `uniform(low, high)` for arrays: one draw per element, in order (a zero-width range still
    /// consumes its draw, as numpy's does).
    pub fn uniform<const K: usize>(&mut self, low: [f64; K], high: [f64; K]) -> [f64; K] {
        std::array::from_fn(|i| {
            let range = high[i] - low[i];
            low[i] + range * self.next_double()
        })
    }

    /// `mt19937_gen`: regenerate the whole state.
    fn generate(&mut self) {
        let k = &mut self.key;
        for i in 0..N {
            let y = (k[i] & UPPER_MASK) | (k[(i + 1) % N] & LOWER_MASK);
            let mag = if y & 1 == 1 { MATRIX_A } else { 0 };
            k[i] = k[(i + M) % N] ^ (y >> 1) ^ mag;
        }
        self.pos = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_outputs_are_the_reference_mt19937s() {
        // The reference MT19937 (Matsumoto & Nishimura's mt19937ar.c) seeded by init_genrand(5489):
        // its first outputs are 3499211612, 581869302, 3890346734.
        let mut r = RandomState::new(5489);
        assert_eq!([r.next_u32(), r.next_u32(), r.next_u32()], [3_499_211_612, 581_869_302, 3_890_346_734]);
        // The 10000th output of the default seed (the C++ standard's check of std::mt19937).
        let mut r = RandomState::new(5489);
        let last = (0..10_000).map(|_| r.next_u32()).last().unwrap();
        assert_eq!(last, 4_123_659_995);
    }

    #[test]
    fn random_sample_matches_numpy() {
        // np.random.RandomState(0).random_sample() == 0.5488135039273248
        assert_eq!(RandomState::new(0).next_double(), 0.548_813_503_927_324_8);
    }
}
