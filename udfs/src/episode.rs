//! One episode of the protocol: reset, the wait steps, then the policy until the cap (or the
//! first success when asked), recording every step; and its one-row episode batch.
//!
//! The loop is OpenVLA's `run_libero_eval.py` (inherited by openpi and vla-eval): `reset()`,
//! `set_init_state(init_states[i])`, `num_steps_wait` steps of `[0,0,0,0,0,0,-1]` whose `done` is
//! ignored, then up to `max_steps` policy steps. The published scripts stop at the first success;
//! here the default is to run to the cap so that last-step scoring stays possible, and
//! `success` (any policy step within the cap) equals the published first-success latch either way.

use crate::goal_evidence::GoalChanges;
use crate::perturbation::EpisodePerturbation;
use crate::policy_cameras::PolicyCameras;
use crate::real_time::{RealTimeClock, Tick, libero_hold};
use crate::scene_view::SceneReader;
use crate::steps_batch::{EpisodeKey, StepRecord, StepsBatchBuilder};
use arrow::array::{ArrayRef, BooleanArray, Float64Array, Int32Array, Int64Array, ListArray, RecordBatch, StringArray};
use arrow::buffer::OffsetBuffer;
use arrow::datatypes::{DataType, Field};
use libero_policies::{Observation, Policy};
use libero_schema::protocol::{CONTROL_FREQ_HZ, WAIT_ACTION};
use libero_schema::real_time::RealTime;
use libero_schema::{Benchmark, InstructionSource, Suite, tables};
use libero_sim::SimError;
use libero_sim::env::LiberoEnv;
use libero_sim::image_noise::SeededDraws;
use std::sync::Arc;
use std::time::Instant;

/// What the protocol fixes for an episode.
#[derive(Debug, Clone)]
pub struct EpisodeProtocol {
    pub max_steps: u32,
    pub num_steps_wait: u32,
    pub stop_on_success: bool,
    /// Which of the task's instruction texts the policy gets.
    pub instruction_source: InstructionSource,
    /// Real-time evaluation: latency and hold ([`crate::real_time`]); None for closed loop.
    pub realtime: Option<RealTime>,
    /// Which published loop a LIBERO episode reproduces (how the env was seeded, so its fixture
    /// poses); None for ALOHA-sim, whose only loop is lerobot's.
    pub protocol: Option<libero_schema::EvalProtocol>,
}

/// Why an episode ended early; stored as `error_kind` / `error`.
#[derive(Debug, Clone)]
pub struct EpisodeError {
    pub kind: &'static str,
    pub message: String,
}

impl EpisodeError {
    pub fn from_sim(e: &SimError) -> Self {
        let kind = match e {
            SimError::Unstable { .. } => "sim_unstable",
            SimError::InvalidAction { .. } => "invalid_action",
            SimError::BundleMissing { .. }
            | SimError::BundleCorrupt { .. }
            | SimError::BundleDamaged { .. }
            | SimError::BundleVersion { .. }
            | SimError::UnknownTask { .. }
            | SimError::Compile { .. }
            | SimError::InitStateOutOfRange { .. }
            | SimError::UnknownSeed { .. }
            | SimError::UnknownSeededSeed { .. } => "bundle",
            SimError::NoGl { .. } | SimError::RenderSize { .. } | SimError::UnknownCamera { .. } => "render",
            _ => "internal",
        };
        EpisodeError { kind, message: e.to_string() }
    }
}

/// The outcome summary of one episode (the episode row without its key columns).
#[derive(Debug, Clone)]
pub struct EpisodeSummary {
    pub instruction: String,
    /// Which text `instruction` is: `filename` or `bddl`.
    pub instruction_source: &'static str,
    /// Hash of what the episode starts from ([`start_sha256`]); None when it could not start.
    pub start_sha256: Option<String>,
    pub n_policy_steps: u32,
    pub first_success_step: Option<u32>,
    pub final_goal: bool,
    /// Policy steps at which the goal changed (the compact re-scoring evidence).
    pub goal_changes: GoalChanges,
    pub goal_terms: Vec<String>,
    /// Object names the failure analysis watches ([`libero_sim::bundle::TaskInfo::objects_of_interest_resolved`]).
    pub objects_of_interest: Vec<String>,
    pub error: Option<EpisodeError>,
    pub wall_s: f64,
    pub sim_s: f64,
    pub policy_s: f64,
    pub render_s: f64,
    /// Unix time (s) the episode's reset began; None when it could not start.
    pub started_at: Option<f64>,
}

impl EpisodeSummary {
    pub fn success(&self) -> bool {
        self.first_success_step.is_some()
    }

    /// The summary of an episode that could not start (no env, no steps).
    pub fn failed_to_start((instruction, instruction_source): (String, &'static str), error: EpisodeError) -> Self {
        EpisodeSummary {
            instruction,
            instruction_source,
            start_sha256: None,
            n_policy_steps: 0,
            first_success_step: None,
            final_goal: false,
            goal_changes: GoalChanges::default(),
            goal_terms: vec![],
            objects_of_interest: vec![],
            error: Some(error),
            wall_s: 0.0,
            sim_s: 0.0,
            policy_s: 0.0,
            render_s: 0.0,
            started_at: None,
        }
    }
}

/// sha256 of everything an episode starts from: the scene file's hash (from the bundle's
/// provenance), the fixture poses of (seed, episode) under `protocol` and the init state row. Two episodes with the
/// same hash start in the same state, whichever suite they belong to (a perturbation that only
/// changes the instruction keeps it), so their outcomes can be compared pair by pair. The spec's
/// perturbation columns are not in it: a camera view or robot init pose changes what follows the
/// start, not the start (`perturbation_params` says what they were).
pub fn start_sha256(
    bundle: &libero_sim::bundle::TaskBundle,
    key: &EpisodeKey,
    protocol: libero_schema::EvalProtocol,
) -> Result<String, SimError> {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    h.update(bundle.provenance["sha256"]["scene_xml"].as_str().unwrap_or_default().as_bytes());
    for (body, pose) in bundle.start_fixture_poses(protocol, key.seed as u64, key.init_state_id as usize)? {
        h.update(body.as_bytes());
        for v in pose.pos.iter().chain(&pose.quat) {
            h.update(v.to_le_bytes());
        }
    }
    for v in bundle.init_state(key.init_state_id as usize)? {
        h.update(v.to_le_bytes());
    }
    Ok(format!("{:x}", h.finalize()))
}

/// What a policy query cost, as its step stores it: the render, the `act` call, the model's own
/// timing. Under a real-time clock it travels with the answer to the step that applies it.
#[derive(Debug, Clone, Copy, Default)]
pub struct QueryCost {
    pub render_ms: f32,
    pub policy_ms: f32,
    pub timing: Option<libero_policies::ActTiming>,
}

/// Run one episode on `env` (already built for the key's task) with `policy`, perturbed as the
/// spec row says (`EpisodePerturbation::default()` for none). `cameras` is the env's renderer for
/// policies that see, made on the first step that asks and kept by the caller for the task's
/// next episodes (`None` before the first).
pub fn run_episode(
    env: &mut LiberoEnv,
    cameras: &mut Option<PolicyCameras>,
    policy: &mut dyn Policy,
    key: &EpisodeKey,
    protocol: &EpisodeProtocol,
    perturbation: &EpisodePerturbation,
    policy_seed: u64,
) -> (StepsBatchBuilder, EpisodeSummary) {
    let t_start = Instant::now();
    let (instruction, instruction_source) = match &perturbation.instruction {
        Some(text) => (text.as_str(), "spec"),
        None => env.bundle().task.instruction(protocol.instruction_source),
    };
    let instruction = instruction.to_string();
    let object_names: Vec<String> = env.object_names().map(str::to_string).collect();
    let mut steps = StepsBatchBuilder::new(key.clone(), object_names);
    let mut summary = EpisodeSummary {
        instruction: instruction.clone(),
        instruction_source,
        start_sha256: start_sha256(env.bundle(), key, protocol.protocol.unwrap_or_default()).ok(),
        n_policy_steps: 0,
        first_success_step: None,
        final_goal: false,
        goal_changes: GoalChanges::default(),
        goal_terms: env.goal_terms().to_vec(),
        objects_of_interest: env.bundle().task.objects_of_interest_resolved(),
        error: None,
        wall_s: 0.0,
        sim_s: 0.0,
        policy_s: 0.0,
        render_s: 0.0,
        started_at: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).ok().map(|d| d.as_secs_f64()),
    };
    let edits = perturbation.env_edits(&env.bundle().task.problem).and_then(|edits| env.set_episode_edits(edits));
    if let Err(e) = edits {
        summary.error = Some(EpisodeError::from_sim(&e));
        return (steps, summary);
    }
    let mut goal =
        match env.reset_under(protocol.protocol.unwrap_or_default(), key.init_state_id as usize, key.seed as u64) {
            Ok(g) => g,
            Err(e) => {
                summary.error = Some(EpisodeError::from_sim(&e));
                return (steps, summary);
            }
        };
    policy.reset(&instruction, policy_seed);
    // Privileged state only for the policies that ask for it (scripted experts).
    let scene = match policy.wants_scene().then(|| SceneReader::new(env)).transpose() {
        Ok(s) => s,
        Err(e) => {
            summary.error = Some(EpisodeError::from_sim(&e));
            return (steps, summary);
        }
    };
    // LIBERO-PRO's dark noise: one frozen field per camera for the whole episode, made when the
    // image size is first known.
    let mut dark_fields: [Option<Vec<f64>>; 2] = [None, None];
    // The state after step t is what the policy sees before step t+1: read it once per step.
    let mut obs = env.observation();
    let mut contacts = env.gripper_contacts();
    let total = protocol.num_steps_wait + protocol.max_steps;
    let mut clock: Option<RealTimeClock<[f32; 7], QueryCost>> =
        protocol.realtime.map(|rt| RealTimeClock::new(rt, CONTROL_FREQ_HZ));
    // the last policy action the env ran (what a real-time hold repeats or keeps the gripper of)
    let mut last_action: Option<[f32; 7]> = None;
    for t in 0..total {
        let policy_step = t.checked_sub(protocol.num_steps_wait);
        let mut cost = QueryCost::default();
        let mut held = false;
        let action: [f32; 7] = match policy_step {
            None => WAIT_ACTION,
            Some(p) => match clock.as_mut().map_or(Tick::Query, RealTimeClock::tick) {
                Tick::Hold => {
                    held = true;
                    libero_hold(protocol.realtime.expect("a clock is real time").hold, last_action.as_ref())
                }
                Tick::Answer(a, answer_cost) => {
                    cost = answer_cost;
                    a
                }
                Tick::Query => {
                    let queries_model = policy.queries_model();
                    let answer = 'query: {
                        let t0 = Instant::now();
                        let images = match policy.camera_size() {
                            None => None,
                            Some(size) => match capture(cameras, env, size, policy.wants_wrist_camera()) {
                                Ok(mut images) => {
                                    if let Some(noise) = &perturbation.sensor_noise {
                                        let mut draws = SeededDraws::new(noise_seed(key, p));
                                        let a = &mut images.agentview;
                                        if let Err(e) =
                                            noise.apply(&mut a.rgb, a.width as usize, a.height as usize, &mut draws)
                                        {
                                            break 'query Err(EpisodeError { kind: "perturbation", message: e });
                                        }
                                    }
                                    if let Some(dark) = &perturbation.dark_noise {
                                        for (i, image) in
                                            [&mut images.agentview, &mut images.wrist].into_iter().enumerate()
                                        {
                                            if image.rgb.is_empty() {
                                                continue;
                                            }
                                            let field = dark_fields[i].get_or_insert_with(|| {
                                                dark.field(dark_noise_seed(key, i), image.rgb.len())
                                            });
                                            if let Err(e) = dark.apply(&mut image.rgb, field) {
                                                break 'query Err(EpisodeError { kind: "perturbation", message: e });
                                            }
                                        }
                                    }
                                    Some(images)
                                }
                                Err(e) => break 'query Err(EpisodeError::from_sim(&e)),
                            },
                        };
                        cost.render_ms = t0.elapsed().as_secs_f32() * 1e3;
                        summary.render_s += cost.render_ms as f64 / 1e3;
                        let input = Observation {
                            policy_step: p,
                            eef_pos: obs.eef_pos,
                            eef_quat: obs.eef_quat,
                            hand_quat: obs.hand_quat,
                            gripper_qpos: obs.gripper_qpos,
                            gripper_qvel: obs.gripper_qvel,
                            eef_mat: obs.eef_mat,
                            joint_pos: obs.joint_pos,
                            joint_vel: obs.joint_vel,
                            scene: scene.as_ref().map(|r| r.read(env, &goal, &contacts)),
                            images,
                        };
                        let t0 = Instant::now();
                        let a = policy.act(&input);
                        cost.policy_ms = t0.elapsed().as_secs_f32() * 1e3;
                        cost.timing = policy.last_timing();
                        summary.policy_s += cost.policy_ms as f64 / 1e3;
                        a.map_err(|e| EpisodeError { kind: "policy", message: e.to_string() })
                    };
                    let a = match answer {
                        Ok(a) => a,
                        Err(e) => {
                            summary.error = Some(e);
                            break;
                        }
                    };
                    match clock.as_mut() {
                        None => a,
                        Some(c) => {
                            let latency = c.latency_ms(queries_model, cost.policy_ms as f64);
                            match c.answered(a, cost, latency) {
                                Some((a, _)) => a,
                                // late: this step holds, and the query's cost goes with the answer's step
                                None => {
                                    held = true;
                                    cost = QueryCost::default();
                                    libero_hold(c.hold(), last_action.as_ref())
                                }
                            }
                        }
                    }
                }
            },
        };
        if policy_step.is_some() && !held {
            last_action = Some(action);
        }
        let t0 = Instant::now();
        let out = env.step(action.map(f64::from));
        let sim_ms = t0.elapsed().as_secs_f32() * 1e3;
        summary.sim_s += sim_ms as f64 / 1e3;
        let out = match out {
            Ok(o) => o,
            Err(e) => {
                summary.error = Some(EpisodeError::from_sim(&e));
                break;
            }
        };
        obs = env.observation();
        let poses: Vec<([f64; 3], [f64; 4])> = obs.object_poses.iter().map(|p| (p.pos, p.quat)).collect();
        contacts = env.gripper_contacts();
        steps.push(&StepRecord {
            step: t as i32,
            policy_step: policy_step.map(|p| p as i32),
            action,
            eef_pos: obs.eef_pos,
            eef_quat: obs.eef_quat,
            gripper_qpos: obs.gripper_qpos,
            joint_pos: obs.joint_pos,
            object_poses: &poses,
            goal: out.goal.satisfied,
            goal_terms: &out.goal.terms,
            gripper_contacts: &contacts,
            sim_ms,
            policy_ms: cost.policy_ms,
            render_ms: cost.render_ms,
            timing: cost.timing,
            held,
        });
        goal = out.goal;
        if let Some(p) = policy_step {
            summary.n_policy_steps = p + 1;
            summary.final_goal = goal.satisfied;
            summary.goal_changes.record(p, goal.satisfied);
            if goal.satisfied && summary.first_success_step.is_none() {
                summary.first_success_step = Some(p);
                if protocol.stop_on_success {
                    break;
                }
            }
        }
    }
    summary.wall_s = t_start.elapsed().as_secs_f64();
    (steps, summary)
}

/// Seed of the sensor-noise draws of policy step `policy_step`: a stable hash of the episode key
/// and the step, so a rerun corrupts every frame the same way and no two frames share a field.
pub fn noise_seed(key: &EpisodeKey, policy_step: u32) -> u64 {
    use sha2::{Digest, Sha256};
    let h = Sha256::digest(format!("{}/sensor_noise/{policy_step}", key.episode_key).as_bytes());
    u64::from_le_bytes(h[..8].try_into().expect("8 bytes"))
}

/// Seed of LIBERO-PRO's dark-noise field of camera `camera` (0 agentview, 1 wrist, the reference's
/// image-key order): fixed for the episode, as the reference's constant seed makes it.
pub fn dark_noise_seed(key: &EpisodeKey, camera: usize) -> u64 {
    use sha2::{Digest, Sha256};
    let h = Sha256::digest(format!("{}/dark_noise/{camera}", key.episode_key).as_bytes());
    u64::from_le_bytes(h[..8].try_into().expect("8 bytes"))
}

/// The camera images of the env's current state at `size` (the wrist camera only when `wrist`),
/// (re)making the renderer when the size changes.
fn capture(
    cameras: &mut Option<PolicyCameras>,
    env: &mut LiberoEnv,
    size: u32,
    wrist: bool,
) -> Result<libero_policies::CameraImages, SimError> {
    if cameras.as_ref().is_none_or(|c| c.size() != size) {
        *cameras = Some(PolicyCameras::new(env, size)?);
    }
    cameras.as_mut().expect("just made").capture(env, wrist)
}

/// Run identity stored in every episode row.
#[derive(Debug, Clone)]
pub struct EpisodeContext<'a> {
    pub policy: &'a str,
    /// The canonical JSON of the episode's perturbation ([`crate::perturbation::EpisodePerturbation::canonical`]).
    pub perturbation_params: Option<&'a str>,
    pub run_config: &'a str,
    pub protocol: &'a EpisodeProtocol,
}

/// The one-row episode batch ([`tables::episodes`]), with `extras` (a one-row slice of the spec's
/// extra columns) appended.
pub fn episode_batch(
    key: &EpisodeKey,
    s: &EpisodeSummary,
    ctx: &EpisodeContext,
    extras: Option<&RecordBatch>,
) -> anyhow::Result<RecordBatch> {
    let terms = StringArray::from(s.goal_terms.clone());
    let item = Arc::new(Field::new("item", DataType::Utf8, false));
    let goal_terms =
        ListArray::try_new(item.clone(), OffsetBuffer::from_lengths([s.goal_terms.len()]), Arc::new(terms), None)?;
    let changes = Int32Array::from(s.goal_changes.steps().iter().map(|&p| p as i32).collect::<Vec<_>>());
    let goal_changes = ListArray::try_new(
        Arc::new(Field::new("item", DataType::Int32, false)),
        OffsetBuffer::from_lengths([changes.len()]),
        Arc::new(changes),
        None,
    )?;
    let interest = StringArray::from(s.objects_of_interest.clone());
    let objects_of_interest =
        ListArray::try_new(item, OffsetBuffer::from_lengths([s.objects_of_interest.len()]), Arc::new(interest), None)?;
    // derived from the suite name, never typed by hand (null only for a suite this build does not
    // know, which validation refuses before a run starts)
    let suite: Option<Suite> = key.suite.parse().ok();
    let mut columns: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from(vec![key.episode_key.as_str()])),
        Arc::new(StringArray::from(vec![key.suite.as_str()])),
        Arc::new(Int32Array::from(vec![key.task_id])),
        Arc::new(Int32Array::from(vec![key.init_state_id])),
        Arc::new(Int64Array::from(vec![key.seed])),
        Arc::new(StringArray::from(vec![suite.map(|s| s.base.name())])),
        Arc::new(StringArray::from(vec![suite.map(|s| s.perturbation_name())])),
        Arc::new(StringArray::from(vec![key.variant.as_deref()])),
        Arc::new(StringArray::from(vec![ctx.perturbation_params])),
        Arc::new(StringArray::from(vec![s.instruction.as_str()])),
        Arc::new(StringArray::from(vec![s.instruction_source])),
        Arc::new(StringArray::from(vec![s.start_sha256.as_deref()])),
        Arc::new(StringArray::from(vec![ctx.policy])),
        Arc::new(StringArray::from(vec![ctx.run_config])),
        Arc::new(Int32Array::from(vec![ctx.protocol.max_steps as i32])),
        Arc::new(Int32Array::from(vec![ctx.protocol.num_steps_wait as i32])),
        Arc::new(BooleanArray::from(vec![ctx.protocol.stop_on_success])),
        Arc::new(Int32Array::from(vec![s.n_policy_steps as i32])),
        Arc::new(BooleanArray::from(vec![s.success()])),
        Arc::new(Int32Array::from(vec![s.first_success_step.map(|x| x as i32)])),
        Arc::new(BooleanArray::from(vec![s.final_goal])),
        Arc::new(goal_changes),
        Arc::new(goal_terms),
        Arc::new(objects_of_interest),
        Arc::new(StringArray::from(vec![s.error.as_ref().map(|e| e.kind)])),
        Arc::new(StringArray::from(vec![s.error.as_ref().map(|e| e.message.as_str())])),
        Arc::new(Float64Array::from(vec![s.wall_s])),
        Arc::new(Float64Array::from(vec![s.sim_s])),
        Arc::new(Float64Array::from(vec![s.policy_s])),
        Arc::new(Float64Array::from(vec![s.render_s])),
        Arc::new(Float64Array::from(vec![s.started_at])),
        // `env`
        Arc::new(StringArray::from(vec![Benchmark::of_suite(&key.suite).name()])),
        // `protocol`
        Arc::new(StringArray::from(vec![ctx.protocol.protocol.map(|p| p.name())])),
    ];
    let base = tables::episodes();
    let schema = match extras {
        None => base,
        Some(x) => {
            columns.extend(x.columns().iter().cloned());
            let fields: Vec<_> = base.fields().iter().chain(x.schema().fields().iter()).cloned().collect();
            Arc::new(arrow::datatypes::Schema::new(fields))
        }
    };
    Ok(RecordBatch::try_new(schema, columns)?)
}
