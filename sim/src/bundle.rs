//! Task bundles: everything the Rust env needs about one LIBERO task, with no Python.
//!
//! Layout (written by `scripts/reference/build_bundles.py`, format
//! [`libero_schema::bundle_format::BUNDLE_FORMAT_VERSION`]):
//!
//! ```text
//! data/bundles/
//!   index.json                      suites, tasks, instructions
//!   assets/{robosuite,libero}/...   meshes and textures shared by all scenes
//!   <suite>/<task_id:02>/
//!     scene.xml                     robosuite's raw MJCF, asset paths relative to this file
//!     init_states.npy               (n, 1+nq+nv) float64 rows: [time, qpos, qvel]
//!     fixtures.json                 fixture root-body poses per env seed and episode index
//!     fixtures_seeded.json          optional: poses after env.seed(seed) and one reset, per seed
//!     task.json                     instruction, goal, objects, regions, controller constants
//!     reference_model.json          the reference's compiled-model sizes and arrays
//!     provenance.json               versions, input hashes, checks made at build time
//! ```
//!
//! **The `seed` of a spec row** is the env seed the reference loop passes to `env.seed()` once per
//! task (OpenVLA: 0, openpi: 7). The reference re-samples fixture poses (cabinet, stove, rack…) from
//! numpy's global RNG at every `reset()`, so the scene of episode `i` is the one after `i+1` resets:
//! the bundle stores it for `(seed, episode = init_state_id)`.
//!
//! **lerobot's protocol** ([`EvalProtocol::Lerobot`]) seeds the env right before each episode's one
//! reset instead, so its episodes start from the poses after `env.seed(seed)` and one reset:
//! `fixtures_seeded.json`, added to built bundles by `scripts/reference/seeded_fixtures.py`
//! (`./setup.sh --lerobot-fixtures`) and read only when `provenance.json` records it
//! (`seeded_at_reset`).

use crate::SimError;
use crate::npy::{self, Array2};
use libero_schema::bundle_format::{BUNDLE_FORMAT_VERSION, MUJOCO_VERSION};
use libero_schema::{EvalProtocol, InstructionSource, Suite};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One row of `index.json`.
#[derive(Debug, Clone, Deserialize)]
pub struct TaskIndexEntry {
    pub suite: String,
    pub task_id: u32,
    pub name: String,
    pub instructions: Instructions,
    pub path: String,
    pub nq: usize,
    pub nv: usize,
    pub nbody: usize,
    pub ngeom: usize,
    pub n_init_states: usize,
}

#[derive(Debug, Clone, Deserialize)]
struct Index {
    bundle_format_version: u32,
    mujoco: String,
    tasks: Vec<TaskIndexEntry>,
}

/// The folder of all bundles (`data/bundles`), opened and version-checked.
#[derive(Debug, Clone)]
pub struct BundleSet {
    root: PathBuf,
    index: Vec<TaskIndexEntry>,
}

impl BundleSet {
    /// A set with no tasks at `root`: the LIBERO side of a run of another benchmark (ALOHA-sim),
    /// which needs no LIBERO bundles.
    pub fn none(root: impl AsRef<Path>) -> Self {
        BundleSet { root: root.as_ref().to_path_buf(), index: vec![] }
    }

    /// Open the bundle folder; fails with a rebuild hint when it is missing, corrupt, or was made
    /// by another exporter or MuJoCo version.
    pub fn open(root: impl AsRef<Path>) -> Result<Self, SimError> {
        let root = root.as_ref().to_path_buf();
        let index_path = root.join("index.json");
        if !index_path.exists() {
            return Err(SimError::BundleMissing {
                path: root,
                hint: "no index.json; build the bundles with ./setup.sh".into(),
            });
        }
        let index: Index = read_json(&index_path)?;
        check_versions(&root, index.bundle_format_version, &index.mujoco)?;
        Ok(BundleSet { root, index: index.tasks })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Every task with a bundle, in (suite, task_id) order.
    pub fn tasks(&self) -> &[TaskIndexEntry] {
        &self.index
    }

    pub fn entry(&self, suite: Suite, task_id: u32) -> Result<&TaskIndexEntry, SimError> {
        self.index.iter().find(|t| t.suite == suite.name() && t.task_id == task_id).ok_or_else(|| {
            let ids: Vec<String> =
                self.index.iter().filter(|t| t.suite == suite.name()).map(|t| t.task_id.to_string()).collect();
            SimError::UnknownTask {
                suite: suite.name(),
                task_id,
                available: if ids.is_empty() {
                    format!("none (build them with ./setup.sh --suites {suite})")
                } else if (task_id as usize) < suite.n_tasks() as usize
                    || suite.perturbation == Some(libero_schema::Perturbation::PlusLayout)
                {
                    format!("{} only (build the whole suite with ./setup.sh --suites {suite})", ids.join(", "))
                } else {
                    ids.join(", ")
                },
            }
        })
    }

    /// Load one task's bundle.
    pub fn load(&self, suite: Suite, task_id: u32) -> Result<TaskBundle, SimError> {
        let entry = self.entry(suite, task_id)?;
        TaskBundle::load(self.root.join(&entry.path))
    }
}

fn check_versions(path: &Path, format: u32, mujoco: &str) -> Result<(), SimError> {
    if format != BUNDLE_FORMAT_VERSION {
        return Err(SimError::BundleVersion {
            path: path.into(),
            what: "bundle format",
            found: format.to_string(),
            expected: BUNDLE_FORMAT_VERSION.to_string(),
        });
    }
    if mujoco != MUJOCO_VERSION {
        return Err(SimError::BundleVersion {
            path: path.into(),
            what: "MuJoCo",
            found: mujoco.into(),
            expected: MUJOCO_VERSION.into(),
        });
    }
    Ok(())
}

/// A LIBERO object or fixture as the goal predicates see it.
#[derive(Debug, Clone, Deserialize)]
pub struct ObjectInfo {
    pub root_body: String,
    /// Non-visual geoms of the object (the ones `contact(a, b)` looks at).
    pub contact_geoms: Vec<String>,
    pub joints: Vec<String>,
    pub cls: String,
    #[serde(default)]
    pub category: Option<String>,
    pub fixture: bool,
    /// predicate ("open", "close", "turnon", "turnoff") -> how a joint position decides it.
    #[serde(default)]
    pub articulation: BTreeMap<String, ArticulationRule>,
}

/// `q <cmp> value` decides an articulation predicate for one joint.
#[derive(Debug, Clone, Copy, Deserialize)]
pub struct ArticulationRule {
    pub cmp: Comparison,
    pub value: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Comparison {
    Lt,
    Gt,
    Ge,
}

impl ArticulationRule {
    pub fn holds(&self, q: f64) -> bool {
        match self.cmp {
            Comparison::Lt => q < self.value,
            Comparison::Gt => q > self.value,
            Comparison::Ge => q >= self.value,
        }
    }
}

/// A region or site (`SiteObjectState` in LIBERO).
#[derive(Debug, Clone, Deserialize)]
pub struct SiteInfo {
    pub cls: String,
    pub parent: Option<String>,
    pub size: Vec<f64>,
    pub joints: Vec<String>,
}

/// The robot/controller constants and the reset-time controller cache (see [`crate::osc`]).
#[derive(Debug, Clone, Deserialize)]
pub struct ControllerInfo {
    pub eef_site: String,
    pub qpos_index: Vec<usize>,
    pub qvel_index: Vec<usize>,
    pub arm_actuators: Vec<usize>,
    pub gripper_actuators: Vec<usize>,
    pub kp: Vec<f64>,
    pub kd: Vec<f64>,
    pub output_max: Vec<f64>,
    pub output_min: Vec<f64>,
    pub input_max: Vec<f64>,
    pub input_min: Vec<f64>,
    pub nullspace_kp: f64,
    pub initial_joint: Vec<f64>,
    pub gripper_speed: f64,
    pub gripper_current_action_after_reset: Vec<f64>,
    pub reset_snapshot: ResetSnapshot,
}

/// What robosuite's OSC controller cached at `reset()` (robot at `init_qpos`, at rest).
#[derive(Debug, Clone, Deserialize)]
pub struct ResetSnapshot {
    pub ee_pos: Vec<f64>,
    pub ee_ori_mat: Vec<Vec<f64>>,
    pub ee_pos_vel: Vec<f64>,
    pub ee_ori_vel: Vec<f64>,
    #[serde(rename = "J_pos")]
    pub j_pos: Vec<Vec<f64>>,
    #[serde(rename = "J_ori")]
    pub j_ori: Vec<Vec<f64>>,
    pub mass_matrix: Vec<Vec<f64>>,
    pub joint_pos: Vec<f64>,
    pub joint_vel: Vec<f64>,
    pub goal_ori: Vec<Vec<f64>>,
    pub new_update: bool,
}

#[derive(Debug, Clone, Deserialize)]
pub struct ControlInfo {
    pub control_freq: u32,
    pub substeps: u32,
    pub timestep: f64,
    pub horizon: u32,
}

#[derive(Debug, Clone, Deserialize)]
pub struct InitStatesInfo {
    pub file: String,
    pub count: usize,
    pub nq: usize,
    pub nv: usize,
}

/// A task's instruction texts (see [`InstructionSource`]; the exporter's `instructions()`).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
pub struct Instructions {
    /// The BDDL `(:language ...)` tag as the env parses it (`env.language_instruction`, lowercased).
    pub bddl: String,
    /// `task.language`, derived from the BDDL file name; for LIBERO-PRO's `_lan` and `_task` the
    /// unperturbed base text, never given to a policy there.
    pub filename: String,
    /// The one the suite's published evaluation gives: `filename` for the LIBERO suites, `bddl`
    /// for the LIBERO-PRO suites.
    pub published: String,
}

impl Instructions {
    /// The text a policy gets under `source` in a LIBERO-PRO suite (`pro`) or a LIBERO one, and
    /// which text it is (`filename` or `bddl`).
    pub fn given(&self, source: InstructionSource, pro: bool) -> (&str, &'static str) {
        match source {
            InstructionSource::Published if !pro => (&self.filename, "filename"),
            _ => (&self.bddl, "bddl"),
        }
    }
}

/// `task.json`.
#[derive(Debug, Clone, Deserialize)]
pub struct TaskInfo {
    pub suite: String,
    pub task_id: u32,
    pub name: String,
    /// The LIBERO suite this task's suite is or perturbs (the exporter's view; the pipeline derives
    /// its own from the suite name and the bundle tests hold the two equal).
    pub base_suite: String,
    /// LIBERO-PRO perturbation (`swap`, `object`, `lan`, `task`, `env`), null for a LIBERO suite.
    pub perturbation: Option<String>,
    /// Made at set-up by LIBERO-PRO's own generator rather than shipped (the `_env` suites): its
    /// numbers cannot be compared with the authors'.
    #[serde(default)]
    pub generated_locally: bool,
    pub instructions: Instructions,
    pub problem: String,
    pub bddl_file: String,
    /// The conjunction of goal predicates, e.g. `[["on", "akita_black_bowl_1", "plate_1"]]`.
    pub goal: Vec<Vec<String>>,
    pub objects_of_interest: Vec<String>,
    pub regions: Vec<String>,
    pub objects: BTreeMap<String, ObjectInfo>,
    pub sites: BTreeMap<String, SiteInfo>,
    pub fixture_bodies: Vec<String>,
    pub cameras: Vec<String>,
    pub init_states: InitStatesInfo,
    pub fixture_seeds: Vec<u64>,
    pub fixture_episodes: usize,
    pub control: ControlInfo,
    pub controller: ControllerInfo,
    /// Model fields `reset()` changes besides fixture poses: field -> row -> values.
    pub model_overrides: BTreeMap<String, BTreeMap<String, Vec<f64>>>,
}

impl TaskInfo {
    /// The instruction a policy gets under `source`, and which text it is (`filename` or `bddl`,
    /// the value of the episodes' `instruction_source`).
    pub fn instruction(&self, source: InstructionSource) -> (&str, &'static str) {
        self.instructions.given(source, self.perturbation.is_some())
    }

    /// The objects a failure analysis watches, as object names (the names of
    /// `Observation::object_poses`): the BDDL's `:obj_of_interest` plus every object a goal term
    /// names, with a region (`wooden_cabinet_1_top_region`) replaced by the object that owns it
    /// (`wooden_cabinet_1`). Table regions, owned by no object, are left out.
    pub fn objects_of_interest_resolved(&self) -> Vec<String> {
        let named = self.objects_of_interest.iter().chain(self.goal.iter().flat_map(|term| term.iter().skip(1)));
        let mut out: Vec<String> = Vec::new();
        for name in named {
            let object = if self.objects.contains_key(name) {
                Some(name.clone())
            } else {
                self.sites.get(name).and_then(|s| s.parent.clone()).filter(|p| self.objects.contains_key(p))
            };
            if let Some(o) = object
                && !out.contains(&o)
            {
                out.push(o);
            }
        }
        out
    }
}

/// A rigid pose; `quat` is MuJoCo's (w, x, y, z).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct Pose {
    pub pos: [f64; 3],
    pub quat: [f64; 4],
}

#[derive(Debug, Clone, Deserialize)]
struct FixturesFile {
    seeds: BTreeMap<String, Vec<BTreeMap<String, Pose>>>,
}

/// The fixture poses of env seeds set right before one reset (lerobot's protocol), beside
/// `fixtures.json`; optional.
pub const SEEDED_FIXTURES_FILE: &str = "fixtures_seeded.json";
/// The `provenance.json` key recording [`SEEDED_FIXTURES_FILE`]: its sha256, seeds and checks.
pub const SEEDED_RECORD: &str = "seeded_at_reset";

#[derive(Debug, Clone, Deserialize)]
struct SeededFixturesFile {
    seeds: BTreeMap<String, BTreeMap<String, Pose>>,
}

/// `reference_model.json`: the reference's compiled model, for parity checks.
#[derive(Debug, Clone, Deserialize)]
pub struct ReferenceModel {
    pub sizes: BTreeMap<String, i64>,
    pub options: BTreeMap<String, f64>,
    pub arrays: BTreeMap<String, serde_json::Value>,
    pub names: BTreeMap<String, Vec<Option<String>>>,
}

/// One loaded task bundle.
#[derive(Debug, Clone)]
pub struct TaskBundle {
    pub dir: PathBuf,
    pub task: TaskInfo,
    pub init_states: Array2,
    /// seed -> episode -> fixture root body -> pose.
    fixtures: BTreeMap<u64, Vec<BTreeMap<String, Pose>>>,
    /// seed -> fixture root body -> pose after `env.seed(seed)` and one reset (lerobot's
    /// protocol); empty when `fixtures_seeded.json` was not recorded.
    seeded: BTreeMap<u64, BTreeMap<String, Pose>>,
    pub provenance: serde_json::Value,
    /// Each object's footprint radius (robosuite's `horizontal_radius`), by object name, from
    /// `object_radii.json` beside `index.json` (written at set-up from LIBERO's object classes;
    /// the compiled scene drops the sites it is read from). None when that file is absent: only
    /// LIBERO-PRO's placement perturbations need it, and they refuse to run without it.
    pub horizontal_radii: Option<BTreeMap<String, f64>>,
}

/// `object_radii.json`: `horizontal_radius` per LIBERO object class name.
#[derive(Debug, Clone, Deserialize)]
struct ObjectRadiiFile {
    radii: BTreeMap<String, f64>,
}

/// The file of object radii of the bundle set a bundle directory (`<root>/<suite>/<NN>`) is in.
pub const OBJECT_RADII_FILE: &str = "object_radii.json";

impl TaskBundle {
    pub fn load(dir: impl AsRef<Path>) -> Result<Self, SimError> {
        let dir = dir.as_ref().to_path_buf();
        if !dir.join("task.json").exists() {
            return Err(SimError::BundleMissing {
                path: dir,
                hint: "no task.json; build the bundles with ./setup.sh".into(),
            });
        }
        let provenance: serde_json::Value = read_json(&dir.join("provenance.json"))?;
        let format = provenance["bundle_format_version"].as_u64().unwrap_or(0) as u32;
        let mujoco = provenance["versions"]["mujoco"].as_str().unwrap_or("unknown");
        check_versions(&dir, format, mujoco)?;
        let task: TaskInfo = read_json(&dir.join("task.json"))?;
        let init_path = dir.join(&task.init_states.file);
        let init_states = npy::read_f64_2d(&init_path)
            .map_err(|detail| SimError::BundleCorrupt { path: init_path.clone(), detail })?;
        let width = 1 + task.init_states.nq + task.init_states.nv;
        if init_states.cols != width || init_states.rows != task.init_states.count {
            return Err(SimError::BundleCorrupt {
                path: init_path,
                detail: format!(
                    "init states are {}x{}, task.json says {}x{width}",
                    init_states.rows, init_states.cols, task.init_states.count
                ),
            });
        }
        let fixtures_file: FixturesFile = read_json(&dir.join("fixtures.json"))?;
        let mut fixtures = BTreeMap::new();
        for (seed, episodes) in fixtures_file.seeds {
            let seed: u64 = seed.parse().map_err(|_| SimError::BundleCorrupt {
                path: dir.join("fixtures.json"),
                detail: format!("seed key {seed:?} is not an integer"),
            })?;
            fixtures.insert(seed, episodes);
        }
        let mut seeded = BTreeMap::new();
        if provenance.get(SEEDED_RECORD).is_some() {
            let file: SeededFixturesFile = read_json(&dir.join(SEEDED_FIXTURES_FILE))?;
            for (seed, poses) in file.seeds {
                let seed: u64 = seed.parse().map_err(|_| SimError::BundleCorrupt {
                    path: dir.join(SEEDED_FIXTURES_FILE),
                    detail: format!("seed key {seed:?} is not an integer"),
                })?;
                seeded.insert(seed, poses);
            }
        }
        if !dir.join("scene.xml").exists() {
            return Err(SimError::BundleCorrupt { path: dir.join("scene.xml"), detail: "missing".into() });
        }
        let radii_path = dir.parent().and_then(Path::parent).map(|root| root.join(OBJECT_RADII_FILE));
        let horizontal_radii = match radii_path.filter(|p| p.exists()) {
            None => None,
            Some(p) => {
                let by_class: ObjectRadiiFile = read_json(&p)?;
                Some(
                    task.objects
                        .iter()
                        .filter_map(|(name, o)| by_class.radii.get(&o.cls).map(|r| (name.clone(), *r)))
                        .collect(),
                )
            }
        };
        Ok(TaskBundle { dir, task, init_states, fixtures, seeded, provenance, horizontal_radii })
    }

    pub fn scene_path(&self) -> PathBuf {
        self.dir.join("scene.xml")
    }

    pub fn suite(&self) -> Result<Suite, SimError> {
        self.task.suite.parse().map_err(SimError::Other)
    }

    pub fn reference_model(&self) -> Result<ReferenceModel, SimError> {
        read_json(&self.dir.join("reference_model.json"))
    }

    /// The init state row `[time, qpos, qvel]` of trial `id`.
    pub fn init_state(&self, id: usize) -> Result<&[f64], SimError> {
        if id >= self.init_states.rows {
            return Err(SimError::InitStateOutOfRange { id, count: self.init_states.rows });
        }
        Ok(self.init_states.row(id))
    }

    /// Env seeds with recorded fixture poses.
    pub fn fixture_seeds(&self) -> Vec<u64> {
        self.fixtures.keys().copied().collect()
    }

    /// Env seeds with recorded fixture poses after `env.seed(seed)` and one reset (lerobot's
    /// protocol); empty when none were recorded.
    pub fn seeded_fixture_seeds(&self) -> Vec<u64> {
        self.seeded.keys().copied().collect()
    }

    /// The fixture poses an episode of `protocol` starts from: episode `init_state_id` after
    /// `env.seed(seed)` (canonical), or after `env.seed(seed)` and one reset (lerobot).
    pub fn start_fixture_poses(
        &self,
        protocol: EvalProtocol,
        seed: u64,
        init_state_id: usize,
    ) -> Result<&BTreeMap<String, Pose>, SimError> {
        match protocol {
            EvalProtocol::Canonical => self.fixture_poses(seed, init_state_id),
            EvalProtocol::Lerobot => self.seeded.get(&seed).ok_or_else(|| SimError::UnknownSeededSeed {
                seed,
                path: self.dir.clone(),
                available: match self.seeded_fixture_seeds().as_slice() {
                    [] => "no seed".to_string(),
                    [only] => format!("seed {only}"),
                    seeds if seeds.windows(2).all(|w| w[1] == w[0] + 1) => {
                        format!("seeds {}..={}", seeds[0], seeds[seeds.len() - 1])
                    }
                    seeds => format!("seeds {seeds:?}"),
                },
            }),
        }
    }

    /// Fixture root-body poses of episode `episode` after `env.seed(seed)`.
    pub fn fixture_poses(&self, seed: u64, episode: usize) -> Result<&BTreeMap<String, Pose>, SimError> {
        self.fixtures.get(&seed).and_then(|eps| eps.get(episode)).ok_or_else(|| SimError::UnknownSeed {
            seed,
            episode,
            available: format!("{:?}", self.fixture_seeds()),
            episodes: self.task.fixture_episodes,
        })
    }
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, SimError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SimError::BundleCorrupt { path: path.into(), detail: format!("cannot read: {e}") })?;
    serde_json::from_str(&text).map_err(|e| SimError::BundleCorrupt { path: path.into(), detail: e.to_string() })
}
