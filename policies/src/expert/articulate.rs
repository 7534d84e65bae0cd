//! Moving a joint until a predicate holds: pulling a drawer open by its handle, pushing a drawer or
//! a door closed, turning a stove knob by pushing the end of its bar.
//!
//! Directions come from the joint itself: the rule says whether `qpos` must rise or fall, the
//! joint's world axis (and anchor, for hinges) turns that into the way the contact point moves.

use super::grasp::FINGER_CLEARANCE;
use super::motion::{
    down_orientation, hand_rotation, hand_yaw, nearest_equivalent_yaw, position_action, rotation_action,
    yaw_closing_along,
};
use super::{SkillState, Step, action};
use crate::Observation;
use crate::scene::{JointRule, SceneView, TaskFacts};
use nalgebra::Vector3;

/// The joint an `open`/`close`/`turnon`/`turnoff` term acts on: a region's own joint (one drawer
/// of a cabinet) or the object's first joint with a rule.
pub(super) fn joint_of(facts: &TaskFacts, name: &str) -> Option<usize> {
    if let Some(s) = facts.site(name) {
        return facts.sites[s].joints.first().and_then(|j| facts.joint(j));
    }
    facts.joints.iter().position(|j| j.owner == name)
}

fn rule(facts: &TaskFacts, joint: usize, op: &str) -> Option<JointRule> {
    let j = &facts.joints[joint];
    match op {
        "open" => j.open,
        "close" => j.close,
        "turnon" => j.turn_on,
        "turnoff" => j.turn_off,
        _ => None,
    }
}

pub(super) fn rule_holds(view: &SceneView, joint: usize, op: &str) -> bool {
    rule(&view.facts, joint, op).is_some_and(|r| r.holds(view.state.joints[joint].qpos))
}

/// Where to push from and which way, for the joint to move toward the rule.
struct Push {
    /// The contact point (on the moving part).
    point: Vector3<f64>,
    /// Unit horizontal direction the point must move.
    dir: Vector3<f64>,
}

fn horizontal(v: Vector3<f64>) -> Vector3<f64> {
    let h = Vector3::new(v.x, v.y, 0.0);
    if h.norm() < 1e-9 { Vector3::x() } else { h.normalize() }
}

fn push_geometry(view: &SceneView, joint: usize, raise: bool) -> Push {
    let (facts, js) = (&view.facts.joints[joint], &view.state.joints[joint]);
    let sign = if raise { 1.0 } else { -1.0 };
    let b = &js.moving_box;
    let c = Vector3::from(b.center());
    let h = Vector3::from(b.half_extent());
    let axis = Vector3::from(js.axis);
    if facts.slide {
        let dir = horizontal(axis * sign);
        // The face that leads against the motion: push it from behind.
        let depth = h.x * dir.x.abs() + h.y * dir.y.abs();
        return Push { point: c - dir * depth, dir };
    }
    let anchor = Vector3::from(js.anchor);
    let mut r = c - anchor;
    r -= axis * axis.dot(&r);
    let (r_hat, reach) = if r.norm() > 0.02 {
        // A door: push near its free edge.
        (r.normalize(), 1.6 * r.norm())
    } else {
        // A knob: push one end of its bar (the box's long horizontal side).
        let r_hat = if h.x >= h.y { -Vector3::x() } else { -Vector3::y() };
        (r_hat, 0.8 * h.x.max(h.y))
    };
    let mut point = anchor + r_hat * reach;
    point.z = c.z;
    let dir = horizontal(axis.cross(&r_hat) * sign);
    Push { point, dir }
}

const ABOVE: f64 = 0.08;
/// Pushing: approach 3 cm behind the contact, push through by this much.
const BEHIND: f64 = 0.035;
const THROUGH: f64 = 0.06;

pub(super) fn step(st: &mut SkillState, view: &SceneView, obs: &Observation, joint: usize, op: &str) -> Step {
    let Some(r) = rule(&view.facts, joint, op) else { return Step::Done };
    let raise = r.above;
    if view.facts.joints[joint].slide && op == "open" {
        return pull(st, view, obs, joint, raise);
    }
    push(st, view, obs, joint, op, raise)
}

fn push(st: &mut SkillState, view: &SceneView, obs: &Observation, joint: usize, op: &str, raise: bool) -> Step {
    let eef = Vector3::from(obs.eef_pos);
    let hand = hand_rotation(&obs.eef_quat);
    let p = push_geometry(view, joint, raise);
    let n = st.phase_steps;
    // Fingers closed, pointing down, the closed fingers' flat side facing the push.
    st.yaw = nearest_equivalent_yaw(yaw_closing_along(&Vector3::new(-p.dir.y, p.dir.x, 0.0)), hand_yaw(&hand));
    let height = p.point.z.max(view.state.joints[joint].moving_box.min[2] + FINGER_CLEARANCE);
    let start = Vector3::new(p.point.x, p.point.y, height) - p.dir * BEHIND;
    let go = |st: &SkillState, t: Vector3<f64>, max: f64| {
        Step::Act(action(position_action(&eef, &t, 1.5, max), rotation_action(&hand, &down_orientation(st.yaw)), 1.0))
    };
    match st.phase {
        0 => {
            let above = start + Vector3::new(0.0, 0.0, ABOVE);
            let t = if (eef.xy() - above.xy()).norm() > 0.03 && eef.z < above.z - 0.02 {
                Vector3::new(eef.x, eef.y, above.z)
            } else {
                above
            };
            if (eef - above).norm() < 0.012 || n > 120 {
                st.goto(1);
            }
            go(st, t, 1.0)
        }
        1 => {
            if (eef - start).norm() < 0.008 || st.stalled(5, 0.002) || n > 60 {
                st.goto(2);
            }
            go(st, start, 0.5)
        }
        2 => {
            let t = Vector3::new(p.point.x, p.point.y, height) + p.dir * THROUGH;
            if rule_holds(view, joint, op) && n > 3 || n > 120 {
                st.anchor = eef - p.dir * 0.04 + Vector3::new(0.0, 0.0, 0.06);
                st.goto(3);
            }
            go(st, t, 0.6)
        }
        _ => {
            if (eef - st.anchor).norm() < 0.015 || n > 40 {
                return Step::Done;
            }
            go(st, st.anchor, 0.6)
        }
    }
}

/// Half-width of the fingers (m per finger) while straddling a drawer handle.
const HANDLE_HALF_WIDTH: f64 = 0.0175;

/// Open a drawer: straddle its handle with the fingers part-open, close, pull along the slide.
fn pull(st: &mut SkillState, view: &SceneView, obs: &Observation, joint: usize, raise: bool) -> Step {
    let eef = Vector3::from(obs.eef_pos);
    let hand = hand_rotation(&obs.eef_quat);
    let js = &view.state.joints[joint];
    let b = &js.moving_box;
    let dir = horizontal(Vector3::from(js.axis) * if raise { 1.0 } else { -1.0 });
    let (c, h) = (Vector3::from(b.center()), Vector3::from(b.half_extent()));
    let depth = h.x * dir.x.abs() + h.y * dir.y.abs();
    // The handle bar: 1.5 cm deep at the front of the drawer's box, at the drawer's mid height.
    let handle = c + dir * (depth - 0.0075);
    let n = st.phase_steps;
    st.yaw = nearest_equivalent_yaw(yaw_closing_along(&dir), hand_yaw(&hand));
    let q0 = obs.gripper_qpos[0];
    let part_open = if q0 > HANDLE_HALF_WIDTH + 0.002 {
        1.0
    } else if q0 < HANDLE_HALF_WIDTH - 0.002 {
        -1.0
    } else {
        0.0
    };
    let go = |st: &SkillState, t: Vector3<f64>, max: f64, g: f64| {
        Step::Act(action(position_action(&eef, &t, 1.5, max), rotation_action(&hand, &down_orientation(st.yaw)), g))
    };
    let grasp = Vector3::new(handle.x, handle.y, handle.z + 0.004);
    match st.phase {
        0 => {
            let above = grasp + Vector3::new(0.0, 0.0, ABOVE);
            let t = if (eef.xy() - above.xy()).norm() > 0.03 && eef.z < above.z - 0.02 {
                Vector3::new(eef.x, eef.y, above.z)
            } else {
                above
            };
            if (eef - above).norm() < 0.01 && (q0 - HANDLE_HALF_WIDTH).abs() < 0.004 || n > 120 {
                st.goto(1);
            }
            go(st, t, 1.0, part_open)
        }
        1 => {
            if (eef - grasp).norm() < 0.006 || st.stalled(5, 0.0015) || n > 60 {
                st.anchor = eef;
                st.goto(2);
            }
            go(st, grasp, 0.4, part_open)
        }
        2 => {
            if n >= 10 {
                st.goto(3);
            }
            go(st, st.anchor, 0.3, 1.0)
        }
        3 => {
            let t = st.anchor + dir * 0.22;
            if rule_holds(view, joint, "open") && n > 5 || n > 120 {
                st.anchor = eef;
                st.goto(4);
            }
            go(st, t, 0.5, 1.0)
        }
        4 => {
            if n >= 8 {
                st.anchor = eef + Vector3::new(0.0, 0.0, 0.08);
                st.goto(5);
            }
            go(st, st.anchor, 0.3, -1.0)
        }
        _ => {
            if (eef - st.anchor).norm() < 0.015 || n > 40 {
                return Step::Done;
            }
            go(st, st.anchor, 0.6, -1.0)
        }
    }
}
