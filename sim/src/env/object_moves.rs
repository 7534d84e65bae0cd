//! LIBERO-PRO's object placement perturbations: an object yawed and shifted after the init state
//! is set (`initial_pose`), or shifted once mid-episode when the gripper comes near it
//! (`runtime_move`) (`perturbation-spec.md` §C2).
//!
//! Both shift the object by a *safe* delta: the first of a fixed list of candidates around the
//! requested one that keeps the object on the work area, clear of the other objects' footprints on
//! its support layer, and out of interpenetration. The list and the checks follow the spec of the
//! reference's `choose_safe_delta`; where the spec is silent we decided (and the doc comments say):
//! the five last-resort directions are ±x, ±y and the +x+y diagonal, and only contacts of the moved
//! object count (a scene's own settled penetrations elsewhere never veto a move). When no candidate
//! passes, the object is not moved and [`LiberoEnv::object_move`] says so.

use super::LiberoEnv;
use crate::SimError;
use mujoco_rs::prelude::*;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// The requested shift of one object, as a LIBERO-PRO block states it.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectShift {
    /// The object (or fixture) of the task to move.
    pub object: String,
    /// Requested displacement in the world's x-y plane (m).
    pub delta_xy: [f64; 2],
    /// A shorter request is lengthened to this (m): the move must be visible.
    pub min_delta_norm: f64,
}

/// `initial_pose`: after `set_init_state`, the object's orientation is *replaced* by a yaw about
/// world z (its init orientation is dropped, as in the reference), then it is shifted.
#[derive(Debug, Clone, PartialEq)]
pub struct InitialPose {
    pub shift: ObjectShift,
    /// Absolute yaw (rad); None keeps the init state's orientation.
    pub yaw: Option<f64>,
}

/// `runtime_move`: before an env step, once the end effector is within `trigger_distance` of the
/// object's body origin, or at env step `fallback_step` at the latest, the object is shifted
/// (position only; its velocity is untouched). It fires once per episode.
#[derive(Debug, Clone, PartialEq)]
pub struct RuntimeMove {
    pub shift: ObjectShift,
    pub trigger_distance: f64,
    pub fallback_step: u32,
}

/// What a placement perturbation did in the current episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AppliedMove {
    /// Env steps taken when it was applied (0: at reset).
    pub at_step: u32,
    /// The displacement applied, or None when no candidate was safe (nothing moved).
    pub delta_xy: Option<[f64; 2]>,
}

/// The work area the reference keeps objects in: |x|, |y| ≤ 0.6 m.
const WORK_AREA: f64 = 0.6;
/// Objects whose origins differ by at most this in height share a support layer (m).
const SAME_LAYER_DZ: f64 = 0.04;
/// Footprint radius of an object without a `horizontal_radius` (m), and the gap kept between two.
const DEFAULT_RADIUS: f64 = 0.04;
const FOOTPRINT_GAP: f64 = 0.01;
/// A contact deeper than this is an interpenetration (m).
const PENETRATION: f64 = -1e-3;
/// The shortest fallback move (m).
const MIN_FALLBACK: f64 = 0.06;
const MAX_CANDIDATES: usize = 32;

/// The candidate displacements for a request, in the order they are tried: the request at
/// `max(|δ|, min)`; then radii {r, max(0.9r, min, 0.06), 1.1r, 1.25r} × angle offsets
/// {0, ±π/2, π, ±π/4, ±3π/4} around δ's direction; then ±x, ±y and the +x+y diagonal at
/// `max(min, 0.06)`. Duplicates (to 0.1 mm) are dropped; at most 32.
pub fn candidate_deltas(delta: [f64; 2], min_norm: f64) -> Vec<[f64; 2]> {
    let norm = delta[0].hypot(delta[1]);
    let r = norm.max(min_norm);
    let angle = if norm > 0.0 { delta[1].atan2(delta[0]) } else { 0.0 };
    let at = |radius: f64, a: f64| [radius * a.cos(), radius * a.sin()];
    let mut out = vec![at(r, angle)];
    for radius in [r, (0.9 * r).max(min_norm).max(MIN_FALLBACK), 1.1 * r, 1.25 * r] {
        for off in [0.0, FRAC_PI_2, -FRAC_PI_2, PI, FRAC_PI_4, -FRAC_PI_4, 3.0 * FRAC_PI_4, -3.0 * FRAC_PI_4] {
            out.push(at(radius, angle + off));
        }
    }
    let f = min_norm.max(MIN_FALLBACK);
    let d = std::f64::consts::FRAC_1_SQRT_2 * f;
    out.extend([[f, 0.0], [-f, 0.0], [0.0, f], [0.0, -f], [d, d]]);
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

/// robosuite's `axisangle2quat([0, 0, yaw])` as MuJoCo's (w, x, y, z).
fn yaw_quat(yaw: f64) -> [f64; 4] {
    [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()]
}

/// Where an object's pose lives: a free joint's qpos, or (a fixture) its body's model pose.
#[derive(Debug, Clone, Copy)]
pub(super) enum Placement {
    FreeJoint { qpos: usize },
    Fixture { body: usize },
}

impl LiberoEnv {
    /// Refuse a shift of an object the task does not have or cannot move.
    pub(super) fn check_shift(&self, shift: &ObjectShift) -> Result<(), SimError> {
        self.placement(&shift.object)?;
        if self.bundle.horizontal_radii.is_none() {
            return Err(SimError::Other(format!(
                "moving {} needs the objects' footprint radii ({} beside the bundles' index.json), which this bundle set lacks: run ./setup.sh",
                shift.object,
                crate::bundle::OBJECT_RADII_FILE
            )));
        }
        if !(shift.delta_xy.iter().all(|x| x.is_finite()) && shift.min_delta_norm.is_finite()) {
            return Err(SimError::Other(format!("the shift of {} is not finite", shift.object)));
        }
        Ok(())
    }

    pub(super) fn placement(&self, object: &str) -> Result<Placement, SimError> {
        let body = self.object_root_body(object)?;
        let m = &self.model;
        let jnt = m.body_jntadr()[body];
        if jnt >= 0 && m.jnt_type()[jnt as usize] == MjtJoint::mjJNT_FREE {
            return Ok(Placement::FreeJoint { qpos: m.jnt_qposadr()[jnt as usize] as usize });
        }
        if self.bundle.task.objects.get(object).is_some_and(|o| o.fixture) {
            return Ok(Placement::Fixture { body });
        }
        Err(SimError::Other(format!("{object} has neither a free joint nor is it a fixture: it cannot be moved")))
    }

    /// What the episode's placement perturbations did so far: (initial pose, runtime move).
    pub fn object_moves(&self) -> (Option<AppliedMove>, Option<AppliedMove>) {
        (self.moves.initial, self.moves.runtime)
    }

    /// `initial_pose`, right after the init state is set (`reset_to`).
    pub(super) fn apply_initial_pose(&mut self) -> Result<(), SimError> {
        self.moves = Default::default();
        let Some(p) = self.edits.initial_pose.clone() else { return Ok(()) };
        let placement = self.placement(&p.shift.object)?;
        if let Some(yaw) = p.yaw {
            let q = yaw_quat(yaw);
            match placement {
                Placement::FreeJoint { qpos } => self.data.qpos_mut()[qpos + 3..qpos + 7].copy_from_slice(&q),
                Placement::Fixture { body } => self.model.body_quat_mut()[body] = q,
            }
            self.data.forward();
        }
        let delta = self.shift_safely(&p.shift, placement)?;
        self.moves.initial = Some(AppliedMove { at_step: 0, delta_xy: delta });
        Ok(())
    }

    /// `runtime_move`, before every env step until it fires.
    pub(super) fn maybe_runtime_move(&mut self) -> Result<(), SimError> {
        let Some(m) = &self.edits.runtime_move else { return Ok(()) };
        if self.moves.runtime.is_some() {
            return Ok(());
        }
        // checked before every step until it fires: nothing is cloned or allocated here
        let body = self.object_root_body(&m.shift.object)?;
        let eef = self.data.site_xpos()[self.eef_site];
        let obj = self.data.xpos()[body];
        let distance = (0..3).map(|i| (eef[i] - obj[i]).powi(2)).sum::<f64>().sqrt();
        if distance > m.trigger_distance && self.steps < m.fallback_step {
            return Ok(());
        }
        let m = m.clone();
        let placement = self.placement(&m.shift.object)?;
        let delta = self.shift_safely(&m.shift, placement)?;
        self.moves.runtime = Some(AppliedMove { at_step: self.steps, delta_xy: delta });
        Ok(())
    }

    /// Move the object by the first safe candidate; the data is forwarded at the pose it is left at.
    pub(super) fn shift_safely(
        &mut self,
        shift: &ObjectShift,
        placement: Placement,
    ) -> Result<Option<[f64; 2]>, SimError> {
        let body = self.object_root_body(&shift.object)?;
        for c in candidate_deltas(shift.delta_xy, shift.min_delta_norm) {
            self.displace(placement, c);
            self.data.forward();
            if self.placement_is_safe(&shift.object, body) {
                return Ok(Some(c));
            }
            self.displace(placement, [-c[0], -c[1]]);
        }
        self.data.forward();
        Ok(None)
    }

    fn displace(&mut self, placement: Placement, d: [f64; 2]) {
        match placement {
            Placement::FreeJoint { qpos } => {
                let q = self.data.qpos_mut();
                q[qpos] += d[0];
                q[qpos + 1] += d[1];
            }
            Placement::Fixture { body } => {
                let p = &mut self.model.body_pos_mut()[body];
                p[0] += d[0];
                p[1] += d[1];
            }
        }
    }

    /// The checks of a candidate, on the forwarded data: inside the work area, no footprint overlap
    /// with an object on the same support layer, no interpenetration of the moved object with
    /// anything but the table or floor.
    pub(super) fn placement_is_safe(&self, object: &str, body: usize) -> bool {
        let xpos = self.data.xpos();
        let p = xpos[body];
        if p[0].abs() > WORK_AREA || p[1].abs() > WORK_AREA {
            return false;
        }
        let radii = self.bundle.horizontal_radii.as_ref();
        let radius = |name: &str| radii.and_then(|r| r.get(name).copied());
        let own = radius(object).unwrap_or(DEFAULT_RADIUS);
        for (other, b) in &self.object_bodies {
            if other == object {
                continue;
            }
            let q = xpos[*b];
            if (q[2] - p[2]).abs() <= SAME_LAYER_DZ
                && (q[0] - p[0]).hypot(q[1] - p[1]) < own + radius(other).unwrap_or(DEFAULT_RADIUS) + FOOTPRINT_GAP
            {
                return false;
            }
        }
        let m = &self.model;
        let parent = m.body_parentid();
        let moved = |g: i32| {
            let mut b = m.geom_bodyid()[g as usize] as usize;
            loop {
                if b == body {
                    return true;
                }
                if b == 0 {
                    return false;
                }
                b = parent[b] as usize;
            }
        };
        let support = |g: i32| {
            m.id_to_name(MjtObj::mjOBJ_GEOM, g).is_some_and(|n| n == "floor" || n.ends_with("table_collision"))
        };
        !self.data.contacts().iter().any(|c| {
            let [a, b] = c.geom;
            c.dist < PENETRATION && (moved(a) || moved(b)) && !(support(a) || support(b))
        })
    }
}

/// The per-episode record of the placement perturbations (reset at every reset).
#[derive(Debug, Clone, Default)]
pub(super) struct MovesDone {
    pub initial: Option<AppliedMove>,
    pub runtime: Option<AppliedMove>,
    pub occlusion: Option<super::occlusion::AppliedOcclusion>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_candidate_is_the_request_lengthened_to_the_minimum() {
        let c = candidate_deltas([0.17, 0.06], 0.18);
        let n = 0.17f64.hypot(0.06).max(0.18);
        assert!((c[0][0].hypot(c[0][1]) - n).abs() < 1e-12);
        assert!((c[0][1].atan2(c[0][0]) - 0.06f64.atan2(0.17)).abs() < 1e-12);
        // the second is the same delta again, dropped as a duplicate: next is +π/2
        assert!((c[1][1].atan2(c[1][0]) - (0.06f64.atan2(0.17) + FRAC_PI_2)).abs() < 1e-12);
        assert_eq!(c.len(), MAX_CANDIDATES);
    }

    #[test]
    fn a_zero_request_still_moves_by_the_minimum() {
        let c = candidate_deltas([0.0, 0.0], 0.18);
        assert_eq!(c[0], [0.18, 0.0]);
    }
}
