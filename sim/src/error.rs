use std::path::PathBuf;

/// Everything that can go wrong in the simulator, with enough context to act on.
#[derive(Debug, Clone, thiserror::Error)]
pub enum SimError {
    #[error("task bundle not found at {path}: {hint}")]
    BundleMissing { path: PathBuf, hint: String },
    #[error("task bundle at {path} is unreadable ({detail}); rebuild the bundles with ./setup.sh")]
    BundleCorrupt { path: PathBuf, detail: String },
    #[error("task bundle file {path} is {detail}; rebuild its suite: {rebuild}")]
    BundleDamaged { path: PathBuf, detail: String, rebuild: String },
    #[error(
        "task bundle at {path} was built for {what} {found}, but this build needs {expected}; rebuild the bundles with ./setup.sh"
    )]
    BundleVersion { path: PathBuf, what: &'static str, found: String, expected: String },
    #[error("unknown task {task_id} of {suite}: the bundles have tasks {available}")]
    UnknownTask { suite: String, task_id: u32, available: String },
    #[error("MuJoCo could not compile {path}: {detail}")]
    Compile { path: PathBuf, detail: String },
    #[error("init state {id} out of range: task has {count} init states (0..{count})")]
    InitStateOutOfRange { id: usize, count: usize },
    #[error(
        "no fixture poses for env seed {seed} (episode {episode}): the bundle has seeds {available} and {episodes} episodes each; rebuild with ./setup.sh after adding the seed"
    )]
    UnknownSeed { seed: u64, episode: usize, available: String, episodes: usize },
    #[error(
        "no fixture poses for env seed {seed} set right before the reset (protocol lerobot) in the bundle at {path}: it has them for {available}; record lerobot's seeds with ./setup.sh --lerobot-fixtures (scripts/reference/seeded_fixtures.py BUNDLES --tasks SUITE/NN --seeds S)"
    )]
    UnknownSeededSeed { seed: u64, path: PathBuf, available: String },
    #[error("invalid action {action:?}: {reason}")]
    InvalidAction { action: Vec<f64>, reason: String },
    #[error("simulation became unstable at step {step}: {detail}")]
    Unstable { step: u32, detail: String },
    #[error("goal predicate {predicate} cannot be evaluated: {detail}")]
    Predicate { predicate: String, detail: String },
    #[error("no headless OpenGL: {detail}; {hint}")]
    NoGl { detail: String, hint: String },
    #[error("camera {name:?} is not in this scene; its cameras are: {available}")]
    UnknownCamera { name: String, available: String },
    #[error("render size {width}x{height} is not supported: {reason}")]
    RenderSize { width: u32, height: u32, reason: String },
    #[error("{0}")]
    Other(String),
}
