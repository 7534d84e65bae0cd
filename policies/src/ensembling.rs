//! Action-chunk ensembling: combining the overlapping predictions of successive chunks into the
//! action the env executes, as the field's harnesses do it.
//!
//! Published numbers depend on the rule, so each is reproduced from its reference's arithmetic
//! (in its precision and order of operations) and named in the policy identity:
//!
//! | rule (`ensemble=`) | reference | when the model is asked | the executed action |
//! |---|---|---|---|
//! | `newest:N`, `average:N`, `ema:A:N` | vla-eval 0.8.0 `model_servers/chunking.py` (`ActionChunkBuffer.push_chunk`, float32) | every N executed actions | the queued actions still ahead, blended with the new chunk's first ones; the new chunk's actions past them queued as they are |
//! | `temporal:K` | lerobot 0.6.1 `ACTTemporalEnsembler` (ACT's temporal ensembling, float32) | every step | every prediction for this step, weights `exp(-K·i)`, i = 0 the oldest |
//! | `adaptive:H:A` | starVLA's (CogACT's) `AdaptiveEnsembler` (float64) | every step | the last H predictions for this step, weights `exp(A·cos(prediction, newest))` |
//!
//! Why `newest/average/ema` take N: vla-eval's server asks its model only once the buffer is
//! empty, so in its request-response path a chunk never meets queued actions and the rule blends
//! nothing. Here the model is asked every N actions (N shorter than the chunk), which is what the
//! rule needs to mean anything; a chunk no longer than N is refused, as is any ensembling of
//! one-action chunks.

use std::collections::VecDeque;
use std::fmt;
use std::str::FromStr;

/// How vla-eval's buffer blends a queued action `old` with the new chunk's action for the same
/// step, `new`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BlendRule {
    /// `new`.
    Newest,
    /// `(old + new) / 2`.
    Average,
    /// `alpha·new + (1 − alpha)·old` (vla-eval's `ema_alpha`, default 0.5).
    Ema { alpha: f64 },
}

/// An ensembling rule and its parameters (the `ensemble=` option of chunked policies).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Ensemble {
    /// vla-eval's `ActionChunkBuffer`: the model is asked every `every` executed actions.
    Blend { rule: BlendRule, every: usize },
    /// ACT's temporal ensembling (lerobot's `ACTTemporalEnsembler`, `temporal_ensemble_coeff`;
    /// ACT's own value is 0.01).
    Temporal { coeff: f64 },
    /// starVLA's adaptive ensembling (`AdaptiveEnsembler(pred_action_horizon, alpha)`; starVLA's
    /// LIBERO client builds it with horizon 3 and alpha 0.1).
    Adaptive { horizon: usize, alpha: f64 },
}

// Parameters are finite (the parser refuses NaN), so equality is an equivalence.
impl Eq for Ensemble {}

impl Ensemble {
    /// Whether the model must be asked before the next action, given how many actions of the last
    /// chunk have run and how many are still queued.
    fn needs_query(&self, executed_since_query: usize, queued: usize) -> bool {
        match self {
            Ensemble::Blend { every, .. } => queued == 0 || executed_since_query >= *every,
            Ensemble::Temporal { .. } | Ensemble::Adaptive { .. } => true,
        }
    }
}

impl Ensemble {
    /// Where the rule comes from, for the run manifest.
    pub fn reference(&self) -> &'static str {
        match self {
            Ensemble::Blend { .. } => {
                "vla-eval 0.8.0 model_servers/chunking.py ActionChunkBuffer.push_chunk (float32), the model asked every N actions"
            }
            Ensemble::Temporal { .. } => {
                "lerobot 0.6.1 ACTTemporalEnsembler (float32), weights exp(-K*i), i = 0 the oldest prediction; the model asked every step"
            }
            Ensemble::Adaptive { .. } => {
                "starVLA AdaptiveEnsembler (float64), weights exp(ALPHA*cos(prediction, newest)) over the last H predictions; the model asked every step"
            }
        }
    }
}

impl fmt::Display for Ensemble {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Ensemble::Blend { rule: BlendRule::Newest, every } => write!(f, "newest:{every}"),
            Ensemble::Blend { rule: BlendRule::Average, every } => write!(f, "average:{every}"),
            Ensemble::Blend { rule: BlendRule::Ema { alpha }, every } => write!(f, "ema:{alpha}:{every}"),
            Ensemble::Temporal { coeff } => write!(f, "temporal:{coeff}"),
            Ensemble::Adaptive { horizon, alpha } => write!(f, "adaptive:{horizon}:{alpha}"),
        }
    }
}

/// What `ensemble=` takes, for error messages.
pub const ENSEMBLE_HELP: &str = "ensemble=newest:N|average:N|ema:ALPHA:N (vla-eval's rules, the model asked every N \
     actions) or temporal:K (ACT's, e.g. temporal:0.01) or adaptive:H:ALPHA (starVLA's, e.g. adaptive:3:0.1)";

impl FromStr for Ensemble {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let bad = |why: &str| format!("ensemble={s}: {why}; expected {ENSEMBLE_HELP}");
        let parts: Vec<&str> = s.split(':').collect();
        let count = |p: &str, what: &str| -> Result<usize, String> {
            p.parse::<usize>().ok().filter(|&n| n >= 1).ok_or_else(|| bad(&format!("{what} must be an integer >= 1")))
        };
        let real = |p: &str, what: &str| -> Result<f64, String> {
            p.parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| bad(&format!("{what} must be a number")))
        };
        match parts[..] {
            ["newest", n] => Ok(Ensemble::Blend { rule: BlendRule::Newest, every: count(n, "N")? }),
            ["average", n] => Ok(Ensemble::Blend { rule: BlendRule::Average, every: count(n, "N")? }),
            ["ema", a, n] => {
                let alpha = real(a, "ALPHA")?;
                if !(0.0..=1.0).contains(&alpha) {
                    return Err(bad("ALPHA must be within [0, 1]"));
                }
                Ok(Ensemble::Blend { rule: BlendRule::Ema { alpha }, every: count(n, "N")? })
            }
            ["temporal", k] => Ok(Ensemble::Temporal { coeff: real(k, "K")? }),
            ["adaptive", h, a] => Ok(Ensemble::Adaptive { horizon: count(h, "H")?, alpha: real(a, "ALPHA")? }),
            _ => Err(bad("unknown rule or wrong number of parameters")),
        }
    }
}

/// One episode's ensembling state over actions `A` (a float32 array: LIBERO's 7 values, ALOHA-sim's 14).
#[derive(Debug, Clone)]
pub(crate) struct Ensembler<A> {
    rule: Ensemble,
    /// Blend: the actions still to execute. Temporal and adaptive: the one action computed.
    queue: VecDeque<A>,
    executed_since_query: usize,
    /// Temporal: the running averages for the steps ahead and how many predictions each holds.
    averages: VecDeque<(A, usize)>,
    /// Temporal: `exp(-K·i)` and its running sums, for the chunk length of the episode's first
    /// chunk (lerobot sizes them from the policy's `chunk_size`).
    weights: Vec<f32>,
    weight_sums: Vec<f32>,
    /// Adaptive: the last `horizon` chunks, oldest first.
    history: VecDeque<Vec<A>>,
}

impl<A: Copy + AsRef<[f32]> + AsMut<[f32]>> Ensembler<A> {
    pub(crate) fn new(rule: Ensemble) -> Self {
        Ensembler {
            rule,
            queue: VecDeque::new(),
            executed_since_query: 0,
            averages: VecDeque::new(),
            weights: Vec::new(),
            weight_sums: Vec::new(),
            history: VecDeque::new(),
        }
    }

    pub(crate) fn reset(&mut self) {
        *self = Self::new(self.rule);
    }

    pub(crate) fn rule(&self) -> Ensemble {
        self.rule
    }

    pub(crate) fn needs_query(&self) -> bool {
        self.rule.needs_query(self.executed_since_query, self.queue.len())
    }

    pub(crate) fn next_action(&mut self) -> Option<A> {
        let action = self.queue.pop_front()?;
        self.executed_since_query += 1;
        Some(action)
    }

    /// Take a new chunk (the model was asked because [`Self::needs_query`] said so).
    pub(crate) fn push_chunk(&mut self, chunk: &[A]) -> Result<(), String> {
        let rule = self.rule;
        let refuse = move |why: String| format!("ensemble={rule}: {why}");
        if chunk.len() < 2 {
            return Err(refuse(format!(
                "the model's chunk holds {} action(s), and ensembling needs chunks of several; run it without ensemble=",
                chunk.len()
            )));
        }
        self.executed_since_query = 0;
        match self.rule {
            Ensemble::Blend { rule, every } => {
                if chunk.len() <= every {
                    return Err(refuse(format!(
                        "the model's chunk holds {} actions, so asking it every {every} leaves nothing to blend; \
                         choose N below {}",
                        chunk.len(),
                        chunk.len()
                    )));
                }
                blend_into(&mut self.queue, chunk, rule);
            }
            Ensemble::Temporal { coeff } => {
                let action = self.temporal(chunk, coeff).map_err(refuse)?;
                self.queue = VecDeque::from([action]);
            }
            Ensemble::Adaptive { horizon, alpha } => {
                let action = self.adaptive(chunk, horizon, alpha).map_err(refuse)?;
                self.queue = VecDeque::from([action]);
            }
        }
        Ok(())
    }

    /// lerobot's `ACTTemporalEnsembler.update` for one episode, in float32 and its order of
    /// operations: the running average of step j holding n predictions becomes
    /// `(avg·Σw[..n] + new·w[n]) / Σw[..=n]`, each operation rounded to float32.
    fn temporal(&mut self, chunk: &[A], coeff: f64) -> Result<A, String> {
        if self.weights.is_empty() {
            // torch: exp of (-coeff · arange) in float32; cumsum accumulates in double on the CPU.
            let neg = (-coeff) as f32;
            self.weights = (0..chunk.len()).map(|i| (neg * i as f32).exp()).collect();
            let mut sum = 0.0f64;
            self.weight_sums = self
                .weights
                .iter()
                .map(|&w| {
                    sum += f64::from(w);
                    sum as f32
                })
                .collect();
        }
        let size = self.weights.len();
        if chunk.len() != size {
            return Err(format!(
                "the model's chunks changed length ({size}, then {}); temporal ensembling needs one length",
                chunk.len()
            ));
        }
        if self.averages.is_empty() {
            self.averages = chunk.iter().map(|a| (*a, 1)).collect();
        } else {
            for (j, (average, n)) in self.averages.iter_mut().enumerate() {
                let (before, weight, after) = (self.weight_sums[*n - 1], self.weights[*n], self.weight_sums[*n]);
                for (x, &new) in average.as_mut().iter_mut().zip(chunk[j].as_ref()) {
                    *x *= before;
                    *x += new * weight;
                    *x /= after;
                }
                *n = (*n + 1).min(size);
            }
            self.averages.push_back((chunk[size - 1], 1));
        }
        Ok(self.averages.pop_front().expect("a chunk of several actions").0)
    }

    /// starVLA's `AdaptiveEnsembler.ensemble_action` for one episode, in float64: the prediction
    /// made i steps ago contributes its action i; weights `exp(alpha·cos)` against the newest
    /// prediction's first action, normalised.
    fn adaptive(&mut self, chunk: &[A], horizon: usize, alpha: f64) -> Result<A, String> {
        if self.history.len() == horizon {
            self.history.pop_front();
        }
        self.history.push_back(chunk.to_vec());
        let n = self.history.len();
        if let Some(short) = self.history.iter().enumerate().find(|(i, c)| c.len() < n - i) {
            return Err(format!(
                "a chunk of {} actions cannot cover the {} steps of the ensembling horizon {horizon}",
                short.1.len(),
                n - short.0
            ));
        }
        let aligned: Vec<Vec<f64>> = self
            .history
            .iter()
            .enumerate()
            .map(|(i, c)| c[n - 1 - i].as_ref().iter().map(|&x| f64::from(x)).collect())
            .collect();
        let reference = &aligned[n - 1];
        let norm = |a: &[f64]| a.iter().map(|x| x * x).sum::<f64>().sqrt();
        let reference_norm = norm(reference);
        let weights: Vec<f64> = aligned
            .iter()
            .map(|a| {
                let dot: f64 = a.iter().zip(reference).map(|(x, r)| x * r).sum();
                (alpha * (dot / (norm(a) * reference_norm + 1e-7))).exp()
            })
            .collect();
        let total: f64 = weights.iter().sum();
        let mut sum = vec![0.0f64; reference.len()];
        for (a, w) in aligned.iter().zip(&weights) {
            for (x, v) in sum.iter_mut().zip(a) {
                *x += w / total * v;
            }
        }
        let mut action = chunk[0];
        for (x, s) in action.as_mut().iter_mut().zip(sum) {
            *x = s as f32;
        }
        Ok(action)
    }
}

/// vla-eval's `ActionChunkBuffer.push_chunk`: the queued actions and the new chunk overlap for the
/// shorter of the two; the overlap is blended, the new chunk's rest queued as it is, and queued
/// actions past the new chunk's end dropped (its code does so, though its docstring keeps them).
fn blend_into<A: Copy + AsRef<[f32]> + AsMut<[f32]>>(queue: &mut VecDeque<A>, chunk: &[A], rule: BlendRule) {
    let remaining: Vec<A> = queue.drain(..).collect();
    let overlap = remaining.len().min(chunk.len());
    for (old, new) in remaining[..overlap].iter().zip(chunk) {
        let mut blended = *new;
        for ((x, &o), &n) in blended.as_mut().iter_mut().zip(old.as_ref()).zip(new.as_ref()) {
            *x = blend(o, n, rule);
        }
        queue.push_back(blended);
    }
    queue.extend(&chunk[overlap..]);
}

/// One value of vla-eval's ensemble functions on float32 arrays (NumPy casts the Python float
/// parameters to float32 and rounds each operation to float32).
fn blend(old: f32, new: f32, rule: BlendRule) -> f32 {
    match rule {
        BlendRule::Newest => new,
        BlendRule::Average => (old + new) / 2.0,
        BlendRule::Ema { alpha } => alpha as f32 * new + (1.0 - alpha) as f32 * old,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chunk(start: f32, n: usize) -> Vec<[f32; 2]> {
        (0..n).map(|i| [start + i as f32, -(start + i as f32)]).collect()
    }

    #[test]
    fn the_rules_parse_print_and_refuse_what_they_cannot_mean() {
        for text in ["newest:2", "average:4", "ema:0.3:2", "temporal:0.01", "adaptive:3:0.1"] {
            assert_eq!(text.parse::<Ensemble>().unwrap().to_string(), text);
        }
        for bad in ["average", "average:0", "ema:1.5:2", "temporal:nan", "adaptive:0:0.1", "median:2"] {
            let err = bad.parse::<Ensemble>().unwrap_err();
            assert!(err.contains(bad) && err.contains("temporal:K"), "{err}");
        }
    }

    #[test]
    fn blending_asks_every_n_actions_and_blends_the_overlap() {
        let mut e = Ensembler::<[f32; 2]>::new("average:2".parse().unwrap());
        assert!(e.needs_query());
        e.push_chunk(&chunk(0.0, 4)).unwrap();
        assert_eq!([e.next_action().unwrap()[0], e.next_action().unwrap()[0]], [0.0, 1.0]);
        assert!(e.needs_query(), "asked again after 2 of 4 actions");
        e.push_chunk(&chunk(10.0, 4)).unwrap();
        // Queued 2, 3 meet the new 10, 11; the new 12, 13 follow as they are.
        let rest: Vec<f32> = std::iter::from_fn(|| e.next_action()).map(|a| a[0]).collect();
        assert_eq!(rest, [6.0, 7.0, 12.0, 13.0]);
    }

    #[test]
    fn chunks_too_short_to_ensemble_are_refused_with_the_fix() {
        let err = Ensembler::<[f32; 2]>::new("newest:4".parse().unwrap()).push_chunk(&chunk(0.0, 4)).unwrap_err();
        assert!(err.contains("choose N below 4"), "{err}");
        let err = Ensembler::<[f32; 2]>::new("temporal:0.01".parse().unwrap()).push_chunk(&chunk(0.0, 1)).unwrap_err();
        assert!(err.contains("1 action(s)") && err.contains("without ensemble="), "{err}");
    }

    #[test]
    fn temporal_ensembling_with_no_decay_is_the_plain_mean_of_the_predictions() {
        let mut e = Ensembler::<[f32; 2]>::new("temporal:0".parse().unwrap());
        let mut executed = Vec::new();
        for step in 0..3 {
            e.push_chunk(&chunk(10.0 * step as f32, 3)).unwrap();
            executed.push(e.next_action().unwrap()[0]);
        }
        // Step 1: predictions 1 (made at 0) and 10; step 2: 2, 11 and 20.
        assert_eq!(executed, [0.0, 5.5, 11.0]);
    }

    #[test]
    fn adaptive_ensembling_weighs_equal_predictions_equally() {
        let mut e = Ensembler::<[f32; 2]>::new("adaptive:2:0.1".parse().unwrap());
        e.push_chunk(&chunk(0.0, 3)).unwrap();
        assert_eq!(e.next_action().unwrap(), [0.0, -0.0]);
        e.push_chunk(&chunk(1.0, 3)).unwrap();
        // The old chunk's action 1 equals the new chunk's action 0: the ensemble is that action.
        let a = e.next_action().unwrap();
        assert!((a[0] - 1.0).abs() < 1e-6 && (a[1] + 1.0).abs() < 1e-6, "{a:?}");
    }
}
