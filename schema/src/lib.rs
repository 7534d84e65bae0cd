//! # libero-schema
//!
//! The shared vocabulary of the pipeline, with no behaviour: the canonical LIBERO protocol
//! constants (one module, each value citing its source), the suite names, and the format versions
//! of everything written to disk (task bundles, and later the spec/step/episode/manifest tables).
//!
//! Every other crate depends on this one; it depends on nothing of ours.

pub mod bundle_format;
pub mod protocol;

pub use protocol::Suite;
