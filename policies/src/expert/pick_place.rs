//! Pick an object and put it on or in a target: approach above the grasp, descend, close, lift
//! clear of whatever lies on the way, carry, lower onto the target, release, retreat.

use super::grasp::{Placement, obstacle_top, plan_grasp, plan_placement};
use super::motion::{
    down_orientation, hand_rotation, hand_yaw, nearest_equivalent_yaw, position_action, rotation_action, rotation_error,
};
use super::{SkillState, Step, action};
use crate::Observation;
use crate::scene::SceneView;
use nalgebra::Vector3;

const APPROACH: u8 = 0;
const DESCEND: u8 = 1;
const CLOSE: u8 = 2;
const LIFT: u8 = 3;
/// Carrying the held object over to its target (read by [`super::ExpertDrop`]).
pub(super) const CARRY: u8 = 4;
const LOWER: u8 = 5;
const RELEASE: u8 = 6;
const RETREAT: u8 = 7;

/// Height above the grasp point from which the hand descends.
const ABOVE: f64 = 0.08;
/// Clearance of the carried object's bottom over obstacles and the target.
const CLEARANCE: f64 = 0.04;
/// Speed limit (fraction of the largest action) while holding an object: fast swings make rim
/// grasps of bowls slip.
const CARRY_SPEED: f64 = 1.0;
const OPEN: f64 = -1.0;
const CLOSED: f64 = 1.0;

pub(super) fn step(
    st: &mut SkillState,
    view: &SceneView,
    obs: &Observation,
    obj: usize,
    relation: &str,
    target: &str,
) -> Step {
    let eef = Vector3::from(obs.eef_pos);
    let hand = hand_rotation(&obs.eef_quat);
    let o = &view.state.objects[obj];
    let root = Vector3::from(o.pos);
    let Some(place) = plan_placement(view, obj, relation, target) else { return Step::Done };
    let n = st.phase_steps;
    let go = |st: &SkillState, target: Vector3<f64>, gripper: f64, max: f64| {
        let r = down_orientation(st.yaw);
        Step::Act(action(position_action(&eef, &target, 1.5, max), rotation_action(&hand, &r), gripper))
    };
    match st.phase {
        APPROACH => {
            let g = plan_grasp(view, obj);
            st.yaw = nearest_equivalent_yaw(g.yaw, hand_yaw(&hand));
            let above = g.point + Vector3::new(0.0, 0.0, ABOVE);
            // Rise first when the hand is low and far, so it does not sweep through objects.
            let t = if (eef.xy() - above.xy()).norm() > 0.03 && eef.z < above.z - 0.02 {
                Vector3::new(eef.x, eef.y, above.z)
            } else {
                above
            };
            let settled = (eef - above).norm() < 0.012 && rotation_error(&hand, &down_orientation(st.yaw)) < 0.08;
            if settled || n > 120 {
                st.goto(DESCEND);
            }
            go(st, t, OPEN, 1.0)
        }
        DESCEND => {
            let g = plan_grasp(view, obj);
            let t = Vector3::new(g.point.x, g.point.y, g.point.z);
            if (eef - t).norm() < 0.006 || st.stalled(5, 0.002) || n > 60 {
                st.anchor = Vector3::new(t.x, t.y, eef.z);
                st.goto(CLOSE);
            }
            go(st, t, OPEN, 0.5)
        }
        CLOSE => {
            if n >= 12 {
                st.grasp_root_z = root.z;
                st.anchor = eef;
                st.goto(LIFT);
            }
            go(st, st.anchor, CLOSED, 0.5)
        }
        LIFT => {
            let carry = carry_height(view, obj, &eef, &place);
            let t = Vector3::new(st.anchor.x, st.anchor.y, carry);
            let rose = eef.z - st.anchor.z;
            if rose > 0.04 && root.z - st.grasp_root_z < 0.5 * rose {
                return Step::Done; // the grasp slipped: retry from the approach
            }
            if (eef - t).norm() < 0.015 || n > 80 {
                st.hold = eef - root;
                st.goto(CARRY);
            }
            go(st, t, CLOSED, CARRY_SPEED)
        }
        CARRY => {
            if dropped(st, &eef, &root) {
                return Step::Done;
            }
            let carry = carry_height(view, obj, &eef, &place).max(eef.z - 0.01);
            let over = place.root + st.hold;
            let t = Vector3::new(over.x, over.y, carry);
            if (eef.xy() - t.xy()).norm() < 0.008 || n > 150 {
                st.goto(LOWER);
            }
            go(st, t, CLOSED, CARRY_SPEED)
        }
        LOWER => {
            if dropped(st, &eef, &root) {
                return Step::Done;
            }
            let t = place.root + st.hold;
            if (eef - t).norm() < 0.005 || st.stalled(4, 0.0015) || n > 80 {
                st.anchor = eef;
                st.goto(RELEASE);
            }
            go(st, t, CLOSED, 0.4)
        }
        RELEASE => {
            if n >= 10 {
                st.anchor = eef + Vector3::new(0.0, 0.0, 0.10);
                st.goto(RETREAT);
            }
            go(st, st.anchor, OPEN, 0.3)
        }
        _ => {
            if (eef - st.anchor).norm() < 0.015 || n > 40 {
                return Step::Done;
            }
            go(st, st.anchor, OPEN, 0.6)
        }
    }
}

/// The object fell out of the hand while carried.
fn dropped(st: &SkillState, eef: &Vector3<f64>, root: &Vector3<f64>) -> bool {
    (eef - (root + st.hold)).norm() > 0.04
}

/// Hand height at which the carried object's bottom clears the path and the target.
fn carry_height(view: &SceneView, obj: usize, eef: &Vector3<f64>, place: &Placement) -> f64 {
    let o = &view.state.objects[obj];
    let hand_above_bottom = eef.z - o.world_box.min[2];
    let from = Vector3::from(o.pos);
    let top = obstacle_top(view, obj, &from, &place.root, 0.06).max(place.surface_z);
    top + CLEARANCE + hand_above_bottom
}
