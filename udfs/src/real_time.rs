//! An episode's real-time clock ([`libero_schema::real_time`]): at each policy step, whether the
//! episode loop asks the policy, commands the hold action, or applies an answer that has now
//! arrived; and each benchmark's hold action.
//!
//! The loops (`episode`, `aloha_episode`) own the env and the policy; this module only keeps time,
//! so a closed-loop run (no clock) steps exactly as before.

use libero_policies::aloha::AlohaAction;
use libero_schema::protocol::WAIT_ACTION;
use libero_schema::real_time::{Hold, Latency, RealTime};

/// What a policy step does under the clock.
#[derive(Debug)]
pub enum Tick<A, C> {
    /// Ask the policy (no answer is outstanding).
    Query,
    /// Command the hold action: the outstanding answer has not arrived.
    Hold,
    /// Apply this answer, which arrived during the previous step; `C` is what its query cost
    /// (timings), stored with this step.
    Answer(A, C),
}

/// An answer on its way: applied after `holds_left` more held steps.
struct Outstanding<A, C> {
    action: A,
    cost: C,
    holds_left: u32,
}

/// The clock of one episode: `A` the action, `C` the query's cost as the steps table stores it.
pub struct RealTimeClock<A, C> {
    setting: RealTime,
    control_hz: u32,
    outstanding: Option<Outstanding<A, C>>,
}

impl<A, C> RealTimeClock<A, C> {
    pub fn new(setting: RealTime, control_hz: u32) -> Self {
        RealTimeClock { setting, control_hz, outstanding: None }
    }

    pub fn hold(&self) -> Hold {
        self.setting.hold
    }

    /// What this policy step does.
    pub fn tick(&mut self) -> Tick<A, C> {
        match self.outstanding.take() {
            None => Tick::Query,
            Some(o) if o.holds_left == 0 => Tick::Answer(o.action, o.cost),
            Some(mut o) => {
                o.holds_left -= 1;
                self.outstanding = Some(o);
                Tick::Hold
            }
        }
    }

    /// The latency of the query just made: the fixed one where the `act` ran the model (nothing
    /// for a queued action), or the call's measured wall time.
    pub fn latency_ms(&self, queried_model: bool, measured_ms: f64) -> f64 {
        match self.setting.latency {
            Latency::Fixed { ms } => {
                if queried_model {
                    ms
                } else {
                    0.0
                }
            }
            Latency::Measured => measured_ms,
        }
    }

    /// The policy answered `action` at this step after `latency_ms`. Returns it back when it is
    /// in time for this step; otherwise keeps it (this step and `held - 1` more hold, then
    /// [`Tick::Answer`]) and returns None.
    pub fn answered(&mut self, action: A, cost: C, latency_ms: f64) -> Option<(A, C)> {
        match RealTime::held_steps(latency_ms, self.control_hz) {
            0 => Some((action, cost)),
            held => {
                self.outstanding = Some(Outstanding { action, cost, holds_left: held - 1 });
                None
            }
        }
    }
}

/// LIBERO's hold after `last` (the last policy action applied; None before the first): `repeat`
/// commands it again; `stay` (and `repeat` before the first answer) a zero delta pose with the
/// gripper's last command (open, as in the wait steps, before the first).
pub fn libero_hold(hold: Hold, last: Option<&[f32; 7]>) -> [f32; 7] {
    match (hold, last) {
        (Hold::Repeat, Some(a)) => *a,
        (_, last) => {
            let mut a = [0.0; 7];
            a[6] = last.map_or(WAIT_ACTION[6], |l| l[6]);
            a
        }
    }
}

/// ALOHA-sim's hold: `repeat` the last action (absolute targets, so the arms hold them); `stay`
/// (and `repeat` before the first answer) the joints where they are (`agent_pos`) as targets, each
/// gripper keeping its last command (before the first: where it is).
pub fn aloha_hold(hold: Hold, last: Option<&AlohaAction>, agent_pos: &[f64; 14]) -> AlohaAction {
    match (hold, last) {
        (Hold::Repeat, Some(a)) => *a,
        (_, last) => {
            let mut a: AlohaAction = agent_pos.map(|q| q as f32);
            if let Some(l) = last {
                for gripper in [6, 13] {
                    a[gripper] = l[gripper];
                }
            }
            a
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clock(ms: f64) -> RealTimeClock<u32, ()> {
        RealTimeClock::new(RealTime { latency: Latency::Fixed { ms }, hold: Hold::Stay }, 20)
    }

    /// The step pattern of a fixed 120 ms latency at 20 Hz: each query's step and the next hold,
    /// the answer runs on the step after.
    #[test]
    fn an_answer_late_by_two_steps_runs_on_the_third() {
        let mut c = clock(120.0);
        let mut pattern = String::new();
        for answer in 0..3u32 {
            assert!(matches!(c.tick(), Tick::Query));
            let latency = c.latency_ms(true, 0.0);
            assert!(c.answered(answer, (), latency).is_none());
            pattern.push('q');
            assert!(matches!(c.tick(), Tick::Hold));
            pattern.push('h');
            match c.tick() {
                Tick::Answer(a, ()) => assert_eq!(a, answer),
                other => panic!("{other:?}"),
            }
            pattern.push('a');
        }
        assert_eq!(pattern, "qhaqhaqha");
    }

    #[test]
    fn an_answer_in_time_and_a_queued_action_run_at_once() {
        let mut c = clock(49.0);
        assert!(matches!(c.tick(), Tick::Query));
        assert_eq!(c.answered(7, (), c.latency_ms(true, 0.0)), Some((7, ())));
        let mut c = clock(500.0);
        // a chunk's queued action: no model, no latency
        assert_eq!(c.latency_ms(false, 0.01), 0.0);
        assert_eq!(c.answered(8, (), 0.0), Some((8, ())));
        let measured: RealTimeClock<u32, ()> =
            RealTimeClock::new(RealTime { latency: Latency::Measured, hold: Hold::Stay }, 20);
        assert_eq!(measured.latency_ms(false, 181.0), 181.0);
    }

    #[test]
    fn holds_keep_the_gripper_and_repeat_repeats() {
        let last = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 1.0];
        assert_eq!(libero_hold(Hold::Stay, None), [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]);
        assert_eq!(libero_hold(Hold::Stay, Some(&last)), [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        assert_eq!(libero_hold(Hold::Repeat, Some(&last)), last);
        assert_eq!(libero_hold(Hold::Repeat, None), libero_hold(Hold::Stay, None));
        let pos: [f64; 14] = std::array::from_fn(|i| i as f64 / 10.0);
        let a = aloha_hold(Hold::Stay, None, &pos);
        assert_eq!(a, pos.map(|q| q as f32));
        let last: AlohaAction = [9.0; 14];
        let a = aloha_hold(Hold::Stay, Some(&last), &pos);
        assert_eq!((a[0], a[6], a[12], a[13]), (0.0, 9.0, 1.2, 9.0));
        assert_eq!(aloha_hold(Hold::Repeat, Some(&last), &pos), last);
    }
}
