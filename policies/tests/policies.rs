//! The policies crate's integration tests, one module a concern, in one test binary (see
//! `Cargo.toml`: one link of the crate's dependencies instead of one per module).

mod libtorch;
mod oft_parity;
mod openpi_client;
mod openvla_parity;
mod preprocess_parity;
/// The tiny random-weight OpenVLA and OFT checkpoints and their Python reference outputs.
mod tiny_reference;
mod torchscript_policy;
