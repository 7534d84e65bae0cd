//! The ALOHA-sim bundle: gym-aloha's scene files and what the oracle recorded about them.
//!
//! Built at set-up by `scripts/reference/aloha_bundle.py` from the gym-aloha 0.1.5 PyPI wheel
//! (`./setup.sh` links it as `data/aloha`):
//!
//! ```text
//! data/aloha/
//!   assets/               the two joint-space task XMLs, their end-effector twins (the scripted
//!                         control's), scene.xml, vx300s_*.xml and the STLs they use, byte-identical
//!                         to the wheel's (compiled as they are: no generated XML)
//!   provenance.json       the wheel's sha256, the oracle's versions, the sha256 of every file here
//!   reference_model.json  per task, the oracle's compiled model (sizes, options, parameter arrays)
//!   init_poses.json       per task and protocol seed, the qpos[16..] numpy drew
//!   golden/               reference episodes of the real gym env (the parity tests' data)
//! ```
//!
//! [`AlohaBundle::open`] checks every file against `provenance.json` before anything uses it, as
//! [`crate::bundle_integrity`] does for the LIBERO bundles: a damaged asset would otherwise be a
//! different robot, silently.

use super::task::AlohaTask;
use crate::SimError;
use crate::bundle::ReferenceModel;
use crate::bundle_integrity::check_file;
use libero_schema::bundle_format::MUJOCO_VERSION;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Where `./setup.sh` links the bundle, relative to the repository root.
pub const DEFAULT_DIR: &str = "data/aloha";

/// A verified ALOHA-sim bundle.
#[derive(Debug, Clone)]
pub struct AlohaBundle {
    dir: PathBuf,
    pub provenance: serde_json::Value,
    /// task → numpy seed → qpos[16..] as numpy drew it.
    init_poses: BTreeMap<AlohaTask, BTreeMap<u32, Vec<f64>>>,
    /// The seed lists of the protocols the oracle recorded poses for (`lerobot`, `openpi`).
    pub protocol_seeds: BTreeMap<String, Vec<u32>>,
}

#[derive(Deserialize)]
struct InitPosesFile {
    tasks: BTreeMap<String, BTreeMap<String, Vec<f64>>>,
    protocols: BTreeMap<String, Vec<u32>>,
}

impl AlohaBundle {
    /// Open the bundle at `dir` and check its files against its provenance.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self, SimError> {
        let dir = dir.as_ref().to_path_buf();
        let provenance_path = dir.join("provenance.json");
        if !provenance_path.exists() {
            return Err(SimError::BundleMissing {
                path: dir,
                hint: "no provenance.json; ./setup.sh --suites aloha_sim builds the ALOHA-sim bundle (scripts/reference/aloha_bundle.py) \
                       and links it as data/aloha"
                    .into(),
            });
        }
        let provenance: serde_json::Value = read_json(&provenance_path)?;
        let built_for = provenance["mujoco"].as_str().unwrap_or("unknown");
        if built_for != MUJOCO_VERSION {
            return Err(SimError::BundleVersion {
                path: dir,
                what: "MuJoCo",
                found: built_for.into(),
                expected: MUJOCO_VERSION.into(),
            });
        }
        let rebuild = |e: SimError| match e {
            SimError::BundleCorrupt { path, detail } => SimError::BundleDamaged {
                path,
                detail,
                rebuild: format!("rm {}/.complete && ./setup.sh --suites aloha_sim", dir.display()),
            },
            other => other,
        };
        let files = provenance["sha256"].as_object().filter(|f| !f.is_empty()).ok_or_else(|| {
            SimError::BundleCorrupt { path: provenance_path.clone(), detail: "no sha256 of the bundle's files".into() }
        })?;
        for (rel, expected) in files {
            check_file(&dir.join(rel), expected.as_str().unwrap_or_default()).map_err(rebuild)?;
        }
        let poses_path = dir.join("init_poses.json");
        let poses: InitPosesFile = read_json(&poses_path)?;
        let mut init_poses = BTreeMap::new();
        for (task, by_seed) in poses.tasks {
            let corrupt = |detail: String| SimError::BundleCorrupt { path: poses_path.clone(), detail };
            let task: AlohaTask = task.parse().map_err(corrupt)?;
            let by_seed = by_seed
                .into_iter()
                .map(|(s, pose)| -> Result<(u32, Vec<f64>), SimError> {
                    Ok((s.parse::<u32>().map_err(|e| corrupt(format!("seed {s:?}: {e}")))?, pose))
                })
                .collect::<Result<BTreeMap<_, _>, SimError>>()?;
            init_poses.insert(task, by_seed);
        }
        Ok(AlohaBundle { dir, provenance, init_poses, protocol_seeds: poses.protocols })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The task's scene file, to compile.
    pub fn scene_path(&self, task: AlohaTask) -> PathBuf {
        self.dir.join("assets").join(task.scene_file())
    }

    /// The task's end-effector scene (mocap-welded grippers), which the scripted positive control
    /// records its joint trajectories in.
    pub fn end_effector_scene_path(&self, task: AlohaTask) -> PathBuf {
        self.dir.join("assets").join(task.end_effector_scene_file())
    }

    /// The oracle's compiled model of `task` (MuJoCo 3.3.7 through dm_control), for parity checks.
    pub fn reference_model(&self, task: AlohaTask) -> Result<ReferenceModel, SimError> {
        let path = self.dir.join("reference_model.json");
        let mut all: BTreeMap<String, serde_json::Value> = read_json(&path)?;
        let one = all.remove(task.name()).ok_or_else(|| SimError::BundleCorrupt {
            path: path.clone(),
            detail: format!("no model of task {task}"),
        })?;
        serde_json::from_value(one).map_err(|e| SimError::BundleCorrupt { path, detail: e.to_string() })
    }

    /// Seeds with a recorded initial pose of `task`, ascending.
    pub fn recorded_seeds(&self, task: AlohaTask) -> Vec<u32> {
        self.init_poses.get(&task).map(|m| m.keys().copied().collect()).unwrap_or_default()
    }

    /// The qpos[16..] numpy drew for `task` and `seed`, when the oracle recorded it.
    pub fn recorded_pose(&self, task: AlohaTask, seed: u32) -> Option<&[f64]> {
        self.init_poses.get(&task)?.get(&seed).map(Vec::as_slice)
    }

    /// The reference episodes' folder (`golden/manifest.json` lists them).
    pub fn golden_dir(&self) -> PathBuf {
        self.dir.join("golden")
    }
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, SimError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SimError::BundleCorrupt { path: path.into(), detail: format!("cannot read: {e}") })?;
    serde_json::from_str(&text).map_err(|e| SimError::BundleCorrupt { path: path.into(), detail: e.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_bundle_names_the_set_up_command() {
        let err = AlohaBundle::open("/nonexistent/aloha").unwrap_err().to_string();
        assert!(err.contains("./setup.sh") && err.contains("/nonexistent/aloha"), "{err}");
    }
}
