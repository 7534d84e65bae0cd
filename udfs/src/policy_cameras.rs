//! Camera images for policies that see (learned VLAs): LIBERO's two cameras rendered after the
//! step the policy is about to answer, at the size the policy asks for, in the reference env's
//! row order (`obs["agentview_image"]`, `obs["robot0_eye_in_hand_image"]`), so that the policy's
//! own preprocessing applies the published loops' 180° rotation exactly as they do.
//!
//! Rendered with the reference's settings and the MuJoCo 3.2.3 look (the published stack): the
//! same pixels the render tests compare with the reference frames.

use libero_policies::{CameraImage, CameraImages};
use libero_sim::SimError;
use libero_sim::env::LiberoEnv;
use libero_sim::gl_thread::{GlThread, OnGlThread};
use libero_sim::render::{Look, Quality, RenderOptions, SceneRenderer};
use std::sync::Arc;

/// The reference env's camera names: the third-person view and the wrist view.
pub const AGENTVIEW: &str = "agentview";
pub const WRIST: &str = "robot0_eye_in_hand";

thread_local! {
    /// The GL thread each rollout worker renders on, chosen on first use.
    static GL: std::cell::OnceCell<Result<Arc<GlThread>, String>> = const { std::cell::OnceCell::new() };
}

/// The rollout worker's GL thread (chosen on first use, shared by LIBERO's and ALOHA-sim's policy
/// cameras): a thread of its own, or the process's shared one ([`GlThread::for_worker`]).
pub fn worker_gl() -> Result<Arc<GlThread>, SimError> {
    GL.with(|cell| cell.get_or_init(|| GlThread::for_worker().map_err(|e| e.to_string())).clone())
        .map_err(SimError::Other)
}

/// A renderer of one env's scene (kept across the episodes of the env's task), reading both
/// cameras on request.
pub struct PolicyCameras {
    renderer: OnGlThread<SceneRenderer>,
    size: u32,
}

impl PolicyCameras {
    /// Set up rendering of `env`'s scene at `size`×`size` (uploads its meshes and textures once).
    pub fn new(env: &mut LiberoEnv, size: u32) -> Result<Self, SimError> {
        let options =
            RenderOptions { look: Look::Mujoco323, quality: Quality::Reference, max_width: size, max_height: size };
        // hashed here, not on a GL thread the other workers may be waiting for
        let key = env.upload_key(options);
        // SAFETY: the env (MuJoCo model and data) is used on the GL thread while this one waits.
        let renderer = unsafe { OnGlThread::make(worker_gl()?, |gl| env.renderer_with_key(gl.clone(), options, key))? };
        Ok(PolicyCameras { renderer, size })
    }

    pub fn size(&self) -> u32 {
        self.size
    }

    /// The cameras' views of the env's current state: agentview, and the wrist camera when
    /// `wrist` (else an empty image), drawn in one call to the GL thread.
    pub fn capture(&mut self, env: &mut LiberoEnv, wrist: bool) -> Result<CameraImages, SimError> {
        let size = self.size;
        // SAFETY: the env and the renderer are used on the GL thread while this one waits.
        unsafe {
            self.renderer.with(|renderer| {
                let mut grab = |camera: &str| -> Result<CameraImage, SimError> {
                    let f = env.render(renderer, camera, size, size)?;
                    Ok(CameraImage { width: f.width, height: f.height, rgb: f.rgb })
                };
                let agentview = grab(AGENTVIEW)?;
                let wrist = if wrist { grab(WRIST)? } else { CameraImage::default() };
                Ok(CameraImages { agentview, wrist })
            })
        }
    }
}
