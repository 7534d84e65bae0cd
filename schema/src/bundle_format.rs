//! Version of the on-disk task bundle layout written by `scripts/reference/build_bundles.py`.
//!
//! Bump it whenever the exporter changes what it writes; loaders refuse other versions with an
//! error that says how to rebuild, and a run made on other bundles is refused on resume with the
//! reason from [`format_change`].

/// The bundle format this build reads. Must equal `BUNDLE_FORMAT_VERSION` in the exporter.
pub const BUNDLE_FORMAT_VERSION: u32 = 2;

/// The MuJoCo version bundles are built and checked with (the oracle venv and mujoco-rs agree).
pub const MUJOCO_VERSION: &str = "3.3.7";

/// Why bundles of format `older` give other episodes than this build's: what a user must know
/// before mixing or comparing runs made on them.
pub fn format_change(older: u32) -> &'static str {
    match older {
        1 => {
            "format 1 put the fixtures (cabinet, stove, microwave) of libero_spatial task 4 and \
             libero_10 tasks 3, 8 and 9 at other poses than the published loop for every episode \
             but the first (1-2 cm, a few degrees), so ~10% of the canonical episodes ran in a \
             scene the published evaluations never showed; format 2 records the published loop's \
             hard-reset poses, checked at build time"
        }
        _ => "the bundle format changed",
    }
}
