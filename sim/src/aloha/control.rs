//! From a policy's 14-D action to the 16 position actuators, and from the joints back to the
//! 14-D `agent_pos`: gym-aloha's `BimanualViperXTask.before_step` and `get_qpos`.
//!
//! The action is, per arm (left, then right), 6 absolute joint targets and one normalized gripper
//! value `x`; the two finger slides get `±(x · (0.058 − 0.01844) + 0.01844)`
//! (`PUPPET_GRIPPER_POSITION_UNNORMALIZE`), which MuJoCo then clamps to the fingers' ctrlrange.
//! Nothing else is clipped. The arithmetic is numpy 1.26's: the f32 action's gripper component
//! promoted to f64 before the affine map (numpy 2 would compute it in f32 and differ by ~1e-9,
//! aloha-sim.md §2), the arm targets widened exactly.

/// Joint positions (and controls) of both arms at reset: per arm `waist, shoulder, elbow,
/// forearm_roll, wrist_angle, wrist_rotate, left_finger, right_finger` (`constants.START_ARM_POSE`).
pub const START_ARM_POSE: [f64; 16] =
    [0.0, -0.96, 1.16, 0.0, -0.3, 0.0, 0.02239, -0.02239, 0.0, -0.96, 1.16, 0.0, -0.3, 0.0, 0.02239, -0.02239];

/// `PUPPET_GRIPPER_POSITION_OPEN` and `_CLOSE`: the finger slide positions of normalized 1 and 0.
pub const GRIPPER_OPEN: f64 = 0.058;
pub const GRIPPER_CLOSE: f64 = 0.01844;

/// Joints (= actuators) of the two arms, before the objects' free joints.
pub const ARM_QPOS: usize = 16;
/// Components of an action and of `agent_pos`.
pub const ACTION_DIM: usize = 14;

/// `unnormalize_puppet_gripper_position`: normalized gripper value → finger slide position.
pub fn unnormalize_gripper(x: f64) -> f64 {
    x * (GRIPPER_OPEN - GRIPPER_CLOSE) + GRIPPER_CLOSE
}

/// `normalize_puppet_gripper_position`: finger slide position → normalized gripper value.
pub fn normalize_gripper(q: f64) -> f64 {
    (q - GRIPPER_CLOSE) / (GRIPPER_OPEN - GRIPPER_CLOSE)
}

/// The control vector `before_step` writes: `[a0..a5, g(a6), −g(a6), a7..a12, g(a13), −g(a13)]`.
pub fn action_to_ctrl(action: &[f32; ACTION_DIM]) -> [f64; ARM_QPOS] {
    let mut ctrl = [0.0; ARM_QPOS];
    for arm in 0..2 {
        let (a, c) = (&action[7 * arm..7 * arm + 7], &mut ctrl[8 * arm..8 * arm + 8]);
        for (target, &joint) in c[..6].iter_mut().zip(&a[..6]) {
            *target = joint as f64;
        }
        let g = unnormalize_gripper(a[6] as f64);
        c[6] = g;
        c[7] = -g;
    }
    ctrl
}

/// `get_qpos`: each arm's 6 joints and its normalized left-finger position.
pub fn agent_pos(qpos: &[f64]) -> [f64; ACTION_DIM] {
    let mut out = [0.0; ACTION_DIM];
    for arm in 0..2 {
        out[7 * arm..7 * arm + 6].copy_from_slice(&qpos[8 * arm..8 * arm + 6]);
        out[7 * arm + 6] = normalize_gripper(qpos[8 * arm + 6]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gripper_map_is_numpy_126s_float64_arithmetic() {
        // aloha-sim.md §2: numpy 1.26 maps the f32 action 0.1 to 0.022396000058948994
        // (numpy 2.x: 0.022396002, in float32).
        let g = unnormalize_gripper(0.1f32 as f64);
        assert_eq!(g, 0.022396000058948994);
        let mut a = [0.0f32; ACTION_DIM];
        a[6] = 0.1;
        a[13] = 1.0;
        a[0] = 0.1;
        let c = action_to_ctrl(&a);
        assert_eq!((c[6], c[7]), (g, -g));
        assert_eq!((c[14], c[15]), (unnormalize_gripper(1.0), -unnormalize_gripper(1.0)));
        assert_eq!(c[0], 0.1f32 as f64);
    }

    #[test]
    fn agent_pos_at_the_start_pose() {
        let p = agent_pos(&START_ARM_POSE);
        assert_eq!(&p[..6], &START_ARM_POSE[..6]);
        assert_eq!(&p[7..13], &START_ARM_POSE[8..14]);
        // aloha-sim.md §2: the initial gripper value is 0.099848.
        assert!((p[6] - 0.099848).abs() < 1e-6 && p[6] == p[13], "{}", p[6]);
    }
}
