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
use libero_sim::gl::GlContext;
use libero_sim::render::{Look, Quality, RenderOptions, SceneRenderer};
use std::rc::Rc;

/// The reference env's camera names: the third-person view and the wrist view.
pub const AGENTVIEW: &str = "agentview";
pub const WRIST: &str = "robot0_eye_in_hand";

thread_local! {
    /// One headless GL context per rollout worker thread, made on first use.
    static GL: std::cell::OnceCell<Result<Rc<GlContext>, String>> = const { std::cell::OnceCell::new() };
}

/// The rollout worker thread's GL context (made on first use, shared by LIBERO's and ALOHA-sim's
/// policy cameras).
pub fn worker_gl() -> Result<Rc<GlContext>, SimError> {
    GL.with(|cell| cell.get_or_init(|| GlContext::new().map(Rc::new).map_err(|e| e.to_string())).clone())
        .map_err(SimError::Other)
}

/// A renderer for one episode's env, reading both cameras on request.
pub struct PolicyCameras {
    renderer: SceneRenderer,
    size: u32,
}

impl PolicyCameras {
    /// Set up rendering of `env`'s scene at `size`×`size` (uploads its meshes and textures once).
    pub fn new(env: &mut LiberoEnv, size: u32) -> Result<Self, SimError> {
        let gl = worker_gl()?;
        let options =
            RenderOptions { look: Look::Mujoco323, quality: Quality::Reference, max_width: size, max_height: size };
        let renderer = env.renderer(gl, options)?;
        Ok(PolicyCameras { renderer, size })
    }

    pub fn size(&self) -> u32 {
        self.size
    }

    /// The cameras' views of the env's current state: agentview, and the wrist camera when
    /// `wrist` (else an empty image).
    pub fn capture(&mut self, env: &mut LiberoEnv, wrist: bool) -> Result<CameraImages, SimError> {
        let mut grab = |camera: &str| -> Result<CameraImage, SimError> {
            let f = env.render(&mut self.renderer, camera, self.size, self.size)?;
            Ok(CameraImage { width: f.width, height: f.height, rgb: f.rgb })
        };
        let agentview = grab(AGENTVIEW)?;
        let wrist = if wrist { grab(WRIST)? } else { CameraImage::default() };
        Ok(CameraImages { agentview, wrist })
    }
}
