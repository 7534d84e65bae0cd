//! Version of the on-disk task bundle layout written by `scripts/reference/build_bundles.py`.
//!
//! Bump it whenever the exporter changes what it writes; loaders refuse other versions with an
//! error that says how to rebuild, and a run made on other bundles is refused on resume with the
//! reason from [`format_change`].

/// The bundle format this build reads. Must equal `BUNDLE_FORMAT_VERSION` in the exporter.
pub const BUNDLE_FORMAT_VERSION: u32 = 3;

/// The MuJoCo version bundles are built and checked with (the oracle venv and mujoco-rs agree).
pub const MUJOCO_VERSION: &str = "3.3.7";

/// Why bundles of format `older` give other episodes than this build's: what a user must know
/// before mixing or comparing runs made on them (every change since `older`).
pub fn format_change(older: u32) -> String {
    let reasons: Vec<&str> = (older..BUNDLE_FORMAT_VERSION).map(change_after).collect();
    if reasons.is_empty() { "the bundle format changed".to_string() } else { reasons.join("; and ") }
}

/// What changed from format `version` to the next.
fn change_after(version: u32) -> &'static str {
    match version {
        1 => {
            "format 1 put the fixtures (cabinet, stove, microwave) of libero_spatial task 4 and \
             libero_10 tasks 3, 8 and 9 at other poses than the published loop for every episode \
             but the first (1-2 cm, a few degrees), so ~10% of the canonical episodes ran in a \
             scene the published evaluations never showed; format 2 records the published loop's \
             hard-reset poses, checked at build time"
        }
        2 => {
            "format 2 gave the policy the BDDL (:language ...) text of every task; the published loops \
             give task.language, derived from the BDDL file name, which differs in more than case for \
             most tasks (libero_goal 0: \"open the middle layer of the drawer\" vs \"open the middle \
             drawer of the cabinet\"). Format 3 records both and the run's --instruction picks one"
        }
        _ => "the bundle format changed",
    }
}
