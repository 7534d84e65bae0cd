//! # libero-udfs
//!
//! The DataFusion functions of the pipeline: `rollout` (runs sim + policy per spec row and writes
//! per-step Parquet), `wilson` / `wilson_lo` / `wilson_hi`, success definitions and failure-mode
//! helpers. The only crate besides `pipeline` that joins `sim` and `policies`.
//!
//! Status: the crate is laid out; its functions land with the dataflow issue.
