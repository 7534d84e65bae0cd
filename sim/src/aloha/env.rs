//! [`AlohaEnv`]: one ALOHA-sim task on MuJoCo, stepped at 50 Hz exactly as gym-aloha steps it.
//!
//! gym-aloha 0.1.5 runs dm_control's `control.Environment` with `control_timestep = 0.02` on the
//! scene's default 2 ms timestep: 10 substeps per env step. dm_control's `Physics.step` (its
//! `legacy_step`) is `mj_step2; mj_step × 9; mj_step1`: the first substep finishes the one that
//! the previous `mj_step1` (or the reset's `mj_forward`) began, and the trailing `mj_step1` brings
//! positions, velocities and contacts up to date with the new state, where `get_reward` reads
//! them. [`AlohaEnv::step`] makes the same calls. A plain `mj_step × 10` reaches the same state on
//! 3.3.7 but leaves the contacts of the last substep's start: the reward then differs on 2–3% of
//! steps (aloha-sim.md §2).
//!
//! Reset: dm_control's `reset_context` (`mj_resetData`, actuation-disabled `mj_forward`s around
//! `initialize_episode`, which writes the start pose to `qpos[..16]` and `ctrl` and the objects'
//! pose to `qpos[16..]`) leaves the same state as `mj_resetData`, those writes and one
//! `mj_forward`, which is what [`AlohaEnv::reset`] does; the parity test checks it bitwise,
//! and every step after it.
//!
//! Observation: [`AlohaEnv::agent_pos`] (`obs["agent_pos"]`) and the `top` camera at 480 × 640
//! ([`AlohaEnv::render_top`]), rendered with the scene's own visual settings (4096² shadow map,
//! 4× multisampling, headlight, fog) and dm_control's scene options, upright as the env returns it.

use super::bundle::AlohaBundle;
use super::control::{ACTION_DIM, ARM_QPOS, START_ARM_POSE, action_to_ctrl, agent_pos};
use super::reward::ContactReward;
use super::task::AlohaTask;
use crate::SimError;
use crate::env::ModelPtr;
use crate::gl::GlContext;
use crate::render::{Frame, Look, Quality, Rect, RenderOptions, SceneRenderer};
use mujoco_rs::prelude::*;
use std::rc::Rc;

/// Physics substeps per env step: `control_timestep` 0.02 s over the default 0.002 s timestep.
pub const SUBSTEPS: u32 = 10;
/// The camera gym-aloha gives policies (`obs["pixels"]["top"]`), and its size.
pub const TOP_CAMERA: &str = "top";
pub const TOP_WIDTH: u32 = 640;
pub const TOP_HEIGHT: u32 = 480;

pub struct AlohaEnv {
    // Field order matters: `data` borrows `model` through a raw pointer and must drop first.
    data: MjData<ModelPtr>,
    model: Box<MjModel>,
    task: AlohaTask,
    reward: ContactReward,
    steps: u32,
    ready: bool,
}

impl AlohaEnv {
    /// Compile the task's scene from the bundle (the wheel's files, as they are).
    pub fn new(bundle: &AlohaBundle, task: AlohaTask) -> Result<Self, SimError> {
        let path = bundle.scene_path(task);
        let model =
            MjModel::from_xml(&path).map_err(|e| SimError::Compile { path: path.clone(), detail: e.to_string() })?;
        let (nq, nu) = (model.ffi().nq as usize, model.ffi().nu as usize);
        if nq != ARM_QPOS + 7 * task.objects() || nu != ARM_QPOS {
            return Err(SimError::BundleCorrupt {
                path,
                detail: format!(
                    "{task} needs nq = {} and nu = {ARM_QPOS}, the scene has nq = {nq}, nu = {nu}",
                    ARM_QPOS + 7 * task.objects()
                ),
            });
        }
        let reward = ContactReward::new(task, &model)?;
        let model = Box::new(model);
        let data = MjData::new(ModelPtr(&*model as *const MjModel));
        Ok(AlohaEnv { data, model, task, reward, steps: 0, ready: false })
    }

    pub fn task(&self) -> AlohaTask {
        self.task
    }

    pub fn model(&self) -> &MjModel {
        &self.model
    }

    /// Start the episode gym-aloha starts for `reset(seed=seed)`: the objects where
    /// `RandomState(seed)` puts them ([`AlohaTask::initial_pose`]).
    pub fn reset(&mut self, seed: u32) -> Result<(), SimError> {
        let pose = self.task.initial_pose(seed);
        self.reset_to_pose(&pose)
    }

    /// Start an episode with the objects at `pose` (`qpos[16..]`: position and (w, x, y, z) of each).
    pub fn reset_to_pose(&mut self, pose: &[f64]) -> Result<(), SimError> {
        let want = 7 * self.task.objects();
        if pose.len() != want {
            return Err(SimError::Other(format!(
                "{} needs an object pose of {want} values (position and quaternion of each object), got {}",
                self.task,
                pose.len()
            )));
        }
        self.data.reset();
        let qpos = self.data.qpos_mut();
        qpos[..ARM_QPOS].copy_from_slice(&START_ARM_POSE);
        qpos[ARM_QPOS..].copy_from_slice(pose);
        self.data.ctrl_mut().copy_from_slice(&START_ARM_POSE);
        self.data.forward();
        self.steps = 0;
        self.ready = true;
        Ok(())
    }

    /// One 50 Hz step: the action (per arm 6 joint targets and a normalized gripper) becomes the
    /// controls, then 10 substeps; returns the reward (0–4) of the new state's contacts.
    /// Non-finite actions and any MuJoCo warning during the step are errors (dm_control raises
    /// `PhysicsError`).
    pub fn step(&mut self, action: &[f32; ACTION_DIM]) -> Result<u8, SimError> {
        if !self.ready {
            return Err(SimError::Other("step() before reset(): call reset(seed) first".into()));
        }
        if let Some(i) = action.iter().position(|x| !x.is_finite()) {
            return Err(SimError::InvalidAction {
                action: action.iter().map(|&x| x as f64).collect(),
                reason: format!("component {i} is not finite"),
            });
        }
        self.data.ctrl_mut().copy_from_slice(&action_to_ctrl(action));
        let before = self.warnings();
        self.data.step2();
        for _ in 1..SUBSTEPS {
            self.data.step();
        }
        self.data.step1();
        self.steps += 1;
        let after = self.warnings();
        if let Some(w) = (0..after.len()).find(|&w| after[w] > before[w]) {
            self.ready = false;
            return Err(SimError::Unstable {
                step: self.steps,
                detail: format!("MuJoCo warning {w} (mjtWarning) during the step: dm_control raises PhysicsError"),
            });
        }
        Ok(self.reward())
    }

    /// [`step`](Self::step) for an action of runtime length (e.g. from a policy).
    pub fn step_slice(&mut self, action: &[f32]) -> Result<u8, SimError> {
        let a: &[f32; ACTION_DIM] = action.try_into().map_err(|_| SimError::InvalidAction {
            action: action.iter().map(|&x| x as f64).collect(),
            reason: format!(
                "expected {ACTION_DIM} components (per arm 6 joint targets and a gripper), got {}",
                action.len()
            ),
        })?;
        self.step(a)
    }

    /// The reward of the current state's contacts.
    pub fn reward(&self) -> u8 {
        self.reward.evaluate(self.data.contacts())
    }

    /// Env steps since reset.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// `obs["agent_pos"]`: per arm 6 joint positions and the normalized gripper.
    pub fn agent_pos(&self) -> [f64; ACTION_DIM] {
        agent_pos(self.data.qpos())
    }

    pub fn time(&self) -> f64 {
        self.data.time()
    }

    pub fn qpos(&self) -> &[f64] {
        self.data.qpos()
    }

    pub fn qvel(&self) -> &[f64] {
        self.data.qvel()
    }

    pub fn ctrl(&self) -> &[f64] {
        self.data.ctrl()
    }

    /// A render context for this env's model: the scene's own visual settings, MuJoCo 3.3.7's
    /// colours as they are, and dm_control's default scene options (geom groups 0–2 shown).
    pub fn renderer(&mut self, gl: Rc<GlContext>) -> Result<SceneRenderer, SimError> {
        let options = RenderOptions { look: Look::Mujoco337, quality: Quality::Reference, max_width: 0, max_height: 0 };
        self.renderer_with(gl, options)
    }

    /// A render context with other options (a larger buffer for a captioned panel, preview
    /// quality), the same scene options as [`renderer`](Self::renderer).
    pub fn renderer_with(&mut self, gl: Rc<GlContext>, options: RenderOptions) -> Result<SceneRenderer, SimError> {
        let mut renderer = SceneRenderer::new(gl, &mut self.model, options)?;
        renderer.set_geom_group(0, true);
        Ok(renderer)
    }

    /// Draw a camera's view of the current state into a region of the renderer's buffer
    /// (reference row order, like everything in the buffer).
    pub fn draw_camera(&mut self, renderer: &mut SceneRenderer, camera: usize, rect: Rect) -> Result<(), SimError> {
        // SAFETY: the renderer was made from this env's model (`renderer_with`), data is live.
        unsafe { renderer.draw_camera(self.model.ffi(), self.data.ffi_mut(), camera, rect) }
    }

    /// A camera's 480 × 640 frame of the current state, upright (dm_control flips the rows MuJoCo
    /// reads back, so `obs["pixels"]["top"]` is upright).
    pub fn render(&mut self, renderer: &mut SceneRenderer, camera: &str) -> Result<Frame, SimError> {
        let id = renderer.camera_id(camera)?;
        let rect = Rect::new(0, 0, TOP_WIDTH, TOP_HEIGHT);
        self.draw_camera(renderer, id, rect)?;
        Ok(renderer.read(rect)?.upright())
    }

    /// `obs["pixels"]["top"]`: what a policy sees.
    pub fn render_top(&mut self, renderer: &mut SceneRenderer) -> Result<Frame, SimError> {
        self.render(renderer, TOP_CAMERA)
    }

    /// MuJoCo's warning counters. dm_control's `Physics.step` raises `PhysicsError` when any of
    /// them grows during the step (`check_invalid_state`), so [`step`](Self::step) errs then too.
    fn warnings(&self) -> Vec<i32> {
        self.data.ffi().warning.iter().map(|w| w.number).collect()
    }
}
