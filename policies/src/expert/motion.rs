//! Turning a desired end-effector pose into the 7-D delta action a VLA emits.
//!
//! LIBERO's OSC controller reads an action as "move the goal by `0.05 × a` metres and rotate it by
//! `0.5 × a` radians (axis-angle, world frame) from where the hand is now", with `a` clipped to
//! [-1, 1]. A proportional law on the pose error, clipped, is therefore a closed loop on the
//! observed end-effector pose: nothing is teleported and nothing in the state is edited.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

/// Metres of goal offset per unit of position action (LIBERO's `output_max`).
const POS_SCALE: f64 = 0.05;
/// Radians of goal rotation per unit of orientation action.
const ROT_SCALE: f64 = 0.5;

/// The gripper pointing straight down with yaw 0, as LIBERO's robot starts: the fingers close
/// along world y (the hand's x axis), the hand's z axis points down.
pub fn down_orientation(yaw: f64) -> Rotation3<f64> {
    let base = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    Rotation3::from_axis_angle(&Vector3::z_axis(), yaw) * Rotation3::from_matrix_unchecked(base)
}

/// Horizontal direction along which the fingers close when the hand points down with this yaw.
#[cfg(test)]
fn closing_direction(yaw: f64) -> Vector3<f64> {
    Vector3::new(-yaw.sin(), yaw.cos(), 0.0)
}

/// The yaw in (-π/2, π/2] whose closing direction is parallel to the horizontal vector `v`.
pub fn yaw_closing_along(v: &Vector3<f64>) -> f64 {
    let mut yaw = (-v.x).atan2(v.y);
    while yaw > std::f64::consts::FRAC_PI_2 {
        yaw -= std::f64::consts::PI;
    }
    while yaw <= -std::f64::consts::FRAC_PI_2 {
        yaw += std::f64::consts::PI;
    }
    yaw
}

/// Largest yaw (either way) the expert asks for: the Panda's last joint turns ±2.90 rad from its
/// start at π/4, so beyond ~±2.1 rad of yaw from the start it hits its limit and the hand stalls
/// tilted. Kept under that with a margin.
const MAX_YAW: f64 = 1.95;

/// The hand's yaw now: the angle of its closing direction, in the convention of [`down_orientation`].
pub fn hand_yaw(hand: &Rotation3<f64>) -> f64 {
    let c = hand * Vector3::x();
    (-c.x).atan2(c.y)
}

/// The yaw to turn to for a grasp planned at `yaw` (in (-π/2, π/2]) when the hand is at `current`.
/// The fingers are symmetric, so `yaw ± π` grasps the same; when the planned yaw is more than a
/// quarter turn away, the equivalent one nearest the hand within the wrist's reach is taken: a turn
/// of a few degrees instead of half a turn that would run the wrist into its limit.
pub fn nearest_equivalent_yaw(yaw: f64, current: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    if (yaw - current).abs() <= FRAC_PI_2 {
        return yaw;
    }
    [yaw - 2.0 * PI, yaw - PI, yaw, yaw + PI, yaw + 2.0 * PI]
        .into_iter()
        .filter(|y| y.abs() <= MAX_YAW)
        .min_by(|a, b| (a - current).abs().total_cmp(&(b - current).abs()))
        .unwrap_or(yaw)
}

/// The hand's orientation from the observation's (w, x, y, z) quaternion.
pub fn hand_rotation(quat: &[f64; 4]) -> Rotation3<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(quat[0], quat[1], quat[2], quat[3])).to_rotation_matrix()
}

/// Position part of the action: proportional on the error, the whole vector capped at `max`.
pub fn position_action(eef: &Vector3<f64>, target: &Vector3<f64>, gain: f64, max: f64) -> [f64; 3] {
    let mut a = (target - eef) * (gain / POS_SCALE);
    let n = a.norm();
    if n > max {
        a *= max / n;
    }
    [a.x, a.y, a.z]
}

/// Orientation part of the action: the world-frame axis-angle from the hand to the target.
pub fn rotation_action(hand: &Rotation3<f64>, target: &Rotation3<f64>) -> [f64; 3] {
    let err = (target * hand.inverse()).scaled_axis();
    let a = err / ROT_SCALE;
    [a.x, a.y, a.z].map(|x| x.clamp(-1.0, 1.0))
}

/// Angle between two orientations (radians).
pub fn rotation_error(hand: &Rotation3<f64>, target: &Rotation3<f64>) -> f64 {
    (target * hand.inverse()).angle()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_yaw_that_closes_along_a_direction_does() {
        for v in [Vector3::new(1.0, 0.0, 0.0), Vector3::new(0.3, -0.8, 0.0), Vector3::new(-0.2, -0.5, 0.0)] {
            let yaw = yaw_closing_along(&v);
            let c = closing_direction(yaw);
            assert!((c.normalize().dot(&v.normalize()).abs() - 1.0).abs() < 1e-9, "{v:?} -> {yaw}");
        }
        // The hand's x axis is the closing direction.
        let r = down_orientation(0.4);
        assert!((r * Vector3::x() - closing_direction(0.4)).norm() < 1e-12);
    }

    #[test]
    fn the_nearest_equivalent_yaw_is_a_short_turn_within_the_wrist() {
        use std::f64::consts::FRAC_PI_2;
        // From -1.9 rad, +π/2 is reached as -π/2 (a 0.33 rad turn, not 3.5).
        assert!((nearest_equivalent_yaw(FRAC_PI_2, -1.9) + FRAC_PI_2).abs() < 1e-12);
        // Never beyond the wrist's limit, even when that is nearer.
        assert!((nearest_equivalent_yaw(0.1, 2.5) - 0.1).abs() < 1e-12);
        // Within a quarter turn the planned yaw stands.
        assert!((nearest_equivalent_yaw(1.2, -0.2) - 1.2).abs() < 1e-12);
        // The hand's own yaw is read back.
        assert!((hand_yaw(&down_orientation(0.7)) - 0.7).abs() < 1e-12);
    }

    #[test]
    fn rotation_action_points_toward_the_target() {
        let hand = down_orientation(0.0);
        let target = down_orientation(0.2);
        let a = rotation_action(&hand, &target);
        // A yaw about world z: positive z component, 0.2 rad / 0.5 = 0.4.
        assert!((a[2] - 0.4).abs() < 1e-9 && a[0].abs() < 1e-9 && a[1].abs() < 1e-9, "{a:?}");
    }

    #[test]
    fn position_action_is_capped() {
        let a = position_action(&Vector3::zeros(), &Vector3::new(1.0, 0.0, 0.0), 1.0, 0.5);
        assert_eq!(a, [0.5, 0.0, 0.0]);
    }
}
