//! Version of the on-disk task bundle layout written by `scripts/reference/build_bundles.py`.
//!
//! Bump it whenever the exporter changes what it writes; loaders refuse other versions with an
//! error that says how to rebuild.

/// The bundle format this build reads. Must equal `BUNDLE_FORMAT_VERSION` in the exporter.
pub const BUNDLE_FORMAT_VERSION: u32 = 1;

/// The MuJoCo version bundles are built and checked with (the oracle venv and mujoco-rs agree).
pub const MUJOCO_VERSION: &str = "3.3.7";
