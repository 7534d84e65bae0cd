//! # libero-schema
//!
//! The shared vocabulary of the pipeline, with no behaviour: the canonical LIBERO protocol
//! constants (one module, each value citing its source), the suite names, the benchmarks
//! ([`Benchmark`]: LIBERO, ALOHA-sim), the Arrow schemas of
//! the stored tables (spec, steps, episodes, run manifest; [`tables`]), the run manifest
//! ([`manifest`]) with its real-time setting ([`real_time`]), and the format versions of everything written to disk.
//!
//! Every other crate depends on this one; it depends on nothing of ours.

pub mod benchmark;
pub mod bundle_format;
pub mod manifest;
pub mod protocol;
pub mod real_time;
pub mod tables;
pub mod tables_reference;

pub use benchmark::Benchmark;
pub use manifest::RunManifest;
pub use protocol::{BaseSuite, EvalProtocol, InstructionSource, Perturbation, Suite};
