//! # libero-policies
//!
//! The `Policy` seam between the rollout and the models it evaluates, and its implementations
//! (baselines, TorchScript, OpenVLA in-process on tch, an openpi websocket client). It knows
//! nothing of MuJoCo: policies see observations (images, proprio state, the instruction) and
//! return action chunks.
//!
//! Status: the crate is laid out; the seam and policies land with the dataflow and policy issues.
