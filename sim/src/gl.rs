//! A headless OpenGL context through EGL: Mesa's software renderer (llvmpipe) on a CPU machine,
//! the NVIDIA driver on a GPU machine. One context per worker thread.
//!
//! The context is made the way robosuite's `EGLGLContext` makes it (the reference's renderer): the
//! EGL *device* platform, a pbuffer-capable RGBA8 config with a 24-bit depth and 8-bit stencil
//! buffer, the desktop OpenGL API, and no surface (MuJoCo renders into its own framebuffer).
//! `libEGL.so.1` is loaded at run time, so a machine without it still runs physics-only work and
//! gets one clear error only when it asks for pixels.

use crate::SimError;
use khronos_egl as egl;
use std::ffi::{CStr, c_void};
use std::sync::OnceLock;

type Egl = egl::DynamicInstance<egl::EGL1_5>;

const PLATFORM_DEVICE_EXT: egl::Enum = 0x313F;
const PLATFORM_SURFACELESS_MESA: egl::Enum = 0x31DD;
const EXTENSIONS: egl::Int = 0x3055;
const DRM_DEVICE_FILE_EXT: egl::Int = 0x3233;

/// The Debian packages that provide headless EGL on a CPU machine.
pub const EGL_PACKAGES: &str = "libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1";

/// The process-wide EGL library (loading it twice would be harmless but slow).
fn library() -> Result<&'static Egl, SimError> {
    static LIB: OnceLock<Result<Egl, String>> = OnceLock::new();
    LIB.get_or_init(|| unsafe { Egl::load_required() }.map_err(|e| e.to_string()))
        .as_ref()
        .map_err(|e| no_gl(format!("cannot load libEGL.so.1 ({e})")))
}

fn no_gl(detail: String) -> SimError {
    SimError::NoGl {
        detail,
        hint: format!(
            "install headless EGL: `apt-get install {EGL_PACKAGES}` on Debian/Ubuntu (./setup.sh does it as root), \
             or the NVIDIA driver's EGL library on a GPU machine"
        ),
    }
}

/// Which EGL device renders: chosen by `MUJOCO_EGL_DEVICE_ID` (the variable robosuite and MuJoCo
/// read), else the first hardware device, else Mesa's software device.
#[derive(Debug, Clone)]
pub struct DeviceInfo {
    pub index: usize,
    pub software: bool,
    /// The DRM node of a hardware device, when the driver names it.
    pub drm_file: Option<String>,
}

/// An EGL context, current on the thread that made it. Not `Send`: GL contexts are per thread.
pub struct GlContext {
    display: egl::Display,
    context: egl::Context,
    device: Option<DeviceInfo>,
    vendor: String,
    _not_send: std::marker::PhantomData<*const ()>,
}

impl GlContext {
    /// Make a context and make it current on this thread.
    pub fn new() -> Result<Self, SimError> {
        let lib = library()?;
        let (display, device) = open_display(lib)?;
        lib.initialize(display).map_err(|e| no_gl(format!("eglInitialize failed: {e}")))?;
        lib.bind_api(egl::OPENGL_API).map_err(|e| no_gl(format!("eglBindAPI(OpenGL) failed: {e}")))?;
        let attributes = [
            egl::RED_SIZE,
            8,
            egl::GREEN_SIZE,
            8,
            egl::BLUE_SIZE,
            8,
            egl::ALPHA_SIZE,
            8,
            egl::DEPTH_SIZE,
            24,
            egl::STENCIL_SIZE,
            8,
            egl::COLOR_BUFFER_TYPE,
            egl::RGB_BUFFER,
            egl::SURFACE_TYPE,
            egl::PBUFFER_BIT,
            egl::RENDERABLE_TYPE,
            egl::OPENGL_BIT,
            egl::NONE,
        ];
        let config = lib
            .choose_first_config(display, &attributes)
            .map_err(|e| no_gl(format!("eglChooseConfig failed: {e}")))?
            .ok_or_else(|| no_gl("no EGL config with RGBA8, depth 24, stencil 8 and desktop OpenGL".into()))?;
        let context = lib
            .create_context(display, config, None, &[egl::NONE])
            .map_err(|e| no_gl(format!("eglCreateContext failed: {e}")))?;
        lib.make_current(display, None, None, Some(context))
            .map_err(|e| no_gl(format!("eglMakeCurrent (surfaceless) failed: {e}")))?;
        let vendor = lib.query_string(Some(display), egl::VENDOR).map(|s| s.to_string_lossy().into_owned());
        Ok(GlContext {
            display,
            context,
            device,
            vendor: vendor.unwrap_or_default(),
            _not_send: std::marker::PhantomData,
        })
    }

    /// "Mesa Project" (CPU, llvmpipe) or "NVIDIA" (GPU), as EGL reports it.
    pub fn vendor(&self) -> &str {
        &self.vendor
    }

    pub fn device(&self) -> Option<&DeviceInfo> {
        self.device.as_ref()
    }
}

impl Drop for GlContext {
    fn drop(&mut self) {
        // The display is shared by every context of the process (EGL returns the same handle per
        // device), so it is never terminated here: that would pull the rug from other threads.
        if let Ok(lib) = library() {
            let _ = lib.make_current(self.display, None, None, None);
            let _ = lib.destroy_context(self.display, self.context);
        }
    }
}

type QueryDevices = unsafe extern "system" fn(egl::Int, *mut *mut c_void, *mut egl::Int) -> egl::Boolean;
type QueryDeviceString = unsafe extern "system" fn(*mut c_void, egl::Int) -> *const std::ffi::c_char;

/// The display of the chosen EGL device; the Mesa surfaceless platform when devices cannot be
/// enumerated.
fn open_display(lib: &Egl) -> Result<(egl::Display, Option<DeviceInfo>), SimError> {
    let query_devices = lib.get_proc_address("eglQueryDevicesEXT");
    let query_string = lib.get_proc_address("eglQueryDeviceStringEXT");
    if let (Some(qd), Some(qs)) = (query_devices, query_string) {
        let qd: QueryDevices = unsafe { std::mem::transmute(qd) };
        let qs: QueryDeviceString = unsafe { std::mem::transmute(qs) };
        let mut devices = [std::ptr::null_mut::<c_void>(); 16];
        let mut n: egl::Int = 0;
        if unsafe { qd(devices.len() as egl::Int, devices.as_mut_ptr(), &mut n) } == egl::TRUE && n > 0 {
            let infos: Vec<DeviceInfo> = (0..n as usize)
                .map(|index| {
                    let text = |what| {
                        let p = unsafe { qs(devices[index], what) };
                        (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
                    };
                    let software = text(EXTENSIONS).is_some_and(|e| e.contains("EGL_MESA_device_software"));
                    DeviceInfo { index, software, drm_file: text(DRM_DEVICE_FILE_EXT) }
                })
                .collect();
            let chosen = choose_device(&infos)?;
            let display =
                unsafe { lib.get_platform_display(PLATFORM_DEVICE_EXT, devices[chosen.index], &[egl::ATTRIB_NONE]) }
                    .map_err(|e| no_gl(format!("eglGetPlatformDisplay(device {}) failed: {e}", chosen.index)))?;
            return Ok((display, Some(chosen)));
        }
    }
    let display =
        unsafe { lib.get_platform_display(PLATFORM_SURFACELESS_MESA, egl::DEFAULT_DISPLAY, &[egl::ATTRIB_NONE]) }
            .map_err(|e| no_gl(format!("no EGL device and no surfaceless platform ({e})")))?;
    Ok((display, None))
}

fn choose_device(infos: &[DeviceInfo]) -> Result<DeviceInfo, SimError> {
    if let Ok(wanted) = std::env::var("MUJOCO_EGL_DEVICE_ID") {
        let index: usize = wanted.trim().parse().map_err(|_| {
            no_gl(format!("MUJOCO_EGL_DEVICE_ID={wanted:?} is not a device index (0..{})", infos.len()))
        })?;
        return infos
            .get(index)
            .cloned()
            .ok_or_else(|| no_gl(format!("MUJOCO_EGL_DEVICE_ID={index} but EGL lists {} device(s)", infos.len())));
    }
    Ok(infos.iter().find(|d| !d.software).or_else(|| infos.first()).cloned().expect("non-empty device list"))
}
