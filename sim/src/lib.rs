//! # libero-sim
//!
//! The LIBERO environment on MuJoCo, in Rust, matching the Python reference (hf-libero 0.1.4 on
//! robosuite 1.4.0) step for step. It owns:
//!
//! - [`bundle`]: loading a *task bundle* (scene MJCF, init states, fixture poses per seed and
//!   episode, goal and object metadata), written at set-up by `scripts/reference/build_bundles.py`;
//! - [`bundle_integrity`]: a bundle's files checked against the hashes of its provenance;
//! - [`scene`]: compiling the bundle's scene and applying what the reference changes on the live
//!   model (fixture poses per episode, site colours);
//! - [`osc`] and [`gripper`]: robosuite's OSC_POSE controller and Panda gripper, quirks included;
//! - [`predicates`]: the BDDL goal (On, In, Open, Close, TurnOn, TurnOff, Up) as LIBERO checks it;
//! - [`env`]: the gym-shaped [`env::LiberoEnv`] tying them together at 20 Hz (25 substeps of 2 ms);
//! - [`viewpoint`]: LIBERO-Plus camera viewpoints (the `agentview` pose of a view variant);
//! - [`gl`] and [`render`]: headless EGL contexts and camera frames rendered as the reference renders
//!   them (orientation conventions, the published stack's look, a clearly named preview mode);
//!   [`gl_thread`]: GL contexts on threads of their own that render for the workers (one each, or
//!   one per GPU shared by all);
//! - [`aloha`]: a second benchmark, ALOHA-sim (gym-aloha's bimanual tasks), on the same MuJoCo and
//!   renderer.
//!
//! It knows nothing of policies, Arrow or DataFusion.
//!
//! ```no_run
//! use libero_sim::{bundle::BundleSet, env::LiberoEnv};
//! let set = BundleSet::open("data/bundles")?;
//! let bundle = set.load("libero_spatial".parse().unwrap(), 0)?;
//! let mut env = LiberoEnv::new(&bundle)?;
//! env.reset(0, 7)?;                               // init state 0, env seed 7
//! let out = env.step([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0])?;
//! println!("goal satisfied: {}", out.goal.satisfied);
//! # Ok::<(), libero_sim::SimError>(())
//! ```

pub mod aloha;
pub mod bundle;
pub mod bundle_integrity;
pub mod dark_noise;
pub mod env;
mod error;
pub mod gl;
pub mod gl_thread;
pub mod gripper;
pub mod image_noise;
pub mod npy;
pub mod osc;
pub mod predicates;
pub mod render;
pub mod scene;
pub mod viewpoint;

pub use error::SimError;

/// The MuJoCo library version this build is linked against (e.g. "3.3.7"), as the library
/// itself reports it (`mj_versionString`).
pub fn mujoco_version() -> String {
    let p = unsafe { mujoco_rs::mujoco_c::mj_versionString() };
    unsafe { std::ffi::CStr::from_ptr(p) }.to_string_lossy().into_owned()
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_linked_mujoco_is_the_bundles_version() {
        assert_eq!(super::mujoco_version(), libero_schema::bundle_format::MUJOCO_VERSION);
    }
}
