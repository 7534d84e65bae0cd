//! Action chunks: a model predicts several actions at once and the loop executes some of them
//! before asking again.
//!
//! The published loops differ here and it moves their numbers: openpi's LIBERO example executes 5
//! of the 10 actions π0 predicts (`replan_steps = 5`), OpenVLA-OFT executes all 8 of its chunk,
//! OpenVLA predicts one. The rollout asks a policy for one action per env step; a chunked policy
//! keeps an [`ActionChunker`], asks its model only when the chunker is empty, and records both
//! lengths (predicted and executed) in its identity, since they are separate choices. With an
//! [`Ensemble`] rule (`ensemble=`), the chunker asks as that rule needs and combines overlapping
//! chunks by it ([`crate::ensembling`]).

use crate::Action;
use crate::ensembling::{Ensemble, Ensembler};
use std::collections::VecDeque;

/// The queue of a chunk's actions still to execute; `A` is the benchmark's action (LIBERO's
/// 7-D [`Action`] by default, ALOHA-sim's 14-D [`crate::aloha::AlohaAction`]).
#[derive(Debug, Clone)]
pub struct ActionChunker<A = Action> {
    replan_steps: usize,
    queue: VecDeque<A>,
    /// Length of the last chunk the model predicted (None before the first).
    last_predicted: Option<usize>,
    queries: u64,
    /// Set by `ensemble=`: it decides when to ask and what runs, in place of `queue`.
    ensembler: Option<Ensembler<A>>,
}

impl<A: Copy + AsRef<[f32]> + AsMut<[f32]>> ActionChunker<A> {
    /// Execute at most `replan_steps` (≥ 1) actions of each predicted chunk.
    pub fn new(replan_steps: usize) -> Self {
        ActionChunker {
            replan_steps: replan_steps.max(1),
            queue: VecDeque::new(),
            last_predicted: None,
            queries: 0,
            ensembler: None,
        }
    }

    /// Combine overlapping chunks by `ensemble` (asking the model as it needs) instead of executing
    /// `replan_steps` of each; `None`: no ensembling. Set before an episode.
    pub fn set_ensemble(&mut self, ensemble: Option<Ensemble>) {
        self.ensembler = ensemble.map(Ensembler::new);
        self.queue.clear();
    }

    /// The ensembling rule, if any.
    pub fn ensemble(&self) -> Option<Ensemble> {
        self.ensembler.as_ref().map(Ensembler::rule)
    }

    /// Forget the queue (a new episode).
    pub fn reset(&mut self) {
        self.queue.clear();
        self.last_predicted = None;
        self.queries = 0;
        if let Some(e) = &mut self.ensembler {
            e.reset();
        }
    }

    /// The model must be asked before the next action.
    pub fn needs_query(&self) -> bool {
        match &self.ensembler {
            Some(e) => e.needs_query(),
            None => self.queue.is_empty(),
        }
    }

    /// Queue the first `replan_steps` actions of a predicted chunk. A chunk shorter than
    /// `replan_steps` is executed whole (and then the model is asked again); an empty chunk is an
    /// error, since the loop would have no action.
    pub fn push_chunk(&mut self, chunk: Vec<A>) -> Result<(), String> {
        if chunk.is_empty() {
            return Err("the model returned an empty action chunk".into());
        }
        self.last_predicted = Some(chunk.len());
        self.queries += 1;
        if let Some(e) = &mut self.ensembler {
            return e.push_chunk(&chunk);
        }
        self.queue.clear();
        self.queue.extend(chunk.into_iter().take(self.replan_steps));
        Ok(())
    }

    /// The next action to execute, if any is queued.
    pub fn next_action(&mut self) -> Option<A> {
        match &mut self.ensembler {
            Some(e) => e.next_action(),
            None => self.queue.pop_front(),
        }
    }

    pub fn replan_steps(&self) -> usize {
        self.replan_steps
    }

    pub fn last_predicted(&self) -> Option<usize> {
        self.last_predicted
    }

    /// Model queries since the last reset.
    pub fn queries(&self) -> u64 {
        self.queries
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chunk(n: usize) -> Vec<Action> {
        (0..n).map(|i| [i as f32; 7]).collect()
    }

    #[test]
    fn executes_replan_steps_of_each_chunk_then_asks_again() {
        let mut c = ActionChunker::new(5);
        assert!(c.needs_query());
        c.push_chunk(chunk(10)).unwrap();
        let executed: Vec<f32> = std::iter::from_fn(|| c.next_action()).map(|a| a[0]).collect();
        assert_eq!(executed, [0.0, 1.0, 2.0, 3.0, 4.0]);
        assert!(c.needs_query());
        assert_eq!((c.last_predicted(), c.replan_steps(), c.queries()), (Some(10), 5, 1));
    }

    #[test]
    fn a_short_chunk_runs_whole_and_an_empty_one_is_an_error() {
        let mut c = ActionChunker::new(8);
        c.push_chunk(chunk(3)).unwrap();
        assert_eq!(std::iter::from_fn(|| c.next_action()).count(), 3);
        assert!(c.push_chunk(vec![]).is_err());
        c.reset();
        assert_eq!((c.last_predicted(), c.queries()), (None, 0));
    }
}
