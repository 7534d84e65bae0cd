//! Camera frames, rendered exactly as the reference renders them.
//!
//! The reference (robosuite 1.4's `MjRenderContextOffscreen`) renders with MuJoCo's own renderer:
//! `mjv_updateScene` over all categories with default `mjvOption` except that collision geoms
//! (group 0) are hidden, a scene of at most 1000 geoms,
//! `mjr_render` into the offscreen buffer and `mjr_readPixels`. [`SceneRenderer`] does the same
//! calls on the same library, so on the same GL stack the pixels are identical.
//!
//! # Orientation: three conventions, named by [`Orientation`]
//! - [`Orientation::Reference`]: what `mjr_readPixels` and the reference env return
//!   (`obs["agentview_image"]`, robosuite's `IMAGE_CONVENTION = "opengl"`): row 0 is the **bottom**
//!   of the picture, so it looks upside down when saved as-is.
//! - [`Orientation::Upright`]: what a person should see: `reference[::-1]` (rows reversed).
//! - [`Orientation::Policy`]: what the published OpenVLA / openpi LIBERO loops feed a policy:
//!   `reference[::-1, ::-1]`, a 180° rotation of the reference array (equivalently, the upright
//!   picture mirrored left-right). Policies were trained on images stored this way.
//!
//! # Look
//! Policies were trained and published on MuJoCo ≤ 3.2.3. From 3.3.3 MuJoCo honours the sRGB tag
//! of PNG textures, which makes libero_object's floor far darker (LIBERO issue #88). [`Look`]
//! chooses between the published stack's look (the default: every texture treated as linear, as
//! 3.2.3 did) and the look of the 3.3.7 library as it is. [`Quality::Preview`] drops shadows,
//! reflections and multisampling for fast pictures; it is never the default and never what a
//! policy should see.

use crate::SimError;
use crate::gl::GlContext;
use mujoco_rs::mujoco_c as c;
use mujoco_rs::prelude::MjModel;
use std::cell::{Cell, RefCell, UnsafeCell};
use std::collections::HashMap;
use std::ffi::CString;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::rc::{Rc, Weak};

/// The image size the published evaluations render at.
pub const DEFAULT_SIZE: u32 = 256;
/// robosuite's scene capacity; geoms beyond it would be dropped, as in the reference.
const MAX_GEOM: i32 = 1000;
/// robosuite's font scale (only matters for text overlays).
const FONT_SCALE: i32 = c::mjtFontScale::mjFONTSCALE_150 as i32;

/// Texture colour semantics, i.e. which MuJoCo's pictures these are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Look {
    /// MuJoCo 3.2.3, the published evaluations' stack: texture data used as linear colour, whatever
    /// the PNG says (3.2.3 had no colour spaces). Forces `tex_colorspace = linear`.
    #[default]
    Mujoco323,
    /// The linked MuJoCo 3.3.7 as it is: PNGs tagged sRGB are decoded as sRGB (darker).
    Mujoco337,
}

impl Look {
    pub fn name(self) -> &'static str {
        match self {
            Look::Mujoco323 => "mujoco-3.2.3",
            Look::Mujoco337 => "mujoco-3.3.7",
        }
    }

    /// Set the model's texture colour spaces; must happen before a render context uploads them.
    /// [`Look::Mujoco337`] leaves the model as compiled ([`LiberoEnv::renderer`](crate::env::LiberoEnv::renderer)
    /// restores the compiled colour spaces first).
    pub fn apply(self, model: &mut MjModel) {
        if self == Look::Mujoco337 {
            return;
        }
        let m = unsafe { model.ffi_mut() };
        for i in 0..m.ntex as usize {
            unsafe { *m.tex_colorspace.add(i) = c::mjtColorSpace::mjCOLORSPACE_LINEAR as i32 };
        }
    }
}

impl std::str::FromStr for Look {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "mujoco-3.2.3" | "published" => Ok(Look::Mujoco323),
            "mujoco-3.3.7" => Ok(Look::Mujoco337),
            other => Err(format!("unknown look {other:?}; use mujoco-3.2.3 (the published stack) or mujoco-3.3.7")),
        }
    }
}

/// Render quality. Only [`Quality::Reference`] is what the reference (and a policy) sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Quality {
    /// The scene's own settings: shadows, reflections, 4× multisampling (robosuite's defaults).
    #[default]
    Reference,
    /// No shadows, reflections or multisampling: ~10× faster on a CPU, for previews only.
    Preview,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Orientation {
    Reference,
    Upright,
    Policy,
}

/// An RGB frame, 3 bytes per pixel, rows in the order its [`Orientation`] says.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
    pub orientation: Orientation,
}

impl Frame {
    /// The picture as a person sees it (rows reversed from the reference order).
    pub fn upright(&self) -> Frame {
        match self.orientation {
            Orientation::Upright => self.clone(),
            Orientation::Reference => Frame { rgb: self.rows_reversed(), orientation: Orientation::Upright, ..*self },
            Orientation::Policy => Frame { rgb: self.mirrored(), orientation: Orientation::Upright, ..*self },
        }
    }

    /// The array OpenVLA / openpi feed a policy: the reference array rotated by 180°.
    pub fn policy_view(&self) -> Frame {
        let reference = self.reference();
        let mut rgb = reference.rgb;
        let px: &mut [[u8; 3]] = bytemuck_pixels(&mut rgb);
        px.reverse();
        Frame { rgb, orientation: Orientation::Policy, ..*self }
    }

    /// Back to the reference order (what the reference env returns).
    pub fn reference(&self) -> Frame {
        match self.orientation {
            Orientation::Reference => self.clone(),
            Orientation::Upright => Frame { rgb: self.rows_reversed(), orientation: Orientation::Reference, ..*self },
            Orientation::Policy => {
                let mut rgb = self.rgb.clone();
                bytemuck_pixels(&mut rgb).reverse();
                Frame { rgb, orientation: Orientation::Reference, ..*self }
            }
        }
    }

    fn rows_reversed(&self) -> Vec<u8> {
        let row = self.width as usize * 3;
        self.rgb.chunks_exact(row).rev().flatten().copied().collect()
    }

    fn mirrored(&self) -> Vec<u8> {
        let row = self.width as usize * 3;
        let mut out = Vec::with_capacity(self.rgb.len());
        for r in self.rgb.chunks_exact(row) {
            out.extend(r.chunks_exact(3).rev().flatten());
        }
        out
    }

    /// Peak signal-to-noise ratio against another frame of the same size and orientation, in dB
    /// (`f64::INFINITY` when identical).
    pub fn psnr(&self, other: &Frame) -> f64 {
        assert_eq!((self.width, self.height), (other.width, other.height), "frame sizes differ");
        assert_eq!(self.orientation, other.orientation, "frame orientations differ");
        let se: f64 = self.rgb.iter().zip(&other.rgb).map(|(&a, &b)| (a as f64 - b as f64).powi(2)).sum();
        let mse = se / self.rgb.len() as f64;
        if mse == 0.0 { f64::INFINITY } else { 10.0 * (255.0f64 * 255.0 / mse).log10() }
    }

    pub fn mean_brightness(&self) -> f64 {
        self.rgb.iter().map(|&v| v as f64).sum::<f64>() / self.rgb.len() as f64
    }
}

fn bytemuck_pixels(rgb: &mut [u8]) -> &mut [[u8; 3]] {
    assert_eq!(rgb.len() % 3, 0);
    // SAFETY: [u8; 3] has alignment 1 and no padding.
    unsafe { std::slice::from_raw_parts_mut(rgb.as_mut_ptr().cast::<[u8; 3]>(), rgb.len() / 3) }
}

/// A rectangle of the offscreen buffer, in pixels from the bottom-left (OpenGL's convention).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rect {
    pub left: u32,
    pub bottom: u32,
    pub width: u32,
    pub height: u32,
}

impl Rect {
    pub fn new(left: u32, bottom: u32, width: u32, height: u32) -> Self {
        Rect { left, bottom, width, height }
    }
    fn ffi(self) -> c::mjrRect {
        c::mjrRect {
            left: self.left as i32,
            bottom: self.bottom as i32,
            width: self.width as i32,
            height: self.height as i32,
        }
    }
}

/// Render settings fixed when a [`SceneRenderer`] is made.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RenderOptions {
    pub look: Look,
    pub quality: Quality,
    /// The largest picture (or panel of pictures) that will be read back; 0 keeps the model's
    /// offscreen size (640×480 in LIBERO scenes), which is what the reference uses.
    pub max_width: u32,
    pub max_height: u32,
}

/// MuJoCo's render context (`mjrContext`: a model's meshes and textures uploaded, fonts, the
/// offscreen buffer) on one GL context, shared by the [`SceneRenderer`]s of that GL context whose
/// models upload the same ([`upload_key`]).
///
/// Why shared: with one GL thread for all of a process's workers (`crate::gl_thread`), each
/// worker's renderer uploaded its task's scene again, one upload after another on that thread: on
/// two H100s, 64 workers' first renders of an episode waited 8.4 s on average, and the GPU with the
/// renders held 59 GB against 24.5 on the other, which had the same model replica and no renders
/// (`data/benchmarks/gpu-two-h100-one-gl-thread-2026-11-27`). Sharing is safe
/// because a render only reads the context: what an episode changes (lights, colours, camera
/// poses, bodies) reaches the picture through the renderer's own `mjvScene`, and renders of one
/// GL context run one at a time, each binding the buffer, drawing and reading back in turn.
struct RenderContext {
    con: UnsafeCell<c::mjrContext>,
    /// The renderer that drew into the shared buffer last ([`SceneRenderer::id`]): a renderer
    /// reads back only what it drew itself.
    last_drawer: Cell<usize>,
    // Dropped after `con` is freed (`Drop`): MuJoCo's context needs the GL context alive and current.
    _gl: Rc<GlContext>,
}

impl Drop for RenderContext {
    fn drop(&mut self) {
        unsafe { c::mjr_freeContext(self.con.get()) };
    }
}

thread_local! {
    /// The render contexts made on this thread, by (GL context, [`UploadKey`]); an entry whose
    /// renderers are all gone no longer upgrades and is replaced.
    static UPLOADED: RefCell<HashMap<(*const GlContext, u64), Weak<RenderContext>>> = RefCell::new(HashMap::new());
}

/// What a [`SceneRenderer`] would upload of a model, hashed ([`upload_key`]): renderers with equal
/// keys on one GL context share one upload. `None` for a model whose upload is never shared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UploadKey(Option<u64>);

/// `model` prepared for `options` (the look's texture colour spaces, the buffer size and samples;
/// what [`SceneRenderer::new`] does first) and [`UploadKey`] of it.
///
/// Everything `mjr_makeContext` (MuJoCo 3.3.7, `render_context.c`) reads from the model is hashed:
/// textures with their colour spaces; meshes; height fields; the materials' texture ids, uniform
/// flags and repeats (the context keeps its own copy); the geoms' types, sizes and materials (the
/// planes' display lists); the buffer's size and samples, shadow, fog and haze settings and the
/// built-in shapes' resolution. Models with skins get `None`: their skin buffers are per model.
///
/// Why a function of its own: the hash reads every texture (150–300 MB in LIBERO's scenes,
/// 60–90 ms), so callers that render on a shared GL thread compute it on their own thread first and
/// hand it to [`SceneRenderer::with_key`], keeping the GL thread for GL work.
pub fn upload_key(model: &mut MjModel, options: RenderOptions) -> UploadKey {
    prepare(model, options);
    let m = model.ffi();
    if m.nskin > 0 {
        return UploadKey(None);
    }
    fn bytes<T: Copy>(xs: &[T]) -> &[u8] {
        // SAFETY: plain numbers and arrays of them (no padding), read as the bytes they are
        unsafe { std::slice::from_raw_parts(xs.as_ptr().cast(), std::mem::size_of_val(xs)) }
    }
    let mut h = DefaultHasher::new();
    (m.ntex, m.nmesh, m.nhfield, m.nmat, m.ngeom).hash(&mut h);
    model.tex_type().iter().map(|&t| t as i32).collect::<Vec<_>>().hash(&mut h);
    model.tex_colorspace().iter().map(|&t| t as i32).collect::<Vec<_>>().hash(&mut h);
    (model.tex_height(), model.tex_width(), model.tex_nchannel(), model.tex_adr(), model.tex_data()).hash(&mut h);
    (model.mesh_vertadr(), model.mesh_vertnum(), model.mesh_faceadr(), model.mesh_facenum()).hash(&mut h);
    (model.mesh_normaladr(), model.mesh_normalnum(), model.mesh_texcoordadr(), model.mesh_texcoordnum()).hash(&mut h);
    (bytes(model.mesh_face()), bytes(model.mesh_facenormal()), bytes(model.mesh_facetexcoord())).hash(&mut h);
    (model.mesh_graphadr(), model.mesh_graph()).hash(&mut h);
    (bytes(model.mesh_vert()), bytes(model.mesh_normal()), bytes(model.mesh_texcoord())).hash(&mut h);
    (model.hfield_nrow(), model.hfield_ncol(), model.hfield_adr()).hash(&mut h);
    (bytes(model.hfield_data()), bytes(model.hfield_size())).hash(&mut h);
    (bytes(model.mat_texid()), bytes(model.mat_texuniform()), bytes(model.mat_texrepeat())).hash(&mut h);
    model.geom_type().iter().map(|&t| t as i32).collect::<Vec<_>>().hash(&mut h);
    (bytes(model.geom_size()), model.geom_matid()).hash(&mut h);
    let (g, q, map, rgba) = (&m.vis.global, &m.vis.quality, &m.vis.map, &m.vis.rgba);
    (g.offwidth, g.offheight, g.linewidth.to_bits(), q.offsamples, q.shadowsize).hash(&mut h);
    (q.numslices, q.numstacks, q.numquads).hash(&mut h);
    let maps = [map.fogstart, map.fogend, map.shadowclip, map.shadowscale, map.znear, map.zfar, map.haze];
    (bytes(&maps), bytes(&rgba.fog), bytes(&rgba.haze), m.stat.extent.to_bits()).hash(&mut h);
    UploadKey(Some(h.finish()))
}

/// What [`SceneRenderer::new`] sets in `model` before it renders it: the look's texture colour
/// spaces, samples for preview quality, a buffer at least as large as asked for.
fn prepare(model: &mut MjModel, options: RenderOptions) {
    options.look.apply(model);
    let m = unsafe { model.ffi_mut() };
    if options.quality == Quality::Preview {
        m.vis.quality.offsamples = 0;
    }
    m.vis.global.offwidth = m.vis.global.offwidth.max(options.max_width as i32);
    m.vis.global.offheight = m.vis.global.offheight.max(options.max_height as i32);
}

/// Scene state for one compiled model over a (possibly shared) [`RenderContext`] on this thread's
/// GL context.
///
/// The first renderer of a scene on a GL context uploads its meshes and textures (~0.5–1 s on
/// llvmpipe); later ones of the same scene on that GL context share the upload.
pub struct SceneRenderer {
    scn: Box<c::mjvScene>,
    opt: Box<c::mjvOption>,
    pert: Box<c::mjvPerturb>,
    cam: Box<c::mjvCamera>,
    cameras: Vec<String>,
    options: RenderOptions,
    buffer: (u32, u32),
    // Last: the scene is freed (`Drop`) before the render context may be.
    con: Rc<RenderContext>,
}

impl SceneRenderer {
    /// Apply the look to `model` (texture colour spaces) and render it on `gl`: on the render
    /// context of an earlier renderer of the same scene on `gl` while one lives, else on a new one
    /// with the model uploaded. Hashes the model on this thread ([`upload_key`]).
    pub fn new(gl: Rc<GlContext>, model: &mut MjModel, options: RenderOptions) -> Result<Self, SimError> {
        let key = upload_key(model, options);
        Self::with_key(gl, model, options, key)
    }

    /// [`SceneRenderer::new`] with `key`, [`upload_key`] of `model` and `options`, computed before.
    pub fn with_key(
        gl: Rc<GlContext>,
        model: &mut MjModel,
        options: RenderOptions,
        key: UploadKey,
    ) -> Result<Self, SimError> {
        prepare(model, options);
        let m = model.ffi();
        let buffer = (m.vis.global.offwidth as u32, m.vis.global.offheight as u32);
        let cameras = (0..m.ncam).map(|i| name_of(model, c::mjtObj::mjOBJ_CAMERA, i)).collect();
        let key = key.0.map(|k| (Rc::as_ptr(&gl), k));
        let shared = key.and_then(|key| UPLOADED.with(|u| u.borrow().get(&key).and_then(Weak::upgrade)));
        let con = match shared {
            Some(con) => con,
            None => {
                let con = Rc::new(Self::upload(gl, model)?);
                if let Some(key) = key {
                    UPLOADED.with(|u| {
                        let mut u = u.borrow_mut();
                        u.retain(|_, weak| weak.strong_count() > 0);
                        u.insert(key, Rc::downgrade(&con));
                    });
                }
                con
            }
        };
        let m = model.ffi();
        // SAFETY: zeroed structs are what MuJoCo's default functions expect to fill in.
        unsafe {
            let mut scn: Box<c::mjvScene> = Box::new(std::mem::zeroed());
            c::mjv_defaultScene(&mut *scn);
            c::mjv_makeScene(m, &mut *scn, MAX_GEOM);
            if options.quality == Quality::Preview {
                scn.flags[c::mjtRndFlag::mjRND_SHADOW as usize] = 0;
                scn.flags[c::mjtRndFlag::mjRND_REFLECTION as usize] = 0;
            }
            let mut opt: Box<c::mjvOption> = Box::new(std::mem::zeroed());
            c::mjv_defaultOption(&mut *opt);
            // robosuite's `_reset_internal` (environments/base.py:297): collision meshes (group 0)
            // hidden (`render_collision_mesh=False`), visual meshes (group 1) shown.
            opt.geomgroup[0] = 0;
            opt.geomgroup[1] = 1;
            let mut pert: Box<c::mjvPerturb> = Box::new(std::mem::zeroed());
            c::mjv_defaultPerturb(&mut *pert);
            pert.active = 0;
            pert.select = 0;
            pert.skinselect = -1;
            let mut cam: Box<c::mjvCamera> = Box::new(std::mem::zeroed());
            c::mjv_defaultCamera(&mut *cam);
            Ok(SceneRenderer { scn, opt, pert, cam, cameras, options, buffer, con })
        }
    }

    /// A new render context on `gl` with `model`'s meshes and textures uploaded.
    fn upload(gl: Rc<GlContext>, model: &MjModel) -> Result<RenderContext, SimError> {
        // SAFETY: a zeroed context is what `mjr_defaultContext` expects to fill in.
        let context =
            RenderContext { con: UnsafeCell::new(unsafe { std::mem::zeroed() }), last_drawer: Cell::new(0), _gl: gl };
        unsafe {
            c::mjr_defaultContext(context.con.get());
            c::mjr_makeContext(model.ffi(), context.con.get(), FONT_SCALE);
            c::mjr_setBuffer(c::mjtFramebuffer::mjFB_OFFSCREEN as i32, context.con.get());
            if (*context.con.get()).currentBuffer != c::mjtFramebuffer::mjFB_OFFSCREEN as i32 {
                return Err(SimError::NoGl {
                    detail: "MuJoCo could not make its offscreen framebuffer".into(),
                    hint: "check that the GL driver supports framebuffer objects (Mesa ≥ 20 or an NVIDIA driver)"
                        .into(),
                });
            }
        }
        Ok(context)
    }

    /// This renderer, among those alive: the address of its scene.
    fn id(&self) -> usize {
        &*self.scn as *const c::mjvScene as usize
    }

    /// Whether `self` and `other` render on one render context (one upload of their scene).
    pub fn shares_upload_with(&self, other: &SceneRenderer) -> bool {
        Rc::ptr_eq(&self.con, &other.con)
    }

    pub fn options(&self) -> RenderOptions {
        self.options
    }

    /// Show or hide the geoms of `group` (0–5). The renderer starts with robosuite's choice
    /// (group 0, the collision meshes, hidden); dm_control's envs (ALOHA-sim) render with
    /// MuJoCo's default `mjvOption`, groups 0–2 shown.
    pub fn set_geom_group(&mut self, group: usize, shown: bool) {
        self.opt.geomgroup[group] = shown as u8;
    }

    /// The scene's camera names, in model order.
    pub fn cameras(&self) -> &[String] {
        &self.cameras
    }

    /// The index of a camera by name; an unknown name lists the ones that exist.
    pub fn camera_id(&self, name: &str) -> Result<usize, SimError> {
        self.cameras
            .iter()
            .position(|c| c == name)
            .ok_or_else(|| SimError::UnknownCamera { name: name.into(), available: self.cameras.join(", ") })
    }

    fn check_rect(&self, rect: Rect) -> Result<(), SimError> {
        let (w, h) = self.buffer;
        if rect.width == 0 || rect.height == 0 || rect.left + rect.width > w || rect.bottom + rect.height > h {
            return Err(SimError::RenderSize {
                width: rect.width,
                height: rect.height,
                reason: format!(
                    "the region at ({}, {}) does not fit the {w}x{h} offscreen buffer; ask for a larger \
                     max_width/max_height in RenderOptions",
                    rect.left, rect.bottom
                ),
            });
        }
        Ok(())
    }

    /// Draw one camera's view of the current state into `rect` of the offscreen buffer.
    ///
    /// # Safety
    /// `model`/`data` must be the model this renderer was made from and a live data of it.
    pub(crate) unsafe fn draw_camera(
        &mut self,
        model: &c::mjModel,
        data: *mut c::mjData,
        camera: usize,
        rect: Rect,
    ) -> Result<(), SimError> {
        self.check_rect(rect)?;
        self.con.last_drawer.set(self.id());
        self.cam.type_ = c::mjtCamera::mjCAMERA_FIXED as i32;
        self.cam.fixedcamid = camera as i32;
        unsafe {
            self.bind_buffer();
            c::mjv_updateScene(
                model,
                data,
                &*self.opt,
                &*self.pert,
                &mut *self.cam,
                c::mjtCatBit::mjCAT_ALL as i32,
                &mut *self.scn,
            );
            c::mjr_render(rect.ffi(), &mut *self.scn, self.con.con.get());
        }
        Ok(())
    }

    /// Fill `rect` with a colour and write `text` in it (top-left, MuJoCo's built-in font; lines
    /// split at `\n`).
    pub fn draw_text(&mut self, rect: Rect, text: &str, background: [f32; 3]) -> Result<(), SimError> {
        self.check_rect(rect)?;
        self.con.last_drawer.set(self.id());
        let text = CString::new(text.replace('\0', " ")).expect("no NUL left");
        let empty = CString::default();
        unsafe {
            self.bind_buffer();
            c::mjr_rectangle(rect.ffi(), background[0], background[1], background[2], 1.0);
            c::mjr_overlay(
                c::mjtFont::mjFONT_NORMAL as i32,
                c::mjtGridPos::mjGRID_TOPLEFT as i32,
                rect.ffi(),
                text.as_ptr(),
                empty.as_ptr(),
                self.con.con.get(),
            );
        }
        Ok(())
    }

    /// Make this renderer's offscreen buffer the one GL draws into and reads from.
    ///
    /// Why every time: the GL binding belongs to the GL context, not to MuJoCo's render context.
    /// Where several renderers share one GL context (`crate::gl_thread`'s shared GL thread for all
    /// of a process's workers), a renderer of another scene made or used in between leaves its own
    /// buffer bound, and a draw without this went into that renderer's buffer: the frame read back
    /// was stale (`tests/render.rs`, three workers on one GL thread, agentview frames differing
    /// entirely). Renderers of one scene on one GL context share the buffer with the upload
    /// ([`RenderContext`]): what one draws is read back before another of them draws, since each
    /// GL-thread job draws and reads in one go.
    fn bind_buffer(&mut self) {
        unsafe { c::mjr_setBuffer(c::mjtFramebuffer::mjFB_OFFSCREEN as i32, self.con.con.get()) };
    }

    /// Read `rect` of the offscreen buffer back, in the reference orientation.
    pub fn read(&mut self, rect: Rect) -> Result<Frame, SimError> {
        self.check_rect(rect)?;
        if self.con.last_drawer.get() != self.id() {
            return Err(SimError::Other(
                "another renderer of this scene drew into the buffer this renderer shares with it since this one \
                 last drew: read each renderer's picture before another one draws"
                    .into(),
            ));
        }
        let mut rgb = vec![0u8; rect.width as usize * rect.height as usize * 3];
        self.bind_buffer();
        unsafe { c::mjr_readPixels(rgb.as_mut_ptr(), std::ptr::null_mut(), rect.ffi(), self.con.con.get()) };
        Ok(Frame { width: rect.width, height: rect.height, rgb, orientation: Orientation::Reference })
    }
}

impl Drop for SceneRenderer {
    fn drop(&mut self) {
        unsafe { c::mjv_freeScene(&mut *self.scn) };
    }
}

fn name_of(model: &MjModel, kind: c::mjtObj, id: i32) -> String {
    let p = unsafe { c::mj_id2name(model.ffi(), kind as i32, id) };
    if p.is_null() { format!("#{id}") } else { unsafe { std::ffi::CStr::from_ptr(p) }.to_string_lossy().into_owned() }
}
