//! Real-time evaluation (`pipeline run --latency-ms`): the env keeps its control rate while the
//! policy computes, and a hold action fills the steps its answer is late for.
//!
//! vla-eval's live runner (`runners/live_runner.py`) does this on the wall clock: the env steps
//! at `hz` whatever the model does, and a step with no fresh action commands the benchmark's
//! hold (`Benchmark.get_hold_action`). A wall clock makes the number depend on the machine and
//! its load, so here time is virtual: a query that takes `L` ms (fixed, or the measured time of
//! the `act` call) makes the env run `floor(L / period)` steps of the hold action before the
//! answer is applied: the observation goes out as the previous step ends, and the answer is
//! applied by the step during whose period it arrives, as in vla-eval's live runner and its
//! `ActionBuffer`. The wait steps are the protocol's settling, not the policy's time;
//! the clock starts at the first policy step. Held steps are policy steps: the cap is the
//! episode's time budget, and latency spends it.
//!
//! The model is stop-and-wait: the next query is sent when the previous answer's actions have
//! run (a chunked policy's queued actions cost no time), with the observation of that moment.

use serde::{Deserialize, Serialize};

/// How long a model query takes in virtual time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Latency {
    /// Every query takes this long (ms): reproducible on any machine. An `act` that runs no model
    /// (a chunked policy's queued action) takes no time.
    Fixed { ms: f64 },
    /// Every `act` takes the wall time it took on this machine (steps' `policy_ms`): the number a
    /// deployment on this hardware would see, not reproducible elsewhere.
    Measured,
}

/// What the env is commanded on a step whose answer has not arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Hold {
    /// The last action applied again (vla-eval's `repeat_last_hold`, for absolute targets:
    /// ALOHA-sim's joint positions). Before the first answer: `stay`.
    Repeat,
    /// The arm holds where it is and the gripper keeps its last command (open before the first):
    /// LIBERO a zero delta pose, ALOHA-sim the current joints as targets. vla-eval's rule for
    /// delta control, where repeating a delta keeps moving.
    Stay,
}

impl Hold {
    pub fn name(self) -> &'static str {
        match self {
            Hold::Repeat => "repeat",
            Hold::Stay => "stay",
        }
    }

    /// The safe hold of a benchmark's control: `stay` for LIBERO's delta end-effector actions,
    /// `repeat` for ALOHA-sim's absolute joint targets (vla-eval's `get_hold_action` rule).
    pub fn default_for(benchmark: crate::Benchmark) -> Hold {
        match benchmark {
            crate::Benchmark::Libero => Hold::Stay,
            crate::Benchmark::AlohaSim => Hold::Repeat,
        }
    }
}

impl std::str::FromStr for Hold {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "repeat" => Ok(Hold::Repeat),
            "stay" => Ok(Hold::Stay),
            _ => Err(format!("unknown hold {s:?}: use repeat (the last action again) or stay (the arm where it is)")),
        }
    }
}

/// A run's real-time setting, stored in the manifest (`realtime`): part of its configuration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RealTime {
    pub latency: Latency,
    pub hold: Hold,
}

impl RealTime {
    /// Env steps of the hold action before an answer of `latency_ms` is applied, at `control_hz`:
    /// the steps that start before it arrives, after the one that sent the query.
    pub fn held_steps(latency_ms: f64, control_hz: u32) -> u32 {
        // `latency_ms * hz / 1000` keeps whole multiples exact (100 ms at 20 Hz is 2.0, not 1.999…)
        let steps = (latency_ms * control_hz as f64 / 1000.0).floor();
        if steps.is_finite() && steps > 0.0 { steps.min(u32::MAX as f64) as u32 } else { 0 }
    }
}

/// Parse `--latency-ms`: a number of milliseconds (≥ 0, finite) or `measured`.
pub fn parse_latency(s: &str) -> Result<Latency, String> {
    if s == "measured" {
        return Ok(Latency::Measured);
    }
    let ms: f64 = s.parse().map_err(|_| {
        format!("--latency-ms {s:?} is neither a number of milliseconds nor `measured`: e.g. --latency-ms 150, or --latency-ms measured for each query's own time")
    })?;
    if !ms.is_finite() || ms < 0.0 {
        return Err(format!(
            "--latency-ms {s} is not a latency: give 0 or more milliseconds (0 = every answer in time: the closed-loop steps, with the held column), or `measured`"
        ));
    }
    Ok(Latency::Fixed { ms })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_answer_reaches_the_first_step_after_it_arrives() {
        // 20 Hz: 50 ms a step
        assert_eq!(RealTime::held_steps(0.0, 20), 0);
        assert_eq!(RealTime::held_steps(49.9, 20), 0);
        assert_eq!(RealTime::held_steps(50.0, 20), 1);
        assert_eq!(RealTime::held_steps(100.0, 20), 2);
        assert_eq!(RealTime::held_steps(149.99, 20), 2);
        assert_eq!(RealTime::held_steps(182.0, 20), 3);
        // 50 Hz: 20 ms a step
        assert_eq!(RealTime::held_steps(30.0, 50), 1);
        assert_eq!(RealTime::held_steps(60.0, 50), 3);
    }

    #[test]
    fn latencies_parse_and_bad_ones_say_what_to_give() {
        assert_eq!(parse_latency("150"), Ok(Latency::Fixed { ms: 150.0 }));
        assert_eq!(parse_latency("0"), Ok(Latency::Fixed { ms: 0.0 }));
        assert_eq!(parse_latency("measured"), Ok(Latency::Measured));
        for bad in ["-5", "-0.1", "inf", "NaN", "fast", ""] {
            let e = parse_latency(bad).unwrap_err();
            assert!(e.contains("--latency-ms") && e.contains("measured"), "{bad}: {e}");
        }
        assert!(parse_latency("-5").unwrap_err().contains("0 or more milliseconds"));
    }

    #[test]
    fn the_setting_round_trips_through_json() {
        for rt in [
            RealTime { latency: Latency::Fixed { ms: 120.0 }, hold: Hold::Stay },
            RealTime { latency: Latency::Measured, hold: Hold::Repeat },
        ] {
            let text = serde_json::to_string(&rt).unwrap();
            assert_eq!(serde_json::from_str::<RealTime>(&text).unwrap(), rt, "{text}");
        }
    }
}
