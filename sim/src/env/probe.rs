//! Privileged geometry of the scene for scripted policies: object boxes, region frames, the joints
//! of articulated objects. Names are resolved once per episode ([`SceneProbe::new`]); reading is
//! cheap enough for every step.

use super::LiberoEnv;
use crate::SimError;
use crate::scene::object_id;
use mujoco_rs::prelude::*;

/// An axis-aligned box `(min, max)`.
pub type Box3 = ([f64; 3], [f64; 3]);

/// One object now: its root-body frame and the box of its contact geoms in that frame and in the
/// world.
#[derive(Debug, Clone, Copy)]
pub struct ObjectGeometry {
    pub pos: [f64; 3],
    pub xmat: [f64; 9],
    pub local_box: Box3,
    pub world_box: Box3,
}

/// One site now.
#[derive(Debug, Clone, Copy)]
pub struct SiteFrame {
    pub pos: [f64; 3],
    pub xmat: [f64; 9],
}

/// One joint now.
#[derive(Debug, Clone, Copy)]
pub struct JointFrame {
    pub qpos: f64,
    pub slide: bool,
    pub axis: [f64; 3],
    pub anchor: [f64; 3],
    /// World box of every geom of the body the joint moves.
    pub moving_box: Box3,
}

/// Resolved ids for reading [`ObjectGeometry`], [`SiteFrame`] and [`JointFrame`] off an env.
#[derive(Debug, Clone)]
pub struct SceneProbe {
    objects: Vec<(usize, Vec<usize>)>,
    sites: Vec<usize>,
    /// (joint id, qpos address, geoms of its body)
    joints: Vec<(usize, usize, Vec<usize>)>,
}

impl SceneProbe {
    /// Objects in [`LiberoEnv::object_names`] order; sites and joints as named.
    pub fn new(env: &LiberoEnv, sites: &[String], joints: &[String]) -> Result<Self, SimError> {
        let model = env.model();
        let task = &env.bundle.task;
        let objects = env
            .object_bodies
            .iter()
            .map(|(name, body)| {
                let geoms = task.objects[name]
                    .contact_geoms
                    .iter()
                    .map(|g| object_id(model, MjtObj::mjOBJ_GEOM, g, "geom"))
                    .collect::<Result<Vec<_>, _>>()?;
                Ok((*body, geoms))
            })
            .collect::<Result<Vec<_>, SimError>>()?;
        let sites = sites.iter().map(|s| object_id(model, MjtObj::mjOBJ_SITE, s, "site")).collect::<Result<_, _>>()?;
        let geom_bodyid = model.geom_bodyid();
        let joints = joints
            .iter()
            .map(|j| {
                let id = object_id(model, MjtObj::mjOBJ_JOINT, j, "joint")?;
                let body = model.jnt_bodyid()[id];
                let geoms = (0..geom_bodyid.len()).filter(|&g| geom_bodyid[g] == body).collect();
                Ok((id, model.jnt_qposadr()[id] as usize, geoms))
            })
            .collect::<Result<Vec<_>, SimError>>()?;
        Ok(SceneProbe { objects, sites, joints })
    }

    pub fn objects(&self, env: &LiberoEnv) -> Vec<ObjectGeometry> {
        let d = &env.data;
        self.objects
            .iter()
            .map(|(body, geoms)| {
                let pos = d.xpos()[*body];
                let xmat = d.xmat()[*body];
                let world_box = world_box(env, geoms);
                // Corners of each geom's box, in the body frame: R^T (p - pos).
                let mut local = ([f64::MAX; 3], [f64::MIN; 3]);
                for_each_corner(env, geoms, |p| {
                    let v = [p[0] - pos[0], p[1] - pos[1], p[2] - pos[2]];
                    for i in 0..3 {
                        let x = xmat[i] * v[0] + xmat[3 + i] * v[1] + xmat[6 + i] * v[2];
                        local.0[i] = local.0[i].min(x);
                        local.1[i] = local.1[i].max(x);
                    }
                });
                ObjectGeometry { pos, xmat, local_box: local, world_box }
            })
            .collect()
    }

    pub fn sites(&self, env: &LiberoEnv) -> Vec<SiteFrame> {
        let d = &env.data;
        self.sites.iter().map(|&s| SiteFrame { pos: d.site_xpos()[s], xmat: d.site_xmat()[s] }).collect()
    }

    pub fn joints(&self, env: &LiberoEnv) -> Vec<JointFrame> {
        let (m, d) = (env.model(), &env.data);
        self.joints
            .iter()
            .map(|(id, adr, geoms)| JointFrame {
                qpos: d.qpos()[*adr],
                slide: m.jnt_type()[*id] == MjtJoint::mjJNT_SLIDE,
                axis: d.xaxis()[*id],
                anchor: d.xanchor()[*id],
                moving_box: world_box(env, geoms),
            })
            .collect()
    }
}

/// Visit the 8 world-frame corners of each geom's local bounding box (`geom_aabb`).
fn for_each_corner(env: &LiberoEnv, geoms: &[usize], mut f: impl FnMut([f64; 3])) {
    let (m, d) = (env.model(), &env.data);
    let aabb = m.geom_aabb();
    for &g in geoms {
        let (c, h) = (&aabb[g][..3], &aabb[g][3..]);
        let (p, r) = (d.geom_xpos()[g], d.geom_xmat()[g]);
        for k in 0..8 {
            let s = [(k & 1) as f64 * 2.0 - 1.0, ((k >> 1) & 1) as f64 * 2.0 - 1.0, ((k >> 2) & 1) as f64 * 2.0 - 1.0];
            let l = [c[0] + s[0] * h[0], c[1] + s[1] * h[1], c[2] + s[2] * h[2]];
            f(std::array::from_fn(|i| p[i] + r[3 * i] * l[0] + r[3 * i + 1] * l[1] + r[3 * i + 2] * l[2]));
        }
    }
}

fn world_box(env: &LiberoEnv, geoms: &[usize]) -> Box3 {
    let mut b = ([f64::MAX; 3], [f64::MIN; 3]);
    for_each_corner(env, geoms, |p| {
        for (i, x) in p.into_iter().enumerate() {
            b.0[i] = b.0[i].min(x);
            b.1[i] = b.1[i].max(x);
        }
    });
    b
}
