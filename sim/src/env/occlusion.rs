//! LIBERO-PRO's `view_occlusion` placement (`perturbation-spec.md` §C2, the `object_placement`
//! block): an occluder, added to the scene at export time (the `<suite>_view_occlusion` bundles),
//! is placed in front of the task's target, toward the camera, and pinned there.
//!
//! After the init state is set (and before the lighting, as the reference orders its edits):
//! 1. the goal partner, when it is another object than the reference and its body is closer than
//!    `partner_threshold` (xy) to the reference's, is moved by `partner_delta` with the safe-delta
//!    search of [`super::object_moves`] (minimum norm 0);
//! 2. the occluder goes to the reference's xy plus the first of [`candidate_reference_offsets`]
//!    (in the frame of the front direction, +x toward the camera, and lateral +y) that passes the
//!    safe-delta checks (work area, footprints on its layer, no interpenetration), lies at least
//!    [`MIN_REFERENCE_DISTANCE`] from the reference and at least `partner_clearance` from the
//!    partner; its height is the one its init state gives it ([`Z_OFFSET`] added), its orientation
//!    [`TARGET_QUAT`]. When no candidate passes it stays where it was (and is pinned there);
//! 3. its 7 qpos are written back after every env step (its qvel is left as the physics made it),
//!    and the data forwarded, so what is rendered and observed has the occluder in place.
//!
//! The spec's `mesh_scale` 1.6 is not applied: writing `mjModel.mesh_scale` after compilation
//! changes nothing in the reference (§C2), so it is no parameter here. The spec's terse candidate
//! list is read as: the `±.16/.32/.48` offsets are angles (rad) about the requested direction.
//! The Python reference (`scripts/reference/pro_occlusion.py`) implements the same reading
//! independently; the parity test compares the two.

use super::LiberoEnv;
use super::object_moves::{AppliedMove, ObjectShift, Placement};
use crate::SimError;

/// The shipped `object_placement` block's constants (§C2).
pub const TARGET_QUAT: [f64; 4] = [1.0, 0.0, 0.0, 0.0];
pub const Z_OFFSET: f64 = 0.0;
pub const MIN_REFERENCE_DISTANCE: f64 = 0.02;
const MAX_CANDIDATES: usize = 32;

/// One episode's occluder placement, as the spec row states it.
#[derive(Debug, Clone, PartialEq)]
pub struct Occlusion {
    /// The occluder: an object of the scene with a free joint (`black_book_occluder_1`, ...).
    pub occluder: String,
    /// The object it is placed in front of (the task's target).
    pub reference: String,
    /// The requested offset from the reference: (forward = +x, lateral = +y), m.
    pub offset_xy: [f64; 2],
    /// The goal partner, moved away first when too close, and kept clear of.
    pub partner: Option<OcclusionPartner>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct OcclusionPartner {
    pub object: String,
    /// The partner is moved when its body is closer (xy) than this to the reference's (m).
    pub threshold: f64,
    /// The move requested for it (m).
    pub delta_xy: [f64; 2],
    /// The occluder keeps at least this xy distance from the partner's body (m).
    pub clearance: f64,
}

/// What the placement did in the current episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AppliedOcclusion {
    /// The partner's move, when it was close enough to be moved (its delta None: no safe one).
    pub partner_move: Option<AppliedMove>,
    /// The occluder's offset from the reference, or None when no candidate was safe.
    pub offset_xy: Option<[f64; 2]>,
    /// The occluder's pinned qpos (position, quaternion w x y z).
    pub pinned: [f64; 7],
}

/// The occluder's candidate offsets, in the order they are tried: the request `o`; then radii
/// {max(n, .12), max(n+.04, .16), max(n+.08, .20)} (n = |o|) × angles {0, ±.16, ±.32, ±.48} rad
/// about o's direction; then forward {.075, .095, .12, .16, .20, .24} × lateral {0, ±.065, ±.10}.
/// Duplicates (to 0.1 mm) are dropped; at most 32.
pub fn candidate_reference_offsets(o: [f64; 2]) -> Vec<[f64; 2]> {
    let n = o[0].hypot(o[1]);
    let a = if n > 0.0 { o[1].atan2(o[0]) } else { 0.0 };
    let mut out = vec![o];
    for r in [n.max(0.12), (n + 0.04).max(0.16), (n + 0.08).max(0.20)] {
        for da in [0.0, 0.16, -0.16, 0.32, -0.32, 0.48, -0.48] {
            out.push([r * (a + da).cos(), r * (a + da).sin()]);
        }
    }
    for f in [0.075, 0.095, 0.12, 0.16, 0.20, 0.24] {
        for l in [0.0, 0.065, -0.065, 0.10, -0.10] {
            out.push([f, l]);
        }
    }
    let mut seen = Vec::new();
    out.retain(|c| {
        let k = c.map(|x| (x * 1e4).round() as i64);
        let new = !seen.contains(&k);
        seen.push(k);
        new
    });
    out.truncate(MAX_CANDIDATES);
    out
}

impl LiberoEnv {
    /// Refuse an occlusion this scene cannot take: the occluder must be an object of the scene with
    /// a free joint (a clean bundle has none: the rows run the `<suite>_view_occlusion` bundles).
    pub(super) fn check_occlusion(&self, o: &Occlusion) -> Result<(), SimError> {
        if self.object_root_body(&o.occluder).is_err() {
            return Err(SimError::Other(format!(
                "the scene of {} task {} has no occluder {:?}: view_occlusion rows run the occluder scenes, suite {}_view_occlusion (build them with ./setup.sh --suites libero_pro_occlusion)",
                self.bundle.task.suite,
                self.bundle.task.task_id,
                o.occluder,
                self.bundle.task.suite.trim_end_matches("_view_occlusion")
            )));
        }
        if !matches!(self.placement(&o.occluder)?, Placement::FreeJoint { .. }) {
            return Err(SimError::Other(format!("the occluder {} has no free joint: it cannot be placed", o.occluder)));
        }
        if o.reference == o.occluder {
            return Err(SimError::Other(format!("the occluder {} cannot be its own reference", o.occluder)));
        }
        self.object_root_body(&o.reference)?;
        let shift = ObjectShift { object: o.occluder.clone(), delta_xy: o.offset_xy, min_delta_norm: 0.0 };
        self.check_shift(&shift)?;
        if let Some(p) = &o.partner {
            if p.object == o.occluder {
                return Err(SimError::Other(format!("the occluder {} cannot be the goal partner", o.occluder)));
            }
            self.check_shift(&ObjectShift { object: p.object.clone(), delta_xy: p.delta_xy, min_delta_norm: 0.0 })?;
        }
        Ok(())
    }

    /// What the occlusion did in this episode (None without one).
    pub fn occlusion(&self) -> Option<AppliedOcclusion> {
        self.moves.occlusion
    }

    /// Steps 1 and 2 of the module doc, right after the init state is set.
    pub(super) fn apply_occlusion(&mut self) -> Result<(), SimError> {
        let Some(o) = self.edits.occlusion.clone() else { return Ok(()) };
        let reference = self.object_root_body(&o.reference)?;
        let partner = o.partner.as_ref().filter(|p| p.object != o.reference);
        let mut partner_move = None;
        if let Some(p) = partner {
            let pb = self.object_root_body(&p.object)?;
            if self.xy_distance(pb, reference) < p.threshold {
                let shift = ObjectShift { object: p.object.clone(), delta_xy: p.delta_xy, min_delta_norm: 0.0 };
                let placement = self.placement(&p.object)?;
                let delta = self.shift_safely(&shift, placement)?;
                partner_move = Some(AppliedMove { at_step: 0, delta_xy: delta });
            }
        }
        let Placement::FreeJoint { qpos } = self.placement(&o.occluder)? else {
            return Err(SimError::Other(format!("the occluder {} has no free joint", o.occluder)));
        };
        let occluder = self.object_root_body(&o.occluder)?;
        let before: [f64; 7] = std::array::from_fn(|i| self.data.qpos()[qpos + i]);
        let r = self.data.xpos()[reference];
        let partner_body = partner.map(|p| self.object_root_body(&p.object)).transpose()?;
        let mut chosen = None;
        for c in candidate_reference_offsets(o.offset_xy) {
            if c[0].hypot(c[1]) < MIN_REFERENCE_DISTANCE {
                continue;
            }
            let pose = [
                r[0] + c[0],
                r[1] + c[1],
                before[2] + Z_OFFSET,
                TARGET_QUAT[0],
                TARGET_QUAT[1],
                TARGET_QUAT[2],
                TARGET_QUAT[3],
            ];
            self.data.qpos_mut()[qpos..qpos + 7].copy_from_slice(&pose);
            self.data.forward();
            let clear = match (partner, partner_body) {
                (Some(p), Some(pb)) => self.xy_distance(occluder, pb) >= p.clearance,
                _ => true,
            };
            if clear && self.placement_is_safe(&o.occluder, occluder) {
                chosen = Some(c);
                break;
            }
            self.data.qpos_mut()[qpos..qpos + 7].copy_from_slice(&before);
        }
        self.data.forward();
        let pinned = std::array::from_fn(|i| self.data.qpos()[qpos + i]);
        self.moves.occlusion = Some(AppliedOcclusion { partner_move, offset_xy: chosen, pinned });
        self.pinned = Some((qpos, pinned));
        Ok(())
    }

    /// Step 3: the occluder back at its pinned pose after an env step, the data forwarded.
    pub(super) fn pin_occluder(&mut self) {
        if let Some((qpos, pose)) = self.pinned {
            self.data.qpos_mut()[qpos..qpos + 7].copy_from_slice(&pose);
            self.data.forward();
        }
    }

    fn xy_distance(&self, a: usize, b: usize) -> f64 {
        let (p, q) = (self.data.xpos()[a], self.data.xpos()[b]);
        (p[0] - q[0]).hypot(p[1] - q[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_candidates_are_the_request_then_the_radii_about_its_direction() {
        let c = candidate_reference_offsets([0.08, 0.0]);
        assert_eq!(c[0], [0.08, 0.0]);
        assert!((c[1][0] - 0.12).abs() < 1e-12 && c[1][1] == 0.0, "{:?}", c[1]);
        assert!((c[2][1].atan2(c[2][0]) - 0.16).abs() < 1e-12);
        assert_eq!(c.len(), MAX_CANDIDATES);
        // the forward × lateral grid starts after the 22 radial ones
        assert_eq!(c[22], [0.075, 0.0]);
        // a lateral request turns the radial candidates with it
        let l = candidate_reference_offsets([0.08, 0.09]);
        let n = 0.08f64.hypot(0.09);
        // (|o| = 0.12 already: the first radius repeats the request, dropped as a duplicate)
        assert!((l[1][0].hypot(l[1][1]) - n).abs() < 1e-12);
        assert!((l[1][1].atan2(l[1][0]) - (0.09f64.atan2(0.08) + 0.16)).abs() < 1e-12);
    }
}
