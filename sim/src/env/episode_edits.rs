//! What an episode changes in the env besides its init state: the perturbations of the model at
//! load time (the `agentview` camera pose) and of the controller (the arm's reset configuration).
//!
//! The reference applies these when it builds the model (LIBERO-Plus compiles the camera pose into
//! the scene XML and picks a robot class whose `init_qpos` differs), so a hard reset rebuilds them
//! every episode. Here the compiled model is reused across episodes, so [`LiberoEnv::reset_to`]
//! re-applies the edits of the episode at hand and restores the nominal values where it has none:
//! an unperturbed episode after a perturbed one is bit for bit an unperturbed episode.

use super::LiberoEnv;
use crate::SimError;
use crate::osc::{ARM_DOF, ArmState};
use crate::viewpoint::CameraPose;
use mujoco_rs::mujoco_c;
use mujoco_rs::prelude::*;

/// The camera LIBERO-Plus moves.
const AGENTVIEW: &str = "agentview";

/// The finger joints when robosuite's controller caches the reset-time kinematics: at the freshly
/// built model's `qpos0`, not yet at the gripper's `init_qpos` (the arm's mass matrix includes the
/// fingers). Found by computing the cache at the nominal `init_qpos`: with these values it equals
/// the bundle's recorded snapshot bit for bit, with `init_qpos` of the gripper it is 1e-4 off.
const GRIPPER_INIT_QPOS: [f64; 2] = [0.0, 0.0];

/// The edits of the next episodes (set with [`LiberoEnv::set_episode_edits`]; kept until changed).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EpisodeEdits {
    /// The `agentview` camera's pose as the scene XML would state it (normalised on apply, as
    /// MuJoCo's compiler does).
    pub agentview: Option<CameraPose>,
    /// The arm's 7 joint positions at `reset()` (robosuite `init_qpos`). `set_init_state` then
    /// overwrites the arm with the init state's, so this survives only in the controller: its
    /// null-space target for the whole episode and its stale reset-time cache, which sets the first
    /// step's goal (LIBERO-Plus robot-init variants; `perturbation-spec.md` §B2).
    pub robot_init_qpos: Option<[f64; ARM_DOF]>,
}

/// The compiled model's own values of what [`EpisodeEdits`] can change.
#[derive(Debug, Clone)]
pub(super) struct Nominal {
    /// `agentview`'s id and compiled pose, if the scene has that camera.
    agentview: Option<(usize, CameraPose)>,
}

impl Nominal {
    pub(super) fn of(model: &MjModel) -> Self {
        let id = model.name_to_id(MjtObj::mjOBJ_CAMERA, AGENTVIEW);
        let agentview = (id >= 0).then(|| {
            let id = id as usize;
            (id, CameraPose { pos: model.cam_pos()[id], quat: model.cam_quat()[id] })
        });
        Nominal { agentview }
    }
}

impl LiberoEnv {
    /// Set what the following resets change (perturbations); `EpisodeEdits::default()` restores the
    /// task as the bundle defines it. Invalid values are refused here, before any reset.
    pub fn set_episode_edits(&mut self, edits: EpisodeEdits) -> Result<(), SimError> {
        if edits.agentview.is_some() && self.nominal.agentview.is_none() {
            return Err(SimError::UnknownCamera { name: AGENTVIEW.into(), available: self.camera_names().join(", ") });
        }
        if let Some(q) = &edits.robot_init_qpos {
            let ranges = self.model.jnt_range();
            let jnt_qposadr = self.model.jnt_qposadr();
            for (i, &adr) in self.qpos_index.iter().enumerate() {
                let joint = (0..jnt_qposadr.len()).find(|&j| jnt_qposadr[j] as usize == adr);
                let [lo, hi] = joint.map(|j| ranges[j]).unwrap_or([f64::NEG_INFINITY, f64::INFINITY]);
                if !q[i].is_finite() || q[i] < lo || q[i] > hi {
                    return Err(SimError::Other(format!(
                        "robot_init_qpos[{i}] = {} is outside the arm joint's range [{lo}, {hi}]",
                        q[i]
                    )));
                }
            }
        }
        self.edits = edits;
        Ok(())
    }

    pub fn episode_edits(&self) -> &EpisodeEdits {
        &self.edits
    }

    /// The scene's camera names (for errors).
    fn camera_names(&self) -> Vec<String> {
        (0..self.model.ffi().ncam)
            .filter_map(|i| self.model.id_to_name(MjtObj::mjOBJ_CAMERA, i).map(str::to_string))
            .collect()
    }

    /// Write the episode's camera pose (or the compiled one) into the live model.
    pub(super) fn apply_camera_edits(&mut self) -> Result<(), SimError> {
        if let Some((id, nominal)) = self.nominal.agentview {
            let pose = self.edits.agentview.map(|p| p.compiled()).unwrap_or(nominal);
            self.model.cam_pos_mut()[id] = pose.pos;
            self.model.cam_quat_mut()[id] = pose.quat;
        }
        Ok(())
    }

    /// The controller's reset-time cache for this episode, with the controller's rest pose set to
    /// match: the bundle's recorded snapshot, or, for a changed `init_qpos`, the kinematics of the
    /// arm at rest there (fingers at `qpos0`, see [`GRIPPER_INIT_QPOS`]), as robosuite's `reset()`
    /// leaves them. Leaves the data to be overwritten by the init state.
    pub(super) fn reset_time_arm_state(&mut self) -> ArmState {
        let c = &self.bundle.task.controller;
        let Some(q) = self.edits.robot_init_qpos else {
            let initial: [f64; ARM_DOF] = std::array::from_fn(|i| c.initial_joint[i]);
            let goal_ori = nalgebra::Matrix3::from_fn(|i, j| c.reset_snapshot.goal_ori[i][j]);
            self.osc.set_rest_pose(&initial, &goal_ori);
            return self.reset_snapshot.clone();
        };
        self.arm_state_at_rest(&q)
    }

    /// The arm state robosuite's controller caches with the arm at `q` and at rest.
    pub fn arm_state_at_rest(&mut self, q: &[f64; ARM_DOF]) -> ArmState {
        unsafe { mujoco_c::mj_resetData(self.model.ffi(), self.data_ptr()) };
        let qpos = self.data.qpos_mut();
        for (i, &adr) in self.qpos_index.iter().enumerate() {
            qpos[adr] = q[i];
        }
        for (i, &adr) in self.gripper_qpos.iter().enumerate() {
            qpos[adr] = GRIPPER_INIT_QPOS[i];
        }
        self.data.forward();
        let s = self.arm_state();
        self.osc.set_rest_pose(q, &s.ee_ori);
        s
    }
}
