//! The proprio(ceptive) state of the LIBERO loops: `concat(eef_pos, quat2axisangle(eef_quat),
//! gripper_qpos)`, 8 numbers, as OpenVLA's `run_libero_eval.py` (which records but does not feed
//! it), OpenVLA-OFT's `prepare_observation` and openpi's `examples/libero/main.py` build it, and
//! as the LIBERO RLDS datasets stored it for training.
//!
//! **The quaternion's sign matters.** `q` and `-q` are the same rotation but not the same
//! axis-angle vector: robosuite's `quat2axisangle` returns `2·acos(w)·(x, y, z)/sin(...)`, whose
//! angle is above π when `w < 0`. In LIBERO the hand points down, a rotation of about π about
//! the world x axis, so `w` sits near 0 and changes sign during an episode: robosuite's
//! `robot0_eef_quat` (MuJoCo's `xquat` of the `robot0_right_hand` *body*, signed as MuJoCo's
//! kinematic chain makes it) keeps `x > 0` (measured on the reference env: `x` in [0.90, 1.00],
//! `w` in [-0.10, 0.29]), and its axis-angle runs continuously through π (e.g. (3.08, 0, 0) ↔
//! (3.20, 0, 0)). A quaternion taken from a rotation matrix or normalised to `w ≥ 0` is the
//! antipode whenever `w < 0` there, and its state jumps to (-3.08, 0, 0): out of the training
//! distribution, silently. [`QuatSign::Hemisphere`] with [`LIBERO_EEF_HEMISPHERE`] puts any
//! quaternion of this rotation on robosuite's side; [`QuatSign::AsGiven`] trusts the caller.
//!
//! Also note which frame: robosuite's eef *position* is the grip site's, its eef *quaternion* the
//! hand body's (about 90° in yaw from the grip site frame).

/// What to do with the sign of the quaternion before [`quat2axisangle`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum QuatSign {
    /// Use it as given: right when it is MuJoCo's body `xquat`, as robosuite reads it.
    AsGiven,
    /// Flip it when its dot product with this reference (x, y, z, w) is negative.
    Hemisphere([f64; 4]),
}

/// The side of the double cover robosuite's `robot0_eef_quat` stays on in LIBERO: the hand
/// pointing down, π about x, (x, y, z, w) = (1, 0, 0, 0).
pub const LIBERO_EEF_HEMISPHERE: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

/// (w, x, y, z) (MuJoCo's order, [`crate::Observation::eef_quat`]) to (x, y, z, w) (robosuite's).
pub fn wxyz_to_xyzw(q: [f64; 4]) -> [f64; 4] {
    [q[1], q[2], q[3], q[0]]
}

/// `q` or `-q`, whichever has a non-negative dot product with `reference`.
pub fn align_to_hemisphere(q: [f64; 4], reference: [f64; 4]) -> [f64; 4] {
    let dot: f64 = q.iter().zip(&reference).map(|(a, b)| a * b).sum();
    if dot < 0.0 { q.map(|v| -v) } else { q }
}

/// robosuite's `transform_utils.quat2axisangle` for an (x, y, z, w) quaternion, operation for
/// operation: `w` clipped to [-1, 1], zeros when `sqrt(1 - w²)` is exactly 0 (`math.isclose` with
/// its default tolerances), else `x·2·acos(w) / sqrt(1 - w²)` per component. No sign
/// normalisation (see the module doc).
pub fn quat2axisangle(q: [f64; 4]) -> [f64; 3] {
    // As the `if quat[3] > 1.0 ... elif < -1.0` of the reference (NaN passes through).
    let w = q[3].clamp(-1.0, 1.0);
    let den = (1.0 - w * w).sqrt();
    if den == 0.0 {
        return [0.0; 3];
    }
    let angle = w.acos();
    [q[0] * 2.0 * angle / den, q[1] * 2.0 * angle / den, q[2] * 2.0 * angle / den]
}

/// The 8-dim LIBERO state: eef position (3), axis-angle of the eef quaternion (x, y, z, w) after
/// `sign` (3), the two finger joints (2).
pub fn libero_state(eef_pos: [f64; 3], eef_quat_xyzw: [f64; 4], gripper_qpos: [f64; 2], sign: QuatSign) -> [f64; 8] {
    let q = match sign {
        QuatSign::AsGiven => eef_quat_xyzw,
        QuatSign::Hemisphere(r) => align_to_hemisphere(eef_quat_xyzw, r),
    };
    let aa = quat2axisangle(q);
    [eef_pos[0], eef_pos[1], eef_pos[2], aa[0], aa[1], aa[2], gripper_qpos[0], gripper_qpos[1]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12)
    }

    #[test]
    fn identity_and_unnormalised_w_give_zeros() {
        assert_eq!(quat2axisangle([0.0, 0.0, 0.0, 1.0]), [0.0; 3]);
        assert_eq!(quat2axisangle([0.0, 0.0, 0.0, -1.0]), [0.0; 3]);
        assert_eq!(quat2axisangle([0.0, 0.0, 0.0, 1.0 + 1e-12]), [0.0; 3]);
    }

    #[test]
    fn half_turns_and_their_antipodes() {
        assert!(close(quat2axisangle([1.0, 0.0, 0.0, 0.0]), [PI, 0.0, 0.0]));
        assert!(close(quat2axisangle([-1.0, 0.0, 0.0, 0.0]), [-PI, 0.0, 0.0]));
        let half = (0.05f64).sin_cos();
        // 2·0.05 short of π about +x, and its antipode: the same rotation, angle past π.
        let q = [half.1, 0.0, 0.0, half.0];
        assert!(close(quat2axisangle(q), [PI - 0.1, 0.0, 0.0]));
        assert!(close(quat2axisangle(q.map(|v| -v)), [-(PI + 0.1), 0.0, 0.0]));
    }

    #[test]
    fn hemisphere_keeps_robosuite_side() {
        // w < 0 with x > 0 is robosuite's own sign in LIBERO: kept.
        let q = [0.9925, 0.05, -0.1, -0.05];
        assert_eq!(align_to_hemisphere(q, LIBERO_EEF_HEMISPHERE), q);
        // Its antipode (what w ≥ 0 normalisation or a matrix conversion may give) is flipped back.
        let anti = q.map(|v| -v);
        assert_eq!(align_to_hemisphere(anti, LIBERO_EEF_HEMISPHERE), q);
        let s = libero_state([1.0, 2.0, 3.0], anti, [0.04, -0.04], QuatSign::Hemisphere(LIBERO_EEF_HEMISPHERE));
        let aa = quat2axisangle(q);
        assert_eq!(s, [1.0, 2.0, 3.0, aa[0], aa[1], aa[2], 0.04, -0.04]);
        assert!(aa[0] > PI);
    }

    #[test]
    fn wxyz_reorders() {
        assert_eq!(wxyz_to_xyzw([4.0, 1.0, 2.0, 3.0]), [1.0, 2.0, 3.0, 4.0]);
    }
}
