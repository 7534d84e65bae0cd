//! [`LiberoEnv`]: one LIBERO task on MuJoCo, stepped at 20 Hz exactly as the reference steps it.
//!
//! One env step (`robosuite/environments/base.py:361-404` + LIBERO's `step`):
//! for each of 25 substeps of 2 ms: refresh kinematics, on the first substep set the OSC goal from
//! the action, compute arm torques (clipped to the actuator ranges) and gripper controls, then
//! `mj_step`. After the last substep the BDDL goal is evaluated on the data `mj_step` left (body
//! positions and contacts of its forward pass, joint positions after integration).
//!
//! The reference refreshes kinematics with `mj_forward` before each `mj_step`, which then computes
//! the same forward pass again. [`StepMode::Split`] (the default) uses MuJoCo's
//! `mj_step1`/`mj_step2` split instead: controls are computed between the position/velocity
//! stages and the acceleration/integration stages, skipping the duplicate; the parity test
//! checks both modes against the reference.

mod episode_edits;
mod object_moves;
mod occlusion;
mod probe;

pub use episode_edits::{Appearance, EpisodeEdits, Lighting};
pub use object_moves::{AppliedMove, InitialPose, ObjectShift, RuntimeMove, candidate_deltas};
pub use occlusion::{AppliedOcclusion, Occlusion, OcclusionPartner, candidate_reference_offsets};
pub use probe::{Box3, JointFrame, ObjectGeometry, SceneProbe, SiteFrame};

use crate::SimError;
use crate::bundle::{Pose, TaskBundle};
use crate::gl::GlContext;
use crate::gripper::Gripper;
use crate::osc::{ARM_DOF, ArmState, OscController};
use crate::predicates::{Goal, GoalStatus};
use crate::render::{Frame, Rect, RenderOptions, SceneRenderer, UploadKey};
use crate::scene::{self, object_id};
use mujoco_rs::mujoco_c;
use mujoco_rs::prelude::*;
use nalgebra::{Matrix3, SVector, Vector3};
use std::ops::Deref;

/// How each physics substep computes the controls.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StepMode {
    /// `mj_step1`, controls, `mj_step2`: one forward pass per substep.
    #[default]
    Split,
    /// `mj_forward`, controls, `mj_step`: the reference's call sequence (two forward passes).
    ForwardThenStep,
}

/// A pointer to the env's boxed model, so `MjData` can borrow it while the env can still edit
/// fixture poses between episodes. The box outlives the data (field order in [`LiberoEnv`];
/// [`crate::aloha::AlohaEnv`] holds its model the same way, to hand it to a renderer).
pub(crate) struct ModelPtr(pub(crate) *const MjModel);
impl Deref for ModelPtr {
    type Target = MjModel;
    fn deref(&self) -> &MjModel {
        unsafe { &*self.0 }
    }
}
unsafe impl Send for ModelPtr {}

/// What one env step returns.
#[derive(Debug, Clone)]
pub struct StepOutcome {
    /// Env steps taken since reset, this one included.
    pub step: u32,
    pub goal: GoalStatus,
}

/// Robot and object state after a step, as observations and per-step records need it.
#[derive(Debug, Clone)]
pub struct Observation {
    /// End-effector (grip site) position, world frame.
    pub eef_pos: [f64; 3],
    /// End-effector orientation as a quaternion (w, x, y, z) of the grip site frame.
    pub eef_quat: [f64; 4],
    /// The two finger joint positions.
    pub gripper_qpos: [f64; 2],
    /// The two finger joint velocities (robosuite's `robot0_gripper_qvel`).
    pub gripper_qvel: [f64; 2],
    /// The grip site's rotation matrix, row-major, as MuJoCo computes it (`site_xmat`): what
    /// robosuite's controller caches as `ee_ori_mat` and lerobot's LIBERO env passes on.
    pub eef_mat: [f64; 9],
    pub joint_pos: [f64; ARM_DOF],
    pub joint_vel: [f64; ARM_DOF],
    /// Root-body pose of every object and fixture, in `object_names()` order.
    pub object_poses: Vec<Pose>,
    /// Orientation (w, x, y, z) of the hand body `robot0_right_hand`: robosuite's
    /// `obs["robot0_eef_quat"]` (MuJoCo's `xquat`, sign included), from which the published loops
    /// build the proprio state's axis-angle. Not `eef_quat`, the grip site's frame, which is
    /// turned ~90° about z from it.
    pub hand_quat: [f64; 4],
}

/// robosuite's Panda hand body (`robot_model.eef_name` = `right_hand`, prefixed `robot0_`).
const HAND_BODY: &str = "robot0_right_hand";

pub struct LiberoEnv {
    // Field order matters: `data` borrows `model` through a raw pointer and must drop first.
    data: MjData<ModelPtr>,
    model: Box<MjModel>,
    bundle: TaskBundle,
    goal: Goal,
    mode: StepMode,
    osc: OscController,
    gripper: Gripper,
    reset_snapshot: ArmState,
    /// What the next resets change besides the init state (perturbations), and the nominal
    /// values they replace.
    edits: EpisodeEdits,
    nominal: episode_edits::Nominal,
    /// What the episode's placement perturbations did so far.
    moves: object_moves::MovesDone,
    /// The occluder's free-joint qpos address and the pose it is pinned at after every step
    /// (LIBERO-PRO's `view_occlusion`), for the current episode.
    pinned: Option<(usize, [f64; 7])>,
    /// `Some` between reset and the first substep: robosuite's stale controller cache.
    stale: Option<ArmState>,
    eef_site: usize,
    /// The hand body (`robot0_right_hand`), whose quaternion is robosuite's `robot0_eef_quat`.
    hand_body: usize,
    qpos_index: [usize; ARM_DOF],
    qvel_index: [usize; ARM_DOF],
    arm_actuators: [usize; ARM_DOF],
    arm_ctrlrange: [[f64; 2]; ARM_DOF],
    gripper_actuators: [usize; 2],
    gripper_ctrlrange: [[f64; 2]; 2],
    gripper_qpos: [usize; 2],
    gripper_qvel: [usize; 2],
    object_bodies: Vec<(String, usize)>,
    substeps: u32,
    horizon: u32,
    steps: u32,
    episode_ready: bool,
    jacp: Vec<f64>,
    jacr: Vec<f64>,
    full_m: Vec<f64>,
    /// When `Some`, the controls of every substep are appended (for benchmarks that replay the
    /// exact same physics without the controller).
    control_log: Option<Vec<f64>>,
    /// Per geom: index into `object_bodies` of the object whose contact geom it is.
    geom_object: Vec<Option<u16>>,
    /// Per geom: it belongs to a gripper body (`gripper0_*`, robosuite's naming).
    geom_is_gripper: Vec<bool>,
    /// Stove burners LIBERO shows or hides after every step (rendering only).
    indicators: Vec<Indicator>,
    /// The compiled texture colour spaces, restored before a [`Look`](crate::render::Look) is applied.
    tex_colorspace: Vec<i32>,
}

/// A site LIBERO's `set_visualization()` toggles after every step: a stove's burner shows while
/// the stove is on (`_post_process` in the problem classes). It changes pictures, not physics.
#[derive(Debug, Clone)]
struct Indicator {
    site: usize,
    /// qpos addresses of the object's joints; "on" if any is at or above `on_at`.
    qpos: Vec<usize>,
    on_at: f64,
    /// The site's alpha in a freshly built model (a hard reset restores it).
    alpha_after_reset: f32,
}

impl LiberoEnv {
    /// Compile the bundle's scene (fixtures at their XML poses until [`reset`](Self::reset)).
    pub fn new(bundle: &TaskBundle) -> Result<Self, SimError> {
        Self::with_model(bundle, scene::compile(bundle)?)
    }

    /// An env on an already compiled model of this bundle (e.g. a copy of a cached one:
    /// compiling decodes every texture and costs ~1 s, copying a few ms).
    pub fn with_model(bundle: &TaskBundle, model: MjModel) -> Result<Self, SimError> {
        let model = Box::new(model);
        let data = MjData::new(ModelPtr(&*model as *const MjModel));
        let task = &bundle.task;
        let c = &task.controller;
        let arr7 = |v: &Vec<usize>, what: &str| -> Result<[usize; ARM_DOF], SimError> {
            v.as_slice().try_into().map_err(|_| SimError::BundleCorrupt {
                path: bundle.dir.join("task.json"),
                detail: format!("controller.{what} has {} entries, the Panda arm has {ARM_DOF}", v.len()),
            })
        };
        let qpos_index = arr7(&c.qpos_index, "qpos_index")?;
        let qvel_index = arr7(&c.qvel_index, "qvel_index")?;
        let arm_actuators = arr7(&c.arm_actuators, "arm_actuators")?;
        let gripper_actuators: [usize; 2] =
            c.gripper_actuators.as_slice().try_into().map_err(|_| SimError::BundleCorrupt {
                path: bundle.dir.join("task.json"),
                detail: "two gripper actuators expected".into(),
            })?;
        let ctrlrange = model.actuator_ctrlrange();
        let arm_ctrlrange = arm_actuators.map(|a| ctrlrange[a]);
        let gripper_ctrlrange = gripper_actuators.map(|a| ctrlrange[a]);
        let eef_site = object_id(&model, MjtObj::mjOBJ_SITE, &c.eef_site, "site")?;
        let hand_body = object_id(&model, MjtObj::mjOBJ_BODY, HAND_BODY, "body")?;
        // The finger joints are the gripper actuators' transmission targets.
        let trnid = model.actuator_trnid();
        let jnt_qposadr = model.jnt_qposadr();
        let gripper_qpos = gripper_actuators.map(|a| jnt_qposadr[trnid[a][0] as usize] as usize);
        let jnt_dofadr = model.jnt_dofadr();
        let gripper_qvel = gripper_actuators.map(|a| jnt_dofadr[trnid[a][0] as usize] as usize);
        let object_bodies = task
            .objects
            .iter()
            .map(|(name, o)| Ok((name.clone(), scene::body_id(&model, &o.root_body)?)))
            .collect::<Result<Vec<_>, SimError>>()?;
        let goal = Goal::compile(task, &model)?;
        let nv = model.ffi().nv as usize;
        let ngeom = model.ffi().ngeom as usize;
        let mut geom_object = vec![None; ngeom];
        for (i, (name, _)) in object_bodies.iter().enumerate() {
            for g in &task.objects[name].contact_geoms {
                geom_object[object_id(&model, MjtObj::mjOBJ_GEOM, g, "geom")?] = Some(i as u16);
            }
        }
        let geom_bodyid = model.geom_bodyid();
        let geom_is_gripper = (0..ngeom)
            .map(|g| model.id_to_name(MjtObj::mjOBJ_BODY, geom_bodyid[g]).is_some_and(|b| b.starts_with("gripper0_")))
            .collect();
        let indicators = burner_indicators(task, &model)?;
        let tex_colorspace =
            (0..model.ffi().ntex as usize).map(|i| unsafe { *model.ffi().tex_colorspace.add(i) }).collect();
        let reset_snapshot = ArmState::from_snapshot(c);
        let nominal = episode_edits::Nominal::of(&model);
        Ok(LiberoEnv {
            data,
            goal,
            mode: StepMode::default(),
            osc: OscController::new(c),
            gripper: Gripper::new(c.gripper_speed, &c.gripper_current_action_after_reset),
            reset_snapshot,
            edits: EpisodeEdits::default(),
            nominal,
            moves: Default::default(),
            pinned: None,
            stale: None,
            eef_site,
            hand_body,
            qpos_index,
            qvel_index,
            arm_actuators,
            arm_ctrlrange,
            gripper_actuators,
            gripper_ctrlrange,
            gripper_qpos,
            gripper_qvel,
            object_bodies,
            substeps: task.control.substeps,
            horizon: task.control.horizon,
            steps: 0,
            episode_ready: false,
            jacp: vec![0.0; 3 * nv],
            jacr: vec![0.0; 3 * nv],
            full_m: vec![0.0; nv * nv],
            control_log: None,
            geom_object,
            geom_is_gripper,
            indicators,
            tex_colorspace,
            bundle: bundle.clone(),
            model,
        })
    }

    pub fn set_step_mode(&mut self, mode: StepMode) {
        self.mode = mode;
    }

    /// Start (or stop, and return) logging the control vector of every physics substep.
    pub fn log_controls(&mut self, on: bool) -> Option<Vec<f64>> {
        std::mem::replace(&mut self.control_log, on.then(Vec::new))
    }

    pub fn bundle(&self) -> &TaskBundle {
        &self.bundle
    }

    pub fn model(&self) -> &MjModel {
        &self.model
    }

    /// The goal terms' BDDL text, in the order of [`GoalStatus::terms`].
    pub fn goal_terms(&self) -> &[String] {
        &self.goal.term_names
    }

    /// The fixture root bodies' poses in the live model (`body_pos`, `body_quat`): what the last
    /// reset put there, for parity checks against the reference loop's scene.
    pub fn fixture_poses(&self) -> Result<std::collections::BTreeMap<String, Pose>, SimError> {
        let mut out = std::collections::BTreeMap::new();
        for body in &self.bundle.task.fixture_bodies {
            let id = scene::body_id(&self.model, body)?;
            out.insert(body.clone(), Pose { pos: self.model.body_pos()[id], quat: self.model.body_quat()[id] });
        }
        Ok(out)
    }

    /// Object and fixture names, in the order of [`Observation::object_poses`].
    pub fn object_names(&self) -> impl Iterator<Item = &str> {
        self.object_bodies.iter().map(|(n, _)| n.as_str())
    }

    /// Start an episode as the reference loop does: `env.seed(seed)` once per task, one
    /// `reset()` per episode, then `set_init_state(init_states[init_state_id])`. The fixture
    /// poses are those of episode `init_state_id` after `env.seed(seed)` (the canonical protocol
    /// runs trial i on init state i).
    pub fn reset(&mut self, init_state_id: usize, seed: u64) -> Result<GoalStatus, SimError> {
        self.reset_under(libero_schema::EvalProtocol::Canonical, init_state_id, seed)
    }

    /// Start an episode as `protocol`'s loop does: [`reset`](Self::reset) for the canonical one;
    /// for lerobot's, `env.seed(seed)` right before one `reset()`, then
    /// `set_init_state(init_states[init_state_id])` (the fixture poses after the seed and one reset).
    pub fn reset_under(
        &mut self,
        protocol: libero_schema::EvalProtocol,
        init_state_id: usize,
        seed: u64,
    ) -> Result<GoalStatus, SimError> {
        let state = self.bundle.init_state(init_state_id)?.to_vec();
        let poses = self.bundle.start_fixture_poses(protocol, seed, init_state_id)?.clone();
        self.reset_to(&poses, &state)
    }

    /// Reset with explicit fixture poses and a `[time, qpos, qvel]` state.
    pub fn reset_to(
        &mut self,
        fixture_poses: &std::collections::BTreeMap<String, Pose>,
        state: &[f64],
    ) -> Result<GoalStatus, SimError> {
        let (nq, nv) = (self.model.ffi().nq as usize, self.model.ffi().nv as usize);
        if state.len() != 1 + nq + nv {
            return Err(SimError::Other(format!(
                "state has {} values, this scene needs 1+nq+nv = {}",
                state.len(),
                1 + nq + nv
            )));
        }
        scene::apply_fixture_poses(&mut self.model, fixture_poses)?;
        self.apply_camera_edits()?;
        let snapshot = self.reset_time_arm_state();
        for ind in &self.indicators {
            self.model.site_rgba_mut()[ind.site][3] = ind.alpha_after_reset;
        }
        // A hard reset builds fresh MjData: zero warm-start, controls and applied forces.
        unsafe { mujoco_c::mj_resetData(self.model.ffi(), self.data_ptr()) };
        self.data.set_time(state[0]);
        self.data.qpos_mut().copy_from_slice(&state[1..1 + nq]);
        self.data.qvel_mut().copy_from_slice(&state[1 + nq..]);
        self.data.forward();
        // LIBERO-PRO's order after `set_init_state`: object edits, then lighting (the camera is set).
        self.pinned = None;
        self.apply_initial_pose()?;
        self.apply_occlusion()?;
        self.apply_look_edits()?;
        // LIBERO's `set_init_state` runs `_post_process()` once (env_wrapper.py:139-145).
        self.update_indicators();
        self.osc.reset();
        self.gripper.reset();
        self.stale = Some(snapshot);
        self.steps = 0;
        self.episode_ready = true;
        Ok(self.goal.evaluate(&self.data))
    }

    /// One 20 Hz control step: delta eef position (3), delta orientation as axis-angle (3),
    /// gripper (-1 open … +1 close); components are clipped to [-1, 1] and scaled to ±5 cm and
    /// ±0.5 rad. Non-finite actions and unstable physics are errors, never panics.
    pub fn step(&mut self, action: [f64; 7]) -> Result<StepOutcome, SimError> {
        if !self.episode_ready {
            return Err(SimError::Other("step() before reset(): call reset(init_state_id, seed) first".into()));
        }
        if let Some(i) = action.iter().position(|x| !x.is_finite()) {
            return Err(SimError::InvalidAction {
                action: action.to_vec(),
                reason: format!("component {i} is not finite"),
            });
        }
        if self.steps >= self.horizon {
            return Err(SimError::Other(format!(
                "executing action in terminated episode (the reference horizon is {} steps)",
                self.horizon
            )));
        }
        self.maybe_runtime_move()?;
        let arm_action: [f64; 6] = std::array::from_fn(|i| action[i]);
        for k in 0..self.substeps {
            match self.mode {
                StepMode::Split => unsafe { mujoco_c::mj_step1(self.model.ffi(), self.data_ptr()) },
                StepMode::ForwardThenStep => self.data.forward(),
            }
            let s = match self.stale.take() {
                Some(stale) => stale,
                None => self.arm_state(),
            };
            if k == 0 {
                self.osc.set_goal(&arm_action, &s);
            }
            let bias = SVector::<f64, ARM_DOF>::from_fn(|i, _| self.data.qfrc_bias()[self.qvel_index[i]]);
            let tau = self.osc.torques(&s, &bias);
            self.gripper.substep(action[6]);
            let grip = self.gripper.controls(self.gripper_ctrlrange);
            let ctrl = self.data.ctrl_mut();
            for i in 0..ARM_DOF {
                let [lo, hi] = self.arm_ctrlrange[i];
                ctrl[self.arm_actuators[i]] = tau[i].clamp(lo, hi);
            }
            for i in 0..2 {
                ctrl[self.gripper_actuators[i]] = grip[i];
            }
            if let Some(log) = &mut self.control_log {
                log.extend_from_slice(self.data.ctrl());
            }
            match self.mode {
                StepMode::Split => unsafe { mujoco_c::mj_step2(self.model.ffi(), self.data_ptr()) },
                StepMode::ForwardThenStep => self.data.step(),
            }
        }
        self.steps += 1;
        self.check_stable()?;
        self.update_indicators();
        // The reference's `done` is computed inside `env.step`, before its harness pins the occluder.
        let goal = self.goal.evaluate(&self.data);
        self.pin_occluder();
        Ok(StepOutcome { step: self.steps, goal })
    }

    /// [`step`](Self::step) for an action of runtime length (e.g. from a policy): anything but
    /// 7 components is an [`SimError::InvalidAction`].
    pub fn step_slice(&mut self, action: &[f64]) -> Result<StepOutcome, SimError> {
        let a: [f64; 7] = action.try_into().map_err(|_| SimError::InvalidAction {
            action: action.to_vec(),
            reason: format!("expected 7 components (dpos 3, drot 3, gripper 1), got {}", action.len()),
        })?;
        self.step(a)
    }

    /// Indices (into [`object_names`](Self::object_names)) of the objects whose contact geoms touch
    /// a gripper geom now, sorted and unique: the evidence of a grasp for failure analysis.
    pub fn gripper_contacts(&self) -> Vec<usize> {
        let mut out: Vec<usize> = self
            .data
            .contacts()
            .iter()
            .filter_map(|c| {
                let (g1, g2) = (c.geom[0] as usize, c.geom[1] as usize);
                match (self.geom_is_gripper[g1], self.geom_is_gripper[g2]) {
                    (true, false) => self.geom_object[g2],
                    (false, true) => self.geom_object[g1],
                    _ => None,
                }
            })
            .map(usize::from)
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    /// Evaluate the goal on the current data (as `check_success()` would).
    pub fn goal_status(&self) -> GoalStatus {
        self.goal.evaluate(&self.data)
    }

    /// The full state `[time, qpos, qvel]`, the layout of the init states.
    pub fn state(&self) -> Vec<f64> {
        let mut s = Vec::with_capacity(1 + self.data.qpos().len() + self.data.qvel().len());
        s.push(self.data.time());
        s.extend_from_slice(self.data.qpos());
        s.extend_from_slice(self.data.qvel());
        s
    }

    pub fn observation(&self) -> Observation {
        let d = &self.data;
        let m = d.site_xmat()[self.eef_site];
        let rot = Matrix3::from_row_slice(&m);
        let q = nalgebra::UnitQuaternion::from_matrix(&rot);
        let q = [q.w, q.i, q.j, q.k];
        let (qpos, qvel) = (d.qpos(), d.qvel());
        Observation {
            eef_pos: d.site_xpos()[self.eef_site],
            eef_quat: q,
            gripper_qpos: self.gripper_qpos.map(|i| qpos[i]),
            gripper_qvel: self.gripper_qvel.map(|i| qvel[i]),
            eef_mat: m,
            joint_pos: self.qpos_index.map(|i| qpos[i]),
            joint_vel: self.qvel_index.map(|i| qvel[i]),
            object_poses: self
                .object_bodies
                .iter()
                .map(|&(_, b)| Pose { pos: d.xpos()[b], quat: d.xquat()[b] })
                .collect(),
            hand_quat: d.xquat()[self.hand_body],
        }
    }

    /// The arm state robosuite's `Controller.update()` caches.
    fn arm_state(&mut self) -> ArmState {
        let (m, d) = (self.model.ffi(), self.data.ffi());
        let nv = m.nv as usize;
        unsafe {
            mujoco_c::mj_jacSite(m, d, self.jacp.as_mut_ptr(), self.jacr.as_mut_ptr(), self.eef_site as i32);
            mujoco_c::mj_fullM(m, self.full_m.as_mut_ptr(), d.qM);
        }
        let qvel = self.data.qvel();
        let full_vel = |jac: &[f64]| Vector3::from_fn(|r, _| (0..nv).map(|c| jac[r * nv + c] * qvel[c]).sum::<f64>());
        let (vi, qi) = (self.qvel_index, self.qpos_index);
        let x = self.data.site_xmat()[self.eef_site];
        ArmState {
            ee_pos: Vector3::from(self.data.site_xpos()[self.eef_site]),
            ee_ori: Matrix3::from_row_slice(&x),
            ee_pos_vel: full_vel(&self.jacp),
            ee_ori_vel: full_vel(&self.jacr),
            j_pos: nalgebra::SMatrix::from_fn(|r, c| self.jacp[r * nv + vi[c]]),
            j_ori: nalgebra::SMatrix::from_fn(|r, c| self.jacr[r * nv + vi[c]]),
            mass: nalgebra::SMatrix::from_fn(|r, c| self.full_m[vi[r] * nv + vi[c]]),
            q: SVector::from_fn(|i, _| self.data.qpos()[qi[i]]),
            dq: SVector::from_fn(|i, _| qvel[vi[i]]),
        }
    }

    fn check_stable(&self) -> Result<(), SimError> {
        let d = self.data.ffi();
        let bad = [
            (MjtWarning::mjWARN_BADQACC, "bad qacc (NaN/inf accelerations)"),
            (MjtWarning::mjWARN_BADQVEL, "bad qvel"),
            (MjtWarning::mjWARN_BADQPOS, "bad qpos"),
        ];
        for (w, what) in bad {
            if d.warning[w as usize].number > 0 {
                return Err(SimError::Unstable { step: self.steps, detail: format!("MuJoCo warning: {what}") });
            }
        }
        if self.data.qpos().iter().chain(self.data.qvel()).any(|x| !x.is_finite()) {
            return Err(SimError::Unstable { step: self.steps, detail: "non-finite state".into() });
        }
        Ok(())
    }

    /// LIBERO's `set_visualization()`: toggle a burner's alpha when its shown/hidden state is wrong
    /// (`alpha = 1 - alpha`, exactly as the reference does it).
    fn update_indicators(&mut self) {
        let qpos = self.data.qpos();
        for ind in &self.indicators {
            let on = ind.qpos.iter().any(|&a| qpos[a] >= ind.on_at);
            let rgba = &mut self.model.site_rgba_mut()[ind.site];
            if (rgba[3] <= 0.0 && on) || (rgba[3] > 0.0 && !on) {
                rgba[3] = 1.0 - rgba[3];
            }
        }
    }

    /// A render context for this env's model (see [`SceneRenderer::new`]; applies the look).
    pub fn renderer(&mut self, gl: std::rc::Rc<GlContext>, options: RenderOptions) -> Result<SceneRenderer, SimError> {
        let key = self.upload_key(options);
        SceneRenderer::with_key(gl, &mut self.model, options, key)
    }

    /// [`crate::render::upload_key`] of this env's model for `options`: computed on the caller's
    /// thread before it hands [`LiberoEnv::renderer_with_key`] to a shared GL thread.
    pub fn upload_key(&mut self, options: RenderOptions) -> UploadKey {
        self.restore_colour_spaces();
        crate::render::upload_key(&mut self.model, options)
    }

    /// The compiled texture colour spaces back in the model (a look may have changed them).
    fn restore_colour_spaces(&mut self) {
        let m = unsafe { self.model.ffi_mut() };
        for (i, &cs) in self.tex_colorspace.iter().enumerate() {
            unsafe { *m.tex_colorspace.add(i) = cs };
        }
    }

    /// [`LiberoEnv::renderer`] with `key` from [`LiberoEnv::upload_key`] of the same options.
    pub fn renderer_with_key(
        &mut self,
        gl: std::rc::Rc<GlContext>,
        options: RenderOptions,
        key: UploadKey,
    ) -> Result<SceneRenderer, SimError> {
        self.restore_colour_spaces();
        SceneRenderer::with_key(gl, &mut self.model, options, key)
    }

    /// Draw a camera's view of the current state into a region of the renderer's buffer.
    pub fn draw_camera(&mut self, renderer: &mut SceneRenderer, camera: usize, rect: Rect) -> Result<(), SimError> {
        let data = self.data_ptr();
        // SAFETY: the renderer was made from this env's model (`renderer()`), data is live.
        unsafe { renderer.draw_camera(self.model.ffi(), data, camera, rect) }
    }

    /// One camera's frame of the current state, `width`×`height`, in the reference orientation.
    pub fn render(
        &mut self,
        renderer: &mut SceneRenderer,
        camera: &str,
        width: u32,
        height: u32,
    ) -> Result<Frame, SimError> {
        let id = renderer.camera_id(camera)?;
        let rect = Rect::new(0, 0, width, height);
        self.draw_camera(renderer, id, rect)?;
        renderer.read(rect)
    }

    fn data_ptr(&mut self) -> *mut mujoco_c::mjData {
        unsafe { self.data.ffi_mut() }
    }
}

/// The burners of the task's stoves (objects with a TurnOn rule and a `<name>_burner` site).
fn burner_indicators(task: &crate::bundle::TaskInfo, model: &MjModel) -> Result<Vec<Indicator>, SimError> {
    let jnt_qposadr = model.jnt_qposadr();
    let mut out = Vec::new();
    for (name, object) in &task.objects {
        let Some(rule) = object.articulation.get("turnon") else { continue };
        let site = model.name_to_id(MjtObj::mjOBJ_SITE, &format!("{name}_burner"));
        if site < 0 {
            continue;
        }
        let qpos = object
            .joints
            .iter()
            .map(|j| Ok(jnt_qposadr[object_id(model, MjtObj::mjOBJ_JOINT, j, "joint")?] as usize))
            .collect::<Result<Vec<_>, SimError>>()?;
        let site = site as usize;
        out.push(Indicator { site, qpos, on_at: rule.value, alpha_after_reset: model.site_rgba()[site][3] });
    }
    Ok(out)
}
