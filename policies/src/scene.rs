//! Privileged simulator state for scripted policies: what the scene *is*, not what a camera sees.
//!
//! Learned policies never receive it (their [`Observation::scene`](crate::Observation::scene) is
//! `None`); the rollout fills it only for a policy whose [`Policy::wants_scene`](crate::Policy::wants_scene)
//! says so, such as the [`Expert`](crate::Expert). The types are plain data so that this crate
//! stays free of MuJoCo: the rollout (`libero-udfs`) reads them off the env.
//!
//! Static facts of the task ([`TaskFacts`]) are shared per episode; the per-step [`SceneState`]
//! lists the same objects, sites and joints in the same order.

use std::sync::Arc;

/// An axis-aligned box `[min, max]`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Aabb {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Aabb {
    pub fn center(&self) -> [f64; 3] {
        std::array::from_fn(|i| 0.5 * (self.min[i] + self.max[i]))
    }
    pub fn half_extent(&self) -> [f64; 3] {
        std::array::from_fn(|i| 0.5 * (self.max[i] - self.min[i]))
    }
}

/// `q <cmp> value` decides an articulation predicate (LIBERO's thresholds, from the bundle).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointRule {
    /// `true`: the predicate holds for `q > value` (or `>=`); `false`: for `q < value`.
    pub above: bool,
    pub value: f64,
}

impl JointRule {
    pub fn holds(&self, q: f64) -> bool {
        if self.above { q >= self.value } else { q < self.value }
    }
}

/// An object or fixture of the task (BDDL name).
#[derive(Debug, Clone)]
pub struct ObjectFacts {
    pub name: String,
    /// Fixtures (cabinets, stoves, tables) do not move.
    pub fixture: bool,
}

/// A BDDL region: a site with a box size, maybe on a parent object and tied to its joints.
#[derive(Debug, Clone)]
pub struct SiteFacts {
    pub name: String,
    pub parent: Option<String>,
    /// Half sizes of the region's box, in the site frame.
    pub size: [f64; 3],
    /// Joints of the parent that open/close this region (a drawer's slide).
    pub joints: Vec<String>,
}

/// A joint of an articulated object (drawer slide, door hinge, knob).
#[derive(Debug, Clone)]
pub struct JointFacts {
    pub name: String,
    /// The object owning it.
    pub owner: String,
    /// Slide (drawer) or hinge (door, knob).
    pub slide: bool,
    pub open: Option<JointRule>,
    pub close: Option<JointRule>,
    pub turn_on: Option<JointRule>,
    pub turn_off: Option<JointRule>,
}

/// What does not change during an episode.
#[derive(Debug, Clone, Default)]
pub struct TaskFacts {
    /// The BDDL goal, a conjunction of terms like `["on", "akita_black_bowl_1", "plate_1"]`.
    pub goal: Vec<Vec<String>>,
    pub objects: Vec<ObjectFacts>,
    pub sites: Vec<SiteFacts>,
    pub joints: Vec<JointFacts>,
}

impl TaskFacts {
    pub fn object(&self, name: &str) -> Option<usize> {
        self.objects.iter().position(|o| o.name == name)
    }
    pub fn site(&self, name: &str) -> Option<usize> {
        self.sites.iter().position(|s| s.name == name)
    }
    pub fn joint(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }
}

/// One object now.
#[derive(Debug, Clone, Copy, Default)]
pub struct ObjectState {
    /// Root body position (m, world).
    pub pos: [f64; 3],
    /// Root body orientation, world-from-body rotation matrix, row-major.
    pub xmat: [f64; 9],
    /// Box of its contact geoms in its root-body frame.
    pub local_box: Aabb,
    /// The same geoms' box in the world frame.
    pub world_box: Aabb,
}

/// One region site now.
#[derive(Debug, Clone, Copy, Default)]
pub struct SiteState {
    pub pos: [f64; 3],
    /// World-from-site rotation, row-major.
    pub xmat: [f64; 9],
}

/// One joint now.
#[derive(Debug, Clone, Copy, Default)]
pub struct JointState {
    pub qpos: f64,
    /// Joint axis in the world frame (direction of increasing `qpos`).
    pub axis: [f64; 3],
    /// A point on the axis (hinges), world frame.
    pub anchor: [f64; 3],
    /// World box of the geoms of the body the joint moves (a drawer with its handle, a door).
    pub moving_box: Aabb,
}

/// The scene at one step, in [`TaskFacts`] order.
#[derive(Debug, Clone, Default)]
pub struct SceneState {
    pub objects: Vec<ObjectState>,
    pub sites: Vec<SiteState>,
    pub joints: Vec<JointState>,
    /// Indices of the objects touching the gripper (grasp evidence).
    pub gripper_contacts: Vec<usize>,
    /// The goal terms' truth after the last step, in [`TaskFacts::goal`] order.
    pub goal_terms: Vec<bool>,
}

/// What a privileged policy sees besides the robot state.
#[derive(Debug, Clone)]
pub struct SceneView {
    pub facts: Arc<TaskFacts>,
    pub state: SceneState,
}
