//! A privileged scripted expert: the positive control of every run.
//!
//! It reads the simulator's state ([`SceneView`]: object boxes and poses, regions, joints, the
//! goal terms) and solves a task with the same 7-D delta end-effector actions a VLA emits, closed
//! loop on the observed hand pose ([`motion`]). The goal's terms become a plan of skills:
//! pick-and-place for `on`/`in`, and for articulated objects open / close / turn on / turn off
//! ([`articulate`]); an `in` a closed drawer is preceded by opening it, closing comes last. Each
//! skill is a small phase machine that retries from the approach when a grasp slips.

mod articulate;
mod grasp;
pub mod motion;
mod pick_place;

use crate::scene::SceneView;
use crate::{Action, Observation, Policy, PolicyError};
use nalgebra::Vector3;

/// One step of the plan.
#[derive(Debug, Clone, PartialEq)]
enum Skill {
    /// Put object `obj` on/in `target` (`relation` is `on` or `in`).
    Place { obj: usize, relation: String, target: String },
    /// Move joint `joint` until `rule` (one of open/close/turnon/turnoff) holds.
    Articulate { joint: usize, op: String },
}

/// The expert's memory within a skill.
#[derive(Debug, Clone, Default)]
pub(crate) struct SkillState {
    pub phase: u8,
    pub phase_steps: u32,
    pub attempts: u32,
    /// Hand position relative to the grasped object's root, measured after lifting.
    pub hold: Vector3<f64>,
    /// Object root height when the grasp closed.
    pub grasp_root_z: f64,
    /// A fixed target chosen when a phase started.
    pub anchor: Vector3<f64>,
    pub yaw: f64,
    /// Recent hand positions, to notice when a move has stalled against something.
    pub trail: Vec<Vector3<f64>>,
}

impl SkillState {
    pub fn goto(&mut self, phase: u8) {
        self.phase = phase;
        self.phase_steps = 0;
        self.trail.clear();
    }
    /// The hand moved less than `eps` over the last `n` steps of this phase.
    pub fn stalled(&self, n: usize, eps: f64) -> bool {
        self.trail.len() > n && (self.trail[self.trail.len() - 1] - self.trail[self.trail.len() - 1 - n]).norm() < eps
    }
}

/// What a skill asks for at one step.
pub(crate) enum Step {
    Act(Action),
    /// The skill finished (its term may or may not hold; the plan checks).
    Done,
}

/// Tries per skill before the expert moves on (a grasp that keeps slipping).
const MAX_ATTEMPTS: u32 = 4;

/// The scripted expert (`--policy expert`).
#[derive(Debug, Default)]
pub struct Expert {
    plan: Vec<(Skill, Option<usize>)>,
    current: usize,
    state: SkillState,
    rounds: u32,
    /// `LIBERO_EXPERT_TRACE=1` prints every skill and phase change to stderr (a diagnostic for
    /// tuning the skills; the per-step evidence itself is in the steps table).
    trace: bool,
    /// `LIBERO_EXPERT_TRACE=N` (N > 1) also prints every N-th action of a phase.
    trace_every: u32,
}

impl Expert {
    pub fn new() -> Self {
        let trace = std::env::var("LIBERO_EXPERT_TRACE").ok();
        let trace_every = trace.as_deref().and_then(|t| t.parse::<u32>().ok()).filter(|&n| n > 1).unwrap_or(0);
        Expert { trace: trace.is_some(), trace_every, ..Self::default() }
    }

    /// The plan for a goal: opening first, then placements, closing last. Each skill keeps the
    /// index of the goal term it serves (`None` for an inserted step such as opening a drawer).
    fn make_plan(view: &SceneView) -> Result<Vec<(Skill, Option<usize>)>, String> {
        let facts = &view.facts;
        let (mut first, mut middle, mut last) = (Vec::new(), Vec::new(), Vec::new());
        for (i, term) in facts.goal.iter().enumerate() {
            let arg = |k: usize| term.get(k).cloned().ok_or_else(|| format!("goal term {term:?} lacks argument {k}"));
            match term[0].as_str() {
                rel @ ("on" | "in") => {
                    let name = arg(1)?;
                    let obj = facts.object(&name).ok_or_else(|| format!("goal names unknown object {name}"))?;
                    let target = arg(2)?;
                    // `in` a drawer region: open its drawer first.
                    if rel == "in"
                        && let Some(s) = facts.site(&target)
                    {
                        for j in &facts.sites[s].joints {
                            if let Some(ji) = facts.joint(j)
                                && facts.joints[ji].open.is_some()
                            {
                                first.push((Skill::Articulate { joint: ji, op: "open".into() }, None));
                            }
                        }
                    }
                    middle.push((Skill::Place { obj, relation: rel.into(), target }, Some(i)));
                }
                op @ ("open" | "close" | "turnon" | "turnoff") => {
                    let name = arg(1)?;
                    let joint = articulate::joint_of(facts, &name).ok_or_else(|| format!("no joint for {name}"))?;
                    let skill = (Skill::Articulate { joint, op: op.into() }, Some(i));
                    if op == "close" { last.push(skill) } else { first.push(skill) }
                }
                other => return Err(format!("the expert cannot plan for the predicate {other:?}")),
            }
        }
        first.extend(middle);
        first.extend(last);
        Ok(first)
    }

    fn skill_holds(view: &SceneView, skill: &Skill, term: Option<usize>) -> bool {
        match (skill, term) {
            (_, Some(t)) => view.state.goal_terms.get(t).copied().unwrap_or(false),
            (Skill::Articulate { joint, op }, None) => articulate::rule_holds(view, *joint, op),
            (Skill::Place { .. }, None) => false,
        }
    }
}

impl Policy for Expert {
    fn reset(&mut self, _instruction: &str, _episode_seed: u64) {
        *self = Expert { trace: self.trace, trace_every: self.trace_every, ..Expert::new() };
    }

    fn wants_scene(&self) -> bool {
        true
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        let err = |detail: String| PolicyError { policy: "expert".into(), detail };
        let view = obs
            .scene
            .as_ref()
            .ok_or_else(|| err("no scene view: the rollout did not provide privileged state".into()))?;
        if obs.policy_step == 0 || self.plan.is_empty() {
            self.plan = Self::make_plan(view).map_err(err)?;
            self.current = 0;
            self.state = SkillState::default();
        }
        let eef = Vector3::from(obs.eef_pos);
        loop {
            if self.current >= self.plan.len() {
                // Everything done once: start again at the first term that does not hold.
                match self.plan.iter().position(|(s, t)| !Self::skill_holds(view, s, *t)) {
                    Some(i) if self.rounds < 2 => {
                        self.rounds += 1;
                        self.current = i;
                        self.state = SkillState::default();
                    }
                    _ => return Ok(hold_still()),
                }
            }
            let (skill, term) = &self.plan[self.current];
            if self.state.phase == 0 && self.state.phase_steps == 0 && Self::skill_holds(view, skill, *term) {
                self.current += 1;
                continue;
            }
            self.state.trail.push(eef);
            let before = (self.state.phase, self.state.attempts);
            let step = match skill {
                Skill::Place { obj, relation, target } => {
                    pick_place::step(&mut self.state, view, obs, *obj, relation, target)
                }
                Skill::Articulate { joint, op } => articulate::step(&mut self.state, view, obs, *joint, op),
            };
            self.state.phase_steps += 1;
            if self.trace && (self.state.phase != before.0 || self.state.attempts != before.1 || obs.policy_step == 0) {
                eprintln!(
                    "expert step {:3} skill {} {:?} attempt {} phase {} -> {} eef [{:.3} {:.3} {:.3}] yaw {:.2} (hand {:.2}) grip {:.4} terms {:?}",
                    obs.policy_step,
                    self.current,
                    skill,
                    self.state.attempts,
                    before.0,
                    self.state.phase,
                    eef.x,
                    eef.y,
                    eef.z,
                    self.state.yaw,
                    motion::hand_yaw(&motion::hand_rotation(&obs.eef_quat)),
                    obs.gripper_qpos[0],
                    view.state.goal_terms,
                );
            }
            match step {
                Step::Act(a) => {
                    if self.trace_every > 0 && self.state.phase_steps.is_multiple_of(self.trace_every) {
                        let q = obs.eef_quat;
                        eprintln!(
                            "expert step {:3}   phase {} n {} eef [{:.3} {:.3} {:.3}] quat [{:.3} {:.3} {:.3} {:.3}] action {:.2?}",
                            obs.policy_step,
                            self.state.phase,
                            self.state.phase_steps,
                            eef.x,
                            eef.y,
                            eef.z,
                            q[0],
                            q[1],
                            q[2],
                            q[3],
                            a
                        );
                    }
                    return Ok(a);
                }
                Step::Done => {
                    let retry = !Self::skill_holds(view, skill, *term) && self.state.attempts + 1 < MAX_ATTEMPTS;
                    if self.trace {
                        eprintln!(
                            "expert step {:3} skill {} done in phase {} (holds: {}, retry: {retry})",
                            obs.policy_step,
                            self.current,
                            self.state.phase,
                            Self::skill_holds(view, skill, *term)
                        );
                    }
                    if retry {
                        let attempts = self.state.attempts + 1;
                        self.state = SkillState { attempts, ..Default::default() };
                    } else {
                        self.current += 1;
                        self.state = SkillState::default();
                    }
                }
            }
        }
    }
}

/// Carry steps after which [`ExpertDrop`] lets go: the object is then well clear of the table.
const FORCED_RELEASE_AFTER_CARRY_STEPS: u32 = 5;

/// Diagnostic (`--policy expert-drop`): the expert, forced to open its gripper a few steps into
/// its first carry and then to hold still. Its episodes are real drops (an object of interest
/// lifted and let fall away from its goal), which the failure-mode analysis must call `dropped`.
#[derive(Debug, Default)]
pub struct ExpertDrop {
    expert: Expert,
    released: bool,
}

impl ExpertDrop {
    pub fn new() -> Self {
        ExpertDrop { expert: Expert::new(), released: false }
    }

    fn carrying(&self) -> bool {
        matches!(self.expert.plan.get(self.expert.current), Some((Skill::Place { .. }, _)))
            && self.expert.state.phase == pick_place::CARRY
            && self.expert.state.phase_steps >= FORCED_RELEASE_AFTER_CARRY_STEPS
    }
}

impl Policy for ExpertDrop {
    fn reset(&mut self, instruction: &str, episode_seed: u64) {
        self.expert.reset(instruction, episode_seed);
        self.released = false;
    }

    fn wants_scene(&self) -> bool {
        true
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        if self.released {
            return Ok(hold_still());
        }
        let a = self.expert.act(obs)?;
        if self.carrying() {
            self.released = true;
            return Ok(hold_still());
        }
        Ok(a)
    }
}

/// Open gripper, no motion.
fn hold_still() -> Action {
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]
}

/// Assemble a 7-D action from position, rotation and gripper parts (clipped to [-1, 1]).
pub(crate) fn action(pos: [f64; 3], rot: [f64; 3], gripper: f64) -> Action {
    let c = |x: f64| x.clamp(-1.0, 1.0) as f32;
    [c(pos[0]), c(pos[1]), c(pos[2]), c(rot[0]), c(rot[1]), c(rot[2]), c(gripper)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{ObjectFacts, ObjectState, SceneState, TaskFacts};
    use crate::{LiftPolicy, RandomPolicy};
    use std::sync::Arc;

    #[test]
    fn only_the_expert_asks_for_privileged_state_and_it_fails_loudly_without_it() {
        assert!(Expert::new().wants_scene());
        assert!(!RandomPolicy::new().wants_scene() && !LiftPolicy.wants_scene());
        let err = Expert::new().act(&Observation::default()).unwrap_err();
        assert!(err.detail.contains("no scene view"), "{err}");
    }

    #[test]
    fn a_goal_it_cannot_plan_for_is_an_error_naming_the_predicate() {
        let facts = TaskFacts {
            goal: vec![vec!["up".into(), "bowl".into()]],
            objects: vec![ObjectFacts { name: "bowl".into(), fixture: false }],
            ..Default::default()
        };
        let scene = SceneView {
            facts: Arc::new(facts),
            state: SceneState { objects: vec![ObjectState::default()], goal_terms: vec![false], ..Default::default() },
        };
        let obs = Observation { scene: Some(scene), ..Default::default() };
        let err = Expert::new().act(&obs).unwrap_err();
        assert!(err.detail.contains("\"up\""), "{err}");
    }

    #[test]
    fn drawers_open_first_and_close_last_around_the_placement() {
        let facts = TaskFacts {
            goal: vec![
                vec!["close".into(), "cabinet_region".into()],
                vec!["in".into(), "bowl".into(), "cabinet_region".into()],
            ],
            objects: vec![
                ObjectFacts { name: "bowl".into(), fixture: false },
                ObjectFacts { name: "cabinet".into(), fixture: true },
            ],
            sites: vec![crate::scene::SiteFacts {
                name: "cabinet_region".into(),
                parent: Some("cabinet".into()),
                size: [0.1; 3],
                joints: vec!["slide".into()],
            }],
            joints: vec![crate::scene::JointFacts {
                name: "slide".into(),
                owner: "cabinet".into(),
                slide: true,
                open: Some(crate::scene::JointRule { above: false, value: -0.14 }),
                close: Some(crate::scene::JointRule { above: true, value: 0.0 }),
                turn_on: None,
                turn_off: None,
            }],
        };
        let view = SceneView { facts: Arc::new(facts), state: SceneState::default() };
        let plan: Vec<Skill> = Expert::make_plan(&view).unwrap().into_iter().map(|(s, _)| s).collect();
        assert_eq!(
            plan,
            [
                Skill::Articulate { joint: 0, op: "open".into() },
                Skill::Place { obj: 0, relation: "in".into(), target: "cabinet_region".into() },
                Skill::Articulate { joint: 0, op: "close".into() },
            ]
        );
    }
}
