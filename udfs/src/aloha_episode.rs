//! One ALOHA-sim episode: `reset(seed)`, then the policy until the cap (or the first success when
//! asked), recording every step as a row of [`tables::aloha_steps`]; the episode row is the
//! LIBERO one ([`crate::episode::episode_batch`]), so every score reads both benchmarks alike.
//!
//! The loop is lerobot's and gym-aloha's: no wait steps, the action of step t from the
//! observation after step t − 1, success = reward 4 (`is_success`). gym-aloha terminates at the
//! first success; here the default runs to the cap, as for LIBERO, so that last-step scoring
//! stays possible, and `success` (reward 4 at any step within the cap) is lerobot's either way.

use crate::episode::{EpisodeError, EpisodeProtocol, EpisodeSummary};
use crate::goal_evidence::GoalChanges;
use crate::real_time::{RealTimeClock, Tick, aloha_hold};
use crate::steps_batch::{EpisodeKey, fixed_f32, fixed_f64, object_poses_column, timing_columns};
use arrow::array::{ArrayRef, BooleanArray, Int32Array, RecordBatch};
use arrow::error::ArrowError;
use libero_policies::aloha::{AlohaAction, AlohaObservation, AlohaPolicy};
use libero_policies::{CameraImage, PolicyError};
use libero_schema::benchmark::aloha as aloha_protocol;
use libero_schema::tables;
use libero_sim::SimError;
use libero_sim::aloha::{AlohaBundle, AlohaEnv, AlohaTask, MAX_REWARD, ScriptRecorder};
use libero_sim::gl_thread::OnGlThread;
use libero_sim::render::SceneRenderer;
use std::sync::Arc;
use std::time::Instant;

/// A rollout worker's ALOHA-sim env for one task, the recorder of the scripted control and the
/// renderer of the `top` camera (each made when a policy first asks for it).
pub struct AlohaWorker {
    pub task: AlohaTask,
    env: AlohaEnv,
    recorder: Option<ScriptRecorder>,
    renderer: Option<OnGlThread<SceneRenderer>>,
}

impl AlohaWorker {
    pub fn new(bundle: &AlohaBundle, task: AlohaTask) -> Result<Self, SimError> {
        Ok(AlohaWorker { task, env: AlohaEnv::new(bundle, task)?, recorder: None, renderer: None })
    }

    /// `obs["pixels"]["top"]` of the current state (480 × 640, upright), as a policy sees it.
    fn render_top(&mut self) -> Result<CameraImage, SimError> {
        let env = &mut self.env;
        if self.renderer.is_none() {
            let thread = crate::policy_cameras::worker_gl()?;
            // SAFETY: the env (MuJoCo model and data) is used on the GL thread while this one waits.
            self.renderer = Some(unsafe { OnGlThread::make(thread, |gl| env.renderer(gl.clone()))? });
        }
        let renderer = self.renderer.as_mut().expect("made above");
        // SAFETY: as above; the renderer was made on that thread.
        let frame = unsafe { renderer.with(|renderer| env.render_top(renderer)) }?;
        Ok(CameraImage { width: frame.width, height: frame.height, rgb: frame.rgb })
    }
}

/// sha256 of what an ALOHA-sim episode starts from: the task's scene file (its hash in the
/// bundle's provenance) and the objects' initial pose. Equal hashes start identically.
pub fn aloha_start_sha256(bundle: &AlohaBundle, task: AlohaTask, pose: &[f64]) -> String {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    let scene = format!("assets/{}", task.scene_file());
    h.update(bundle.provenance["sha256"][&scene].as_str().unwrap_or_default().as_bytes());
    for v in pose {
        h.update(v.to_le_bytes());
    }
    format!("{:x}", h.finalize())
}

/// Run one episode of `worker`'s task with the objects where `key.seed` puts them.
pub fn run_aloha_episode(
    worker: &mut AlohaWorker,
    bundle: &AlohaBundle,
    policy: &mut dyn AlohaPolicy,
    key: &EpisodeKey,
    protocol: &EpisodeProtocol,
    policy_seed: u64,
) -> (Result<RecordBatch, ArrowError>, EpisodeSummary) {
    let t_start = Instant::now();
    let task = worker.task;
    let mut steps = AlohaStepsBuilder::new(key.clone(), task);
    let mut summary = EpisodeSummary {
        instruction: task.instruction().to_string(),
        instruction_source: "task",
        start_sha256: None,
        n_policy_steps: 0,
        first_success_step: None,
        final_goal: false,
        goal_changes: GoalChanges::default(),
        // the goal is one predicate, reward 4
        goal_terms: vec![],
        objects_of_interest: task.object_names().iter().map(|s| s.to_string()).collect(),
        error: None,
        wall_s: 0.0,
        sim_s: 0.0,
        policy_s: 0.0,
        render_s: 0.0,
        started_at: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).ok().map(|d| d.as_secs_f64()),
    };
    let fail = |mut summary: EpisodeSummary, error: EpisodeError, steps: AlohaStepsBuilder| {
        summary.error = Some(error);
        summary.wall_s = t_start.elapsed().as_secs_f64();
        (steps.finish(), summary)
    };
    // the spec validation keeps seeds in u32 (numpy's RandomState takes 0 ..= 2^32 - 1)
    let Ok(seed) = u32::try_from(key.seed) else {
        let e = EpisodeError { kind: "bundle", message: format!("seed {} is outside 0..=4294967295", key.seed) };
        return fail(summary, e, steps);
    };
    let pose = task.initial_pose(seed);
    summary.start_sha256 = Some(aloha_start_sha256(bundle, task, &pose));
    if let Err(e) = worker.env.reset_to_pose(&pose) {
        return fail(summary, EpisodeError::from_sim(&e), steps);
    }
    policy.reset(policy_seed);
    let script = if policy.wants_script() {
        let recorder = match worker.recorder.take() {
            Some(r) => Ok(r),
            None => ScriptRecorder::new(bundle, task),
        };
        match recorder.and_then(|mut r| {
            let plan = r.record(&pose);
            worker.recorder = Some(r);
            plan
        }) {
            Ok(plan) => Some(Arc::new(plan.actions().to_vec())),
            Err(e) => return fail(summary, EpisodeError::from_sim(&e), steps),
        }
    } else {
        None
    };
    // the joints after step t are what the policy sees before step t + 1: read them once a step
    let mut agent_pos = worker.env.agent_pos();
    let mut clock: Option<RealTimeClock<AlohaAction, QueryCost>> =
        protocol.realtime.map(|rt| RealTimeClock::new(rt, aloha_protocol::CONTROL_FREQ_HZ as u32));
    // the last policy action the env ran (what a real-time hold repeats or keeps the grippers of)
    let mut last_action: Option<AlohaAction> = None;
    for p in 0..protocol.max_steps {
        let mut cost = QueryCost::default();
        let mut held = false;
        let action = match clock.as_mut().map_or(Tick::Query, RealTimeClock::tick) {
            Tick::Hold => {
                held = true;
                aloha_hold(protocol.realtime.expect("a clock is real time").hold, last_action.as_ref(), &agent_pos)
            }
            Tick::Answer(a, answer_cost) => {
                cost = answer_cost;
                a
            }
            Tick::Query => {
                let queries_model = policy.queries_model();
                let top = if policy.wants_top_camera() {
                    let t0 = Instant::now();
                    let top = worker.render_top();
                    cost.render_ms = t0.elapsed().as_secs_f32() * 1e3;
                    summary.render_s += cost.render_ms as f64 / 1e3;
                    match top {
                        Ok(top) => Some(top),
                        Err(e) => {
                            summary.error = Some(EpisodeError::from_sim(&e));
                            break;
                        }
                    }
                } else {
                    None
                };
                let obs =
                    AlohaObservation { task: task.name(), policy_step: p, agent_pos, top, script: script.clone() };
                let t0 = Instant::now();
                let action: Result<AlohaAction, PolicyError> = policy.act(&obs);
                cost.policy_ms = t0.elapsed().as_secs_f32() * 1e3;
                summary.policy_s += cost.policy_ms as f64 / 1e3;
                let action = match action {
                    Ok(a) => a,
                    Err(e) => {
                        summary.error = Some(EpisodeError { kind: "policy", message: e.to_string() });
                        break;
                    }
                };
                match clock.as_mut() {
                    None => action,
                    Some(c) => {
                        let latency = c.latency_ms(queries_model, cost.policy_ms as f64);
                        match c.answered(action, cost, latency) {
                            Some((a, _)) => a,
                            // late: this step holds, and the query's cost goes with the answer's step
                            None => {
                                held = true;
                                cost = QueryCost::default();
                                aloha_hold(c.hold(), last_action.as_ref(), &agent_pos)
                            }
                        }
                    }
                }
            }
        };
        if !held {
            last_action = Some(action);
        }
        let t0 = Instant::now();
        let reward = worker.env.step(&action);
        let sim_ms = t0.elapsed().as_secs_f32() * 1e3;
        summary.sim_s += sim_ms as f64 / 1e3;
        let reward = match reward {
            Ok(r) => r,
            Err(e) => {
                summary.error = Some(EpisodeError::from_sim(&e));
                break;
            }
        };
        let goal = reward == MAX_REWARD;
        agent_pos = worker.env.agent_pos();
        let timing = StepTiming { sim_ms, policy_ms: cost.policy_ms, render_ms: cost.render_ms, held };
        steps.push(p as i32, &action, &agent_pos, &worker.env.qpos()[16..], goal, reward, timing);
        summary.n_policy_steps = p + 1;
        summary.final_goal = goal;
        summary.goal_changes.record(p, goal);
        if goal && summary.first_success_step.is_none() {
            summary.first_success_step = Some(p);
            if protocol.stop_on_success {
                break;
            }
        }
    }
    summary.wall_s = t_start.elapsed().as_secs_f64();
    (steps.finish(), summary)
}

/// Column buffers of one ALOHA-sim episode's steps ([`tables::aloha_steps`]).
struct AlohaStepsBuilder {
    key: EpisodeKey,
    object_names: &'static [&'static str],
    step: Vec<i32>,
    action: Vec<f32>,
    agent_pos: Vec<f64>,
    object_pos: Vec<f64>,
    object_quat: Vec<f64>,
    goal: Vec<bool>,
    reward: Vec<i32>,
    sim_ms: Vec<f32>,
    policy_ms: Vec<f32>,
    render_ms: Vec<f32>,
    held: Vec<bool>,
}

/// Where one step's time went (ms): the env, the policy, rendering its camera; and whether it
/// was a real-time hold.
struct StepTiming {
    sim_ms: f32,
    policy_ms: f32,
    render_ms: f32,
    held: bool,
}

/// What a policy query cost (ms): its camera render and its `act` call.
#[derive(Debug, Clone, Copy, Default)]
struct QueryCost {
    render_ms: f32,
    policy_ms: f32,
}

impl AlohaStepsBuilder {
    fn new(key: EpisodeKey, task: AlohaTask) -> Self {
        AlohaStepsBuilder {
            key,
            object_names: task.object_names(),
            step: vec![],
            action: vec![],
            agent_pos: vec![],
            object_pos: vec![],
            object_quat: vec![],
            goal: vec![],
            reward: vec![],
            sim_ms: vec![],
            policy_ms: vec![],
            render_ms: vec![],
            held: vec![],
        }
    }

    /// One step; `objects` is `qpos[16..]` (position and (w, x, y, z) of each object).
    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        step: i32,
        action: &AlohaAction,
        agent_pos: &[f64; 14],
        objects: &[f64],
        goal: bool,
        reward: u8,
        timing: StepTiming,
    ) {
        self.step.push(step);
        self.action.extend_from_slice(action);
        self.agent_pos.extend_from_slice(agent_pos);
        for pose in objects.chunks_exact(7) {
            self.object_pos.extend_from_slice(&pose[..3]);
            self.object_quat.extend_from_slice(&pose[3..]);
        }
        self.goal.push(goal);
        self.reward.push(reward as i32);
        self.sim_ms.push(timing.sim_ms);
        self.policy_ms.push(timing.policy_ms);
        self.render_ms.push(timing.render_ms);
        self.held.push(timing.held);
    }

    fn finish(self) -> Result<RecordBatch, ArrowError> {
        let (n, k) = (self.step.len(), &self.key);
        let poses = object_poses_column(self.object_names, n, self.object_pos, self.object_quat)?;
        let mut columns = k.columns(n);
        columns.extend::<[ArrayRef; 8]>([
            Arc::new(Int32Array::from(self.step.clone())),
            Arc::new(Int32Array::from(self.step)),
            Arc::new(BooleanArray::from(vec![false; n])),
            fixed_f32(self.action, 14)?,
            fixed_f64(self.agent_pos, 14)?,
            poses,
            Arc::new(BooleanArray::from(self.goal)),
            Arc::new(Int32Array::from(self.reward)),
        ]);
        // no ALOHA policy reports model timings (a forward's split) yet
        columns.extend(timing_columns(self.sim_ms, self.policy_ms, self.render_ms, &vec![None; n]));
        columns.push(Arc::new(BooleanArray::from(self.held)));
        RecordBatch::try_new(tables::aloha_steps(), columns)
    }
}
