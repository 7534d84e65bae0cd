//! robosuite 1.4's OSC_POSE controller as LIBERO configures it, quirks included.
//!
//! Configuration (`controllers/config/osc_pose.json`): kp 150, damping ratio 1 (kd = 2√kp),
//! delta mode, input ±1 scaled to ±0.05 m / ±0.5 rad per step, no interpolation, uncoupled
//! position/orientation, nullspace toward the initial joints (kp 10, kd 2√10), mass-matrix weighted.
//!
//! Reference behaviours reproduced on purpose (`shared/reference/libero-port-spec.md` §5):
//! - **stale cache**: after `reset()` the controller's kinematics cache is not refreshed by
//!   `set_init_state`, so the first substep of an episode uses the reset-time ee pose, Jacobian and
//!   mass matrix (robot at `init_qpos`, at rest) with live bias forces;
//! - **goal orientation kept on exact-zero rotation**: `goal_ori` is only recomputed when some
//!   rotation component is not exactly 0 (`math.isclose(x, 0)` with `abs_tol=0`), so the wait
//!   steps keep the reset-time orientation;
//! - **float32 `quat2mat`**: the numba-jitted `quat2mat` casts the quaternion to float32.

use crate::bundle::ControllerInfo;
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

pub const ARM_DOF: usize = 7;
type Mat7 = SMatrix<f64, ARM_DOF, ARM_DOF>;
type Mat3x7 = SMatrix<f64, 3, ARM_DOF>;
type Mat6x7 = SMatrix<f64, 6, ARM_DOF>;
type Vec7 = SVector<f64, ARM_DOF>;

/// The arm's kinematic state as the controller caches it (robosuite `Controller.update`).
#[derive(Debug, Clone)]
pub struct ArmState {
    pub ee_pos: Vector3<f64>,
    pub ee_ori: Matrix3<f64>,
    pub ee_pos_vel: Vector3<f64>,
    pub ee_ori_vel: Vector3<f64>,
    pub j_pos: Mat3x7,
    pub j_ori: Mat3x7,
    pub mass: Mat7,
    pub q: Vec7,
    pub dq: Vec7,
}

impl ArmState {
    /// The reset-time cache recorded in the bundle.
    pub fn from_snapshot(c: &ControllerInfo) -> Self {
        let s = &c.reset_snapshot;
        let m3 = |rows: &Vec<Vec<f64>>| Matrix3::from_fn(|i, j| rows[i][j]);
        let m3x7 = |rows: &Vec<Vec<f64>>| Mat3x7::from_fn(|i, j| rows[i][j]);
        ArmState {
            ee_pos: Vector3::from_column_slice(&s.ee_pos),
            ee_ori: m3(&s.ee_ori_mat),
            ee_pos_vel: Vector3::from_column_slice(&s.ee_pos_vel),
            ee_ori_vel: Vector3::from_column_slice(&s.ee_ori_vel),
            j_pos: m3x7(&s.j_pos),
            j_ori: m3x7(&s.j_ori),
            mass: Mat7::from_fn(|i, j| s.mass_matrix[i][j]),
            q: Vec7::from_column_slice(&s.joint_pos),
            dq: Vec7::from_column_slice(&s.joint_vel),
        }
    }
}

/// Gains, limits and the goal of the OSC controller.
#[derive(Debug, Clone)]
pub struct OscController {
    kp: [f64; 6],
    kd: [f64; 6],
    /// Per-component scale and offset of `scale_action` (input ±1 → output ±max).
    action_scale: [f64; 6],
    action_output_transform: [f64; 6],
    action_input_transform: [f64; 6],
    input_min: [f64; 6],
    input_max: [f64; 6],
    nullspace_kp: f64,
    initial_joint: Vec7,
    reset_goal_ori: Matrix3<f64>,
    pub goal_pos: Vector3<f64>,
    pub goal_ori: Matrix3<f64>,
}

impl OscController {
    pub fn new(c: &ControllerInfo) -> Self {
        let a6 = |v: &Vec<f64>| -> [f64; 6] { std::array::from_fn(|i| v[i]) };
        let (out_max, out_min, in_max, in_min) =
            (a6(&c.output_max), a6(&c.output_min), a6(&c.input_max), a6(&c.input_min));
        let reset_goal_ori = Matrix3::from_fn(|i, j| c.reset_snapshot.goal_ori[i][j]);
        OscController {
            kp: a6(&c.kp),
            kd: a6(&c.kd),
            action_scale: std::array::from_fn(|i| (out_max[i] - out_min[i]).abs() / (in_max[i] - in_min[i]).abs()),
            action_output_transform: std::array::from_fn(|i| (out_max[i] + out_min[i]) / 2.0),
            action_input_transform: std::array::from_fn(|i| (in_max[i] + in_min[i]) / 2.0),
            input_min: in_min,
            input_max: in_max,
            nullspace_kp: c.nullspace_kp,
            initial_joint: Vec7::from_column_slice(&c.initial_joint),
            reset_goal_ori,
            goal_pos: Vector3::zeros(),
            goal_ori: reset_goal_ori,
        }
    }

    /// The arm configuration robosuite's `reset()` puts the robot in (its `init_qpos`) and the
    /// end-effector orientation there: the null-space target for the whole episode and the goal
    /// orientation [`reset`](Self::reset) restores. A LIBERO-Plus robot-init variant changes them.
    pub fn set_rest_pose(&mut self, initial_joint: &[f64; ARM_DOF], ee_ori: &Matrix3<f64>) {
        self.initial_joint = Vec7::from_column_slice(initial_joint);
        self.reset_goal_ori = *ee_ori;
    }

    /// What `reset()` leaves: the goal orientation is the reset-time ee orientation.
    pub fn reset(&mut self) {
        self.goal_ori = self.reset_goal_ori;
        self.goal_pos = Vector3::zeros();
    }

    /// `set_goal` in delta mode, called on the first substep of every env step.
    pub fn set_goal(&mut self, action: &[f64; 6], s: &ArmState) {
        let delta: [f64; 6] = std::array::from_fn(|i| {
            let a = action[i].clamp(self.input_min[i], self.input_max[i]);
            (a - self.action_input_transform[i]) * self.action_scale[i] + self.action_output_transform[i]
        });
        // `math.isclose(x, 0.0)` with the default abs_tol=0 is true only for an exact zero.
        if delta[3..].iter().any(|&x| x != 0.0) {
            self.goal_ori = axis_angle_to_mat_f32(&[delta[3], delta[4], delta[5]]) * s.ee_ori;
        }
        self.goal_pos = s.ee_pos + Vector3::new(delta[0], delta[1], delta[2]);
    }

    /// `run_controller`: joint torques (before clipping) for the cached state `s` and live bias.
    pub fn torques(&self, s: &ArmState, bias: &Vec7) -> Vec7 {
        let pos_err = self.goal_pos - s.ee_pos;
        let ori_err = orientation_error(&self.goal_ori, &s.ee_ori);
        let force = Vector3::from_fn(|i, _| pos_err[i] * self.kp[i] + (-s.ee_pos_vel[i]) * self.kd[i]);
        let torque = Vector3::from_fn(|i, _| ori_err[i] * self.kp[3 + i] + (-s.ee_ori_vel[i]) * self.kd[3 + i]);

        let m_inv = s.mass.try_inverse().unwrap_or_else(|| pinv7(&s.mass));
        let mut j_full = Mat6x7::zeros();
        j_full.fixed_view_mut::<3, ARM_DOF>(0, 0).copy_from(&s.j_pos);
        j_full.fixed_view_mut::<3, ARM_DOF>(3, 0).copy_from(&s.j_ori);
        let lambda_full = pinv6(&(j_full * m_inv * j_full.transpose()));
        let lambda_pos = pinv3(&(s.j_pos * m_inv * s.j_pos.transpose()));
        let lambda_ori = pinv3(&(s.j_ori * m_inv * s.j_ori.transpose()));
        let j_bar = m_inv * j_full.transpose() * lambda_full;
        let nullspace = Mat7::identity() - j_bar * j_full;

        let f = lambda_pos * force;
        let t = lambda_ori * torque;
        let wrench = SVector::<f64, 6>::new(f[0], f[1], f[2], t[0], t[1], t[2]);
        let mut tau = j_full.transpose() * wrench + bias;
        let kv = self.nullspace_kp.sqrt() * 2.0;
        let pose_torques = s.mass * ((self.initial_joint - s.q) * self.nullspace_kp - s.dq * kv);
        tau += nullspace.transpose() * pose_torques;
        tau
    }
}

/// Moore-Penrose pseudo-inverse via SVD, as `numpy.linalg.pinv` (rcond 1e-15 of the largest
/// singular value). The matrices here are symmetric positive definite away from singularities.
/// Fixed-size (stack-allocated) SVDs: this runs three times per physics substep.
macro_rules! pinv_fixed {
    ($name:ident, $n:literal) => {
        fn $name(m: &SMatrix<f64, $n, $n>) -> SMatrix<f64, $n, $n> {
            let svd = nalgebra::SVD::new(*m, true, true);
            let max = svd.singular_values.max();
            svd.pseudo_inverse(1e-15 * max).expect("SVD computed with both U and V")
        }
    };
}
pinv_fixed!(pinv3, 3);
pinv_fixed!(pinv6, 6);
pinv_fixed!(pinv7, 7);

/// robosuite `orientation_error`: ½ Σᵢ cur[:,i] × des[:,i].
pub fn orientation_error(desired: &Matrix3<f64>, current: &Matrix3<f64>) -> Vector3<f64> {
    let c = |i: usize| Vector3::new(current[(0, i)], current[(1, i)], current[(2, i)]);
    let d = |i: usize| Vector3::new(desired[(0, i)], desired[(1, i)], desired[(2, i)]);
    (c(0).cross(&d(0)) + c(1).cross(&d(1)) + c(2).cross(&d(2))) * 0.5
}

/// `quat2mat(axisangle2quat(v))` exactly as robosuite computes it: the quaternion is cast to
/// float32 inside the numba-jitted `quat2mat`; diagonal terms are float64 `1.0 - f32 - f32`,
/// off-diagonal ones float32 sums.
pub fn axis_angle_to_mat_f32(v: &[f64; 3]) -> Matrix3<f64> {
    let angle = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if angle == 0.0 {
        return Matrix3::identity();
    }
    let axis = [v[0] / angle, v[1] / angle, v[2] / angle];
    let (s, c) = ((angle / 2.0).sin(), (angle / 2.0).cos());
    // (w, x, y, z) in float32
    let mut q = [c as f32, (axis[0] * s) as f32, (axis[1] * s) as f32, (axis[2] * s) as f32];
    // numpy's float32 dot (OpenBLAS sdot accumulates in double): the correctly rounded sum.
    let n = q.iter().map(|&x| x as f64 * x as f64).sum::<f64>() as f32;
    if (n as f64) < f64::EPSILON * 4.0 {
        return Matrix3::identity();
    }
    let k = (2.0 / n as f64).sqrt();
    for x in &mut q {
        *x = (*x as f64 * k) as f32;
    }
    let q2 = |i: usize, j: usize| q[i] * q[j];
    let d = |a: f32, b: f32| 1.0 - a as f64 - b as f64;
    Matrix3::new(
        d(q2(2, 2), q2(3, 3)),
        (q2(1, 2) - q2(3, 0)) as f64,
        (q2(1, 3) + q2(2, 0)) as f64,
        (q2(1, 2) + q2(3, 0)) as f64,
        d(q2(1, 1), q2(3, 3)),
        (q2(2, 3) - q2(1, 0)) as f64,
        (q2(1, 3) - q2(2, 0)) as f64,
        (q2(2, 3) + q2(1, 0)) as f64,
        d(q2(1, 1), q2(2, 2)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_angle_rotation_is_a_rotation_to_float32_precision() {
        let r = axis_angle_to_mat_f32(&[0.1, -0.2, 0.3]);
        let err = (r * r.transpose() - Matrix3::identity()).abs().max();
        assert!(err < 1e-6, "not orthonormal: {err}");
        assert!(err > 0.0, "float32 rounding should be visible");
        // 90° about z maps x to y
        let z = axis_angle_to_mat_f32(&[0.0, 0.0, std::f64::consts::FRAC_PI_2]);
        assert!((z * Vector3::x() - Vector3::y()).norm() < 1e-6);
        assert_eq!(axis_angle_to_mat_f32(&[0.0, 0.0, 0.0]), Matrix3::identity());
    }

    #[test]
    fn orientation_error_of_a_small_rotation_is_its_axis_angle() {
        let cur = Matrix3::identity();
        let des = axis_angle_to_mat_f32(&[0.0, 0.0, 0.01]);
        let e = orientation_error(&des, &cur);
        assert!((e - Vector3::new(0.0, 0.0, 0.01)).norm() < 1e-6, "{e}");
    }
}
