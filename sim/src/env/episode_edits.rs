//! What an episode changes in the env besides its init state: the perturbations of the model at
//! load time (the `agentview` camera pose, the lights, objects' colours), of the controller (the
//! arm's reset configuration) and of the objects' placement (LIBERO-PRO's initial pose and runtime
//! move, in [`super::object_moves`]; its occluder, in [`super::occlusion`]).
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
    /// The `agentview` camera's pose written into the live model as given, *not* normalised:
    /// LIBERO-PRO's `camera` block writes `cam_pos`/`cam_quat` after reset, and its shipped
    /// quaternion is not unit (|q|² = 1.00243), which scales `cam_xmat` (`perturbation-spec.md` §C2).
    pub agentview_raw: Option<CameraPose>,
    /// LIBERO-PRO's `lighting` block: every light switched on and given these colours.
    pub lighting: Option<Lighting>,
    /// LIBERO-PRO's `object_appearance` block: objects recoloured, their textures dropped.
    pub appearance: Option<Appearance>,
    /// LIBERO-PRO's `initial_pose` block: an object yawed and shifted after `set_init_state`.
    pub initial_pose: Option<super::object_moves::InitialPose>,
    /// LIBERO-PRO's `runtime_move` block: an object shifted once, mid-episode.
    pub runtime_move: Option<super::object_moves::RuntimeMove>,
    /// LIBERO-PRO's `object_placement` block (`view_occlusion`): the occluder placed in front of
    /// the target and pinned after every step ([`super::occlusion`]).
    pub occlusion: Option<super::occlusion::Occlusion>,
    /// The arm's 7 joint positions at `reset()` (robosuite `init_qpos`). `set_init_state` then
    /// overwrites the arm with the init state's, so this survives only in the controller: its
    /// null-space target for the whole episode and its stale reset-time cache, which sets the first
    /// step's goal (LIBERO-Plus robot-init variants; `perturbation-spec.md` §B2).
    pub robot_init_qpos: Option<[f64; ARM_DOF]>,
}

/// LIBERO-PRO's lighting edit (`dark_lighting` and the like): each colour, when set, goes to every
/// light's three channels (a scalar broadcasts to all light slots), every light is switched on,
/// and `light_intensity` is zeroed (the classic renderer ignores it; the reference writes it).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Lighting {
    pub ambient: Option<f32>,
    pub diffuse: Option<f32>,
    pub specular: Option<f32>,
}

/// LIBERO-PRO's appearance edit: for every visual geom (group 1) of each object's body subtree,
/// or whose name starts with the object's name, `geom_rgba = rgba` and its material's
/// `mat_rgba = rgba`. A material shared with other geoms recolours those too, as in the reference.
///
/// The reference also writes `mat_texid = -1` to drop the textures, but its render context was
/// made at reset, before the edit, and a context keeps its own copy of the texture ids: the
/// policy still sees the texture, now tinted by `rgba` (the parity test renders the reference's
/// frames exactly so). We reproduce what the policy sees, so the texture ids are left alone.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Appearance {
    pub objects: Vec<String>,
    pub rgba: [f32; 4],
}

/// The compiled model's own values of what [`EpisodeEdits`] can change.
#[derive(Debug, Clone)]
pub(super) struct Nominal {
    /// `agentview`'s id and compiled pose, if the scene has that camera.
    agentview: Option<(usize, CameraPose)>,
    light_active: Vec<bool>,
    light_colours: Vec<[[f32; 3]; 3]>,
    light_intensity: Vec<f32>,
    geom_rgba: Vec<[f32; 4]>,
    mat_rgba: Vec<[f32; 4]>,
}

impl Nominal {
    pub(super) fn of(model: &MjModel) -> Self {
        let id = model.name_to_id(MjtObj::mjOBJ_CAMERA, AGENTVIEW);
        let agentview = (id >= 0).then(|| {
            let id = id as usize;
            (id, CameraPose { pos: model.cam_pos()[id], quat: model.cam_quat()[id] })
        });
        let light_colours = (0..model.ffi().nlight as usize)
            .map(|i| [model.light_ambient()[i], model.light_diffuse()[i], model.light_specular()[i]])
            .collect();
        Nominal {
            agentview,
            light_active: model.light_active().to_vec(),
            light_colours,
            light_intensity: model.light_intensity().to_vec(),
            geom_rgba: model.geom_rgba().to_vec(),
            mat_rgba: model.mat_rgba().to_vec(),
        }
    }
}

impl LiberoEnv {
    /// Set what the following resets change (perturbations); `EpisodeEdits::default()` restores the
    /// task as the bundle defines it. Invalid values are refused here, before any reset.
    pub fn set_episode_edits(&mut self, edits: EpisodeEdits) -> Result<(), SimError> {
        if edits.agentview.is_some() && edits.agentview_raw.is_some() {
            return Err(SimError::Other(
                "the agentview pose is set twice (a LIBERO-Plus view and a raw LIBERO-PRO pose): give one".into(),
            ));
        }
        if (edits.agentview.is_some() || edits.agentview_raw.is_some()) && self.nominal.agentview.is_none() {
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
        if let Some(a) = &edits.appearance {
            for name in &a.objects {
                self.object_root_body(name)?;
            }
        }
        for shift in [edits.initial_pose.as_ref().map(|p| &p.shift), edits.runtime_move.as_ref().map(|m| &m.shift)]
            .into_iter()
            .flatten()
        {
            self.check_shift(shift)?;
        }
        if let Some(o) = &edits.occlusion {
            self.check_occlusion(o)?;
        }
        self.edits = edits;
        Ok(())
    }

    /// The root body of object `name` (an object or fixture of the task), for errors that list
    /// the task's objects.
    pub(super) fn object_root_body(&self, name: &str) -> Result<usize, SimError> {
        match self.object_bodies.iter().find(|(n, _)| n == name) {
            Some(&(_, b)) => Ok(b),
            None => Err(SimError::Other(format!(
                "the task has no object {name:?}; its objects are {}",
                self.object_bodies.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(", ")
            ))),
        }
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
            let pose = self.edits.agentview.map(|p| p.compiled()).or(self.edits.agentview_raw).unwrap_or(nominal);
            self.model.cam_pos_mut()[id] = pose.pos;
            self.model.cam_quat_mut()[id] = pose.quat;
        }
        Ok(())
    }

    /// Restore the compiled lights and colours, then write the episode's lighting and appearance
    /// (a hard reset in the reference rebuilds the model, undoing the last episode's).
    pub(super) fn apply_look_edits(&mut self) -> Result<(), SimError> {
        let n = &self.nominal;
        self.model.light_active_mut().copy_from_slice(&n.light_active);
        self.model.light_intensity_mut().copy_from_slice(&n.light_intensity);
        for (i, [a, d, s]) in n.light_colours.iter().enumerate() {
            self.model.light_ambient_mut()[i] = *a;
            self.model.light_diffuse_mut()[i] = *d;
            self.model.light_specular_mut()[i] = *s;
        }
        self.model.geom_rgba_mut().copy_from_slice(&n.geom_rgba);
        self.model.mat_rgba_mut().copy_from_slice(&n.mat_rgba);
        if let Some(l) = self.edits.lighting {
            for i in 0..self.model.ffi().nlight as usize {
                self.model.light_active_mut()[i] = true;
                self.model.light_intensity_mut()[i] = 0.0;
                if let Some(a) = l.ambient {
                    self.model.light_ambient_mut()[i] = [a; 3];
                }
                if let Some(d) = l.diffuse {
                    self.model.light_diffuse_mut()[i] = [d; 3];
                }
                if let Some(s) = l.specular {
                    self.model.light_specular_mut()[i] = [s; 3];
                }
            }
        }
        if let Some(a) = self.edits.appearance.clone() {
            for name in &a.objects {
                for g in self.visual_geoms_of(name)? {
                    self.model.geom_rgba_mut()[g] = a.rgba;
                    let mat = self.model.geom_matid()[g];
                    if mat >= 0 {
                        self.model.mat_rgba_mut()[mat as usize] = a.rgba;
                    }
                }
            }
        }
        Ok(())
    }

    /// The visual geoms (group 1) of object `name`: those of its root body's subtree and those
    /// whose name starts with the object's name, in geom order.
    fn visual_geoms_of(&self, name: &str) -> Result<Vec<usize>, SimError> {
        let root = self.object_root_body(name)?;
        let m = &self.model;
        let parent = m.body_parentid();
        let in_subtree = |mut b: usize| loop {
            if b == root {
                return true;
            }
            if b == 0 {
                return false;
            }
            b = parent[b] as usize;
        };
        Ok((0..m.ffi().ngeom as usize)
            .filter(|&g| m.geom_group()[g] == 1)
            .filter(|&g| {
                in_subtree(m.geom_bodyid()[g] as usize)
                    || m.id_to_name(MjtObj::mjOBJ_GEOM, g as i32).is_some_and(|n| n.starts_with(name))
            })
            .collect())
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
