//! Compiling a bundle's scene into a MuJoCo model equal to the reference's live model.
//!
//! The reference compiles robosuite's raw XML, then `reset()` changes the live model: fixture root
//! bodies get freshly sampled poses (per episode, see [`crate::bundle`]) and `visualize()` hides
//! some sites (rgba). The bundle records both; [`compile`] applies the constant part and
//! [`apply_fixture_poses`] the per-episode part.

use crate::SimError;
use crate::bundle::{Pose, ReferenceModel, TaskBundle};
use mujoco_rs::prelude::*;
use std::collections::BTreeMap;

/// Compile the bundle's scene and apply its constant model overrides.
pub fn compile(bundle: &TaskBundle) -> Result<MjModel, SimError> {
    let path = bundle.scene_path();
    let mut model =
        MjModel::from_xml(&path).map_err(|e| SimError::Compile { path: path.clone(), detail: e.to_string() })?;
    for (field, rows) in &bundle.task.model_overrides {
        for (row, values) in rows {
            let row: usize = row.parse().map_err(|_| SimError::BundleCorrupt {
                path: bundle.dir.join("task.json"),
                detail: format!("model_overrides.{field} has a non-integer row {row:?}"),
            })?;
            apply_override(&mut model, field, row, values)
                .map_err(|detail| SimError::BundleCorrupt { path: bundle.dir.join("task.json"), detail })?;
        }
    }
    Ok(model)
}

fn apply_override(model: &mut MjModel, field: &str, row: usize, values: &[f64]) -> Result<(), String> {
    let rgba = |v: &[f64]| -> Result<[f32; 4], String> {
        <[f64; 4]>::try_from(v).map(|a| a.map(|x| x as f32)).map_err(|_| format!("{field} row needs 4 values"))
    };
    let slot = match field {
        "site_rgba" => model.site_rgba_mut().get_mut(row),
        "geom_rgba" => model.geom_rgba_mut().get_mut(row),
        other => return Err(format!("unsupported model override field {other:?}")),
    };
    *slot.ok_or_else(|| format!("{field} row {row} out of range"))? = rgba(values)?;
    Ok(())
}

/// Put the fixture root bodies at the poses of one episode.
pub fn apply_fixture_poses(model: &mut MjModel, poses: &BTreeMap<String, Pose>) -> Result<(), SimError> {
    for (body, pose) in poses {
        let id = body_id(model, body)?;
        model.body_pos_mut()[id] = pose.pos;
        model.body_quat_mut()[id] = pose.quat;
    }
    Ok(())
}

pub fn body_id(model: &MjModel, name: &str) -> Result<usize, SimError> {
    object_id(model, MjtObj::mjOBJ_BODY, name, "body")
}

pub fn object_id(model: &MjModel, kind: MjtObj, name: &str, what: &str) -> Result<usize, SimError> {
    let id = model.name_to_id(kind, name);
    if id < 0 {
        return Err(SimError::Other(format!("the scene has no {what} named {name:?}")));
    }
    Ok(id as usize)
}

/// Differences between our compiled model and the reference's (sizes, options, parameter arrays).
/// Empty when they are equal, which the tests require for every bundle.
pub fn compare_with_reference(model: &MjModel, reference: &ReferenceModel) -> Vec<String> {
    let mut out = Vec::new();
    let ffi = model.ffi();
    let sizes: [(&str, i64); 13] = [
        ("nq", ffi.nq as i64),
        ("nv", ffi.nv as i64),
        ("nu", ffi.nu as i64),
        ("na", ffi.na as i64),
        ("nbody", ffi.nbody as i64),
        ("njnt", ffi.njnt as i64),
        ("ngeom", ffi.ngeom as i64),
        ("nsite", ffi.nsite as i64),
        ("nmesh", ffi.nmesh as i64),
        ("ntex", ffi.ntex as i64),
        ("nmat", ffi.nmat as i64),
        ("ncam", ffi.ncam as i64),
        ("nlight", ffi.nlight as i64),
    ];
    for (name, ours) in sizes {
        match reference.sizes.get(name) {
            Some(&theirs) if theirs == ours => {}
            other => out.push(format!("{name}: ours {ours}, reference {other:?}")),
        }
    }
    let opt = &ffi.opt;
    let options: [(&str, f64); 5] = [
        ("timestep", opt.timestep),
        ("density", opt.density),
        ("viscosity", opt.viscosity),
        ("impratio", opt.impratio),
        ("tolerance", opt.tolerance),
    ];
    for (name, ours) in options {
        if reference.options.get(name) != Some(&ours) {
            out.push(format!("opt.{name}: ours {ours}, reference {:?}", reference.options.get(name)));
        }
    }
    let flat = |v: &serde_json::Value| -> Vec<f64> {
        fn walk(v: &serde_json::Value, acc: &mut Vec<f64>) {
            match v {
                serde_json::Value::Array(a) => a.iter().for_each(|x| walk(x, acc)),
                serde_json::Value::Number(n) => acc.push(n.as_f64().unwrap_or(f64::NAN)),
                serde_json::Value::Bool(b) => acc.push(*b as u8 as f64),
                _ => acc.push(f64::NAN),
            }
        }
        let mut acc = Vec::new();
        walk(v, &mut acc);
        acc
    };
    for (name, theirs) in &reference.arrays {
        let Some(ours) = model_array(model, name) else {
            out.push(format!("{name}: not compared (unknown field)"));
            continue;
        };
        let theirs = flat(theirs);
        if ours.len() != theirs.len() {
            out.push(format!("{name}: {} values, reference {}", ours.len(), theirs.len()));
            continue;
        }
        let worst = ours.iter().zip(&theirs).map(|(a, b)| if a == b { 0.0 } else { (a - b).abs() }).fold(0.0, f64::max);
        if worst != 0.0 || ours.iter().zip(&theirs).any(|(a, b)| a.is_nan() != b.is_nan()) {
            out.push(format!("{name}: max |diff| {worst:e}"));
        }
    }
    out
}

fn model_array(m: &MjModel, name: &str) -> Option<Vec<f64>> {
    fn f<T: Copy + Into<f64>, const N: usize>(a: &[[T; N]]) -> Vec<f64> {
        a.iter().flatten().map(|&x| x.into()).collect()
    }
    fn s<T: Copy + Into<f64>>(a: &[T]) -> Vec<f64> {
        a.iter().map(|&x| x.into()).collect()
    }
    fn enum_ids<T: Copy>(a: &[T]) -> Vec<f64> {
        // rustified C enums are 4-byte discriminants
        a.iter().map(|x| unsafe { *(x as *const T as *const i32) } as f64).collect()
    }
    Some(match name {
        "body_parentid" => s(m.body_parentid()),
        "body_pos" => f(m.body_pos()),
        "body_quat" => f(m.body_quat()),
        "body_ipos" => f(m.body_ipos()),
        "body_iquat" => f(m.body_iquat()),
        "body_mass" => s(m.body_mass()),
        "body_inertia" => f(m.body_inertia()),
        "jnt_type" => enum_ids(m.jnt_type()),
        "jnt_qposadr" => s(m.jnt_qposadr()),
        "jnt_dofadr" => s(m.jnt_dofadr()),
        "jnt_range" => f(m.jnt_range()),
        "jnt_stiffness" => s(m.jnt_stiffness()),
        "dof_damping" => s(m.dof_damping()),
        "dof_armature" => s(m.dof_armature()),
        "dof_frictionloss" => s(m.dof_frictionloss()),
        "geom_type" => enum_ids(m.geom_type()),
        "geom_bodyid" => s(m.geom_bodyid()),
        "geom_group" => s(m.geom_group()),
        "geom_contype" => s(m.geom_contype()),
        "geom_conaffinity" => s(m.geom_conaffinity()),
        "geom_size" => f(m.geom_size()),
        "geom_friction" => f(m.geom_friction()),
        "geom_solref" => f(m.geom_solref()),
        "geom_solimp" => f(m.geom_solimp()),
        "geom_pos" => f(m.geom_pos()),
        "geom_quat" => f(m.geom_quat()),
        "actuator_ctrlrange" => f(m.actuator_ctrlrange()),
        "actuator_gainprm" => f(m.actuator_gainprm()),
        "actuator_biasprm" => f(m.actuator_biasprm()),
        "actuator_forcerange" => f(m.actuator_forcerange()),
        "site_pos" => f(m.site_pos()),
        "site_size" => f(m.site_size()),
        "cam_pos" => f(m.cam_pos()),
        "cam_quat" => f(m.cam_quat()),
        "cam_fovy" => s(m.cam_fovy()),
        "qpos0" => s(m.qpos0()),
        _ => return None,
    })
}
