//! The Panda gripper controller of robosuite 1.4 (`PandaGripper.format_action` + `grip_action`).
//!
//! Only the *sign* of the gripper action matters: every physics substep moves the command by
//! `speed` (0.01) toward closed (+1) or open (-1), so a full open→close swing takes 8 env steps.
//! The command persists across steps and is reset only by `reset()` (it is not part of the sim
//! state, so an init state cannot restore it).

/// Finger commands in [-1, 1] for the two finger actuators.
#[derive(Debug, Clone, PartialEq)]
pub struct Gripper {
    pub current: [f64; 2],
    reset_value: [f64; 2],
    speed: f64,
}

impl Gripper {
    pub fn new(speed: f64, after_reset: &[f64]) -> Self {
        let reset_value = [after_reset.first().copied().unwrap_or(0.0), after_reset.get(1).copied().unwrap_or(0.0)];
        Gripper { current: reset_value, reset_value, speed }
    }

    pub fn reset(&mut self) {
        self.current = self.reset_value;
    }

    /// One substep: move the command by `speed` in the direction of `sign(action)`.
    pub fn substep(&mut self, action: f64) {
        let sign = if action > 0.0 {
            1.0
        } else if action < 0.0 {
            -1.0
        } else {
            0.0
        };
        for (i, dir) in [-1.0, 1.0].into_iter().enumerate() {
            self.current[i] = (self.current[i] + dir * self.speed * sign).clamp(-1.0, 1.0);
        }
    }

    /// Actuator controls: `bias + weight * current` from each actuator's ctrlrange.
    pub fn controls(&self, ctrlrange: [[f64; 2]; 2]) -> [f64; 2] {
        std::array::from_fn(|i| {
            let [lo, hi] = ctrlrange[i];
            0.5 * (hi + lo) + 0.5 * (hi - lo) * self.current[i]
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closing_from_the_reset_command_takes_four_env_steps_and_only_the_sign_matters() {
        let mut g = Gripper::new(0.01, &[0.0, 0.0]);
        for _ in 0..4 * 25 {
            g.substep(0.3);
        }
        assert_eq!(g.current, [-1.0, 1.0]);
        let mut h = Gripper::new(0.01, &[0.0, 0.0]);
        h.substep(1.0);
        let mut k = Gripper::new(0.01, &[0.0, 0.0]);
        k.substep(1e-9);
        assert_eq!(h, k);
        k.substep(0.0);
        assert_eq!(h, k, "zero holds");
        let ctrl = g.controls([[0.0, 0.04], [-0.04, 0.0]]);
        assert_eq!(ctrl, [0.0, 0.0]);
    }
}
