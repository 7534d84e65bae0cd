//! Filling a privileged policy's [`SceneView`] from the env: the one place where the simulator's
//! geometry ([`SceneProbe`]) is translated into the MuJoCo-free types of `libero-policies`.

use libero_policies::scene::{
    Aabb, JointFacts, JointRule, JointState, ObjectFacts, ObjectState, SceneState, SceneView, SiteFacts, SiteState,
    TaskFacts,
};
use libero_sim::SimError;
use libero_sim::bundle::{ArticulationRule, Comparison};
use libero_sim::env::{Box3, LiberoEnv, SceneProbe};
use libero_sim::predicates::GoalStatus;
use std::sync::Arc;

/// Reads the scene of one episode.
pub struct SceneReader {
    facts: Arc<TaskFacts>,
    probe: SceneProbe,
}

fn aabb(b: Box3) -> Aabb {
    Aabb { min: b.0, max: b.1 }
}

fn joint_rule(r: Option<&ArticulationRule>) -> Option<JointRule> {
    r.map(|r| JointRule { above: !matches!(r.cmp, Comparison::Lt), value: r.value })
}

impl SceneReader {
    pub fn new(env: &LiberoEnv) -> Result<Self, SimError> {
        let task = &env.bundle().task;
        let objects =
            env.object_names().map(|n| ObjectFacts { name: n.to_string(), fixture: task.objects[n].fixture }).collect();
        let sites: Vec<SiteFacts> = task
            .sites
            .iter()
            .map(|(name, s)| SiteFacts {
                name: name.clone(),
                parent: s.parent.clone(),
                size: [0, 1, 2].map(|i| s.size.get(i).copied().unwrap_or(0.0)),
                joints: s.joints.clone(),
            })
            .collect();
        // The joints of every articulated object (drawers, doors, knobs).
        let joints: Vec<JointFacts> = task
            .objects
            .iter()
            .filter(|(_, o)| !o.articulation.is_empty())
            .flat_map(|(owner, o)| {
                o.joints.iter().map(move |j| JointFacts {
                    name: j.clone(),
                    owner: owner.clone(),
                    slide: false, // filled from the model below
                    open: joint_rule(o.articulation.get("open")),
                    close: joint_rule(o.articulation.get("close")),
                    turn_on: joint_rule(o.articulation.get("turnon")),
                    turn_off: joint_rule(o.articulation.get("turnoff")),
                })
            })
            .collect();
        let site_names: Vec<String> = sites.iter().map(|s| s.name.clone()).collect();
        let joint_names: Vec<String> = joints.iter().map(|j| j.name.clone()).collect();
        let probe = SceneProbe::new(env, &site_names, &joint_names)?;
        let mut facts = TaskFacts { goal: task.goal.clone(), objects, sites, joints };
        for (f, j) in facts.joints.iter_mut().zip(probe.joints(env)) {
            f.slide = j.slide;
        }
        Ok(SceneReader { facts: Arc::new(facts), probe })
    }

    /// The scene after the last step, with its goal status and the gripper's contacts.
    pub fn read(&self, env: &LiberoEnv, goal: &GoalStatus, gripper_contacts: &[usize]) -> SceneView {
        let objects = self
            .probe
            .objects(env)
            .into_iter()
            .map(|o| ObjectState {
                pos: o.pos,
                xmat: o.xmat,
                local_box: aabb(o.local_box),
                world_box: aabb(o.world_box),
            })
            .collect();
        let sites = self.probe.sites(env).into_iter().map(|s| SiteState { pos: s.pos, xmat: s.xmat }).collect();
        let joints = self
            .probe
            .joints(env)
            .into_iter()
            .map(|j| JointState { qpos: j.qpos, axis: j.axis, anchor: j.anchor, moving_box: aabb(j.moving_box) })
            .collect();
        SceneView {
            facts: self.facts.clone(),
            state: SceneState {
                objects,
                sites,
                joints,
                gripper_contacts: gripper_contacts.to_vec(),
                goal_terms: goal.terms.clone(),
            },
        }
    }
}
