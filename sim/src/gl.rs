//! A headless OpenGL context through EGL: Mesa's software renderer (llvmpipe) on a CPU machine,
//! the NVIDIA driver on a GPU machine. One context per worker thread; on a machine with several GPUs
//! the contexts go to their EGL devices in turn (`choose_device`).
//!
//! The context is made the way robosuite's `EGLGLContext` makes it (the reference's renderer): the
//! EGL *device* platform, a pbuffer-capable RGBA8 config with a 24-bit depth and 8-bit stencil
//! buffer, the desktop OpenGL API, and no surface (MuJoCo renders into its own framebuffer).
//! `libEGL.so.1` is loaded at run time, so a machine without it still runs physics-only work and
//! gets one clear error only when it asks for pixels.

use crate::SimError;
use khronos_egl as egl;
use std::collections::BTreeSet;
use std::ffi::{CStr, c_void};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};

type Egl = egl::DynamicInstance<egl::EGL1_5>;

const PLATFORM_DEVICE_EXT: egl::Enum = 0x313F;
const PLATFORM_SURFACELESS_MESA: egl::Enum = 0x31DD;
const EXTENSIONS: egl::Int = 0x3055;
const DRM_DEVICE_FILE_EXT: egl::Int = 0x3233;
/// `EGL_NV_device_cuda`: the CUDA device an NVIDIA EGL device is.
const CUDA_DEVICE_NV: egl::Int = 0x323A;

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
/// read), else the hardware devices in turn (one context after another), else Mesa's software device.
#[derive(Debug, Clone)]
pub struct DeviceInfo {
    pub index: usize,
    pub software: bool,
    /// The DRM node of a hardware device, when the driver names it.
    pub drm_file: Option<String>,
    /// The CUDA device it is (NVIDIA's `EGL_NV_device_cuda`, numbered as the CUDA driver numbers
    /// devices without `CUDA_VISIBLE_DEVICES`).
    pub cuda: Option<i64>,
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
    /// Make a context and make it current on this thread, on the device the process's next
    /// context takes ([`next_device`]).
    pub fn new() -> Result<Self, SimError> {
        let device = next_device()?;
        Self::on(device.as_ref())
    }

    /// Make a context on `device` (`None`: Mesa's surfaceless platform, for machines whose EGL
    /// cannot list devices) and make it current on this thread.
    pub fn on(device: Option<&DeviceInfo>) -> Result<Self, SimError> {
        let lib = library()?;
        let display = open_display(lib, device)?;
        let device = device.cloned();
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
        let gl = GlContext {
            display,
            context,
            device,
            vendor: vendor.unwrap_or_default(),
            _not_send: std::marker::PhantomData,
        };
        RENDER_DEVICES.lock().expect("render devices").insert(RenderDevice::of(&gl));
        Ok(gl)
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
type QueryDeviceAttrib = unsafe extern "system" fn(*mut c_void, egl::Int, *mut egl::Attrib) -> egl::Boolean;

/// The EGL devices and what they are, with their handles; `None` when EGL cannot list them.
fn egl_devices(lib: &Egl) -> Option<Vec<(*mut c_void, DeviceInfo)>> {
    let qd: QueryDevices = unsafe { std::mem::transmute(lib.get_proc_address("eglQueryDevicesEXT")?) };
    let qs: QueryDeviceString = unsafe { std::mem::transmute(lib.get_proc_address("eglQueryDeviceStringEXT")?) };
    let query_attrib: Option<QueryDeviceAttrib> =
        lib.get_proc_address("eglQueryDeviceAttribEXT").map(|f| unsafe { std::mem::transmute(f) });
    let mut devices = [std::ptr::null_mut::<c_void>(); 16];
    let mut n: egl::Int = 0;
    if unsafe { qd(devices.len() as egl::Int, devices.as_mut_ptr(), &mut n) } != egl::TRUE || n <= 0 {
        return None;
    }
    let info = |index: usize| {
        let text = |what| {
            let p = unsafe { qs(devices[index], what) };
            (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
        };
        let software = text(EXTENSIONS).is_some_and(|e| e.contains("EGL_MESA_device_software"));
        let cuda = query_attrib.and_then(|qa| {
            let mut value: egl::Attrib = 0;
            (unsafe { qa(devices[index], CUDA_DEVICE_NV, &mut value) } == egl::TRUE).then_some(value as i64)
        });
        DeviceInfo { index, software, drm_file: text(DRM_DEVICE_FILE_EXT), cuda }
    };
    Some((0..n as usize).map(|index| (devices[index], info(index))).collect())
}

/// The EGL devices this machine lists, in EGL's order (what `MUJOCO_EGL_DEVICE_ID` indexes);
/// `None` where EGL cannot list devices (Mesa's surfaceless platform is then used).
pub fn devices() -> Result<Option<Vec<DeviceInfo>>, SimError> {
    Ok(egl_devices(library()?).map(|all| all.into_iter().map(|(_, info)| info).collect()))
}

/// The device the process's next context (or [`crate::gl_thread::GlThread`]) takes: see
/// [`choose_device`]. `None` where EGL cannot list devices (Mesa's surfaceless platform then).
pub fn next_device() -> Result<Option<DeviceInfo>, SimError> {
    let Some(devices) = egl_devices(library()?) else { return Ok(None) };
    let infos: Vec<DeviceInfo> = devices.into_iter().map(|(_, info)| info).collect();
    let wanted = std::env::var("MUJOCO_EGL_DEVICE_ID").ok();
    let nth = CONTEXTS_MADE.fetch_add(1, Ordering::Relaxed);
    let (models, placement) = MODEL_GPUS.lock().expect("model GPUs").clone();
    choose_device(&infos, wanted.as_deref(), nth, &models, placement).map(Some)
}

/// The display of `device`; Mesa's surfaceless platform for `None`.
fn open_display(lib: &Egl, device: Option<&DeviceInfo>) -> Result<egl::Display, SimError> {
    if let Some(device) = device {
        let handle = egl_devices(lib)
            .and_then(|all| all.into_iter().find(|(_, d)| d.index == device.index))
            .map(|(handle, _)| handle)
            .ok_or_else(|| no_gl(format!("EGL no longer lists device {}", device.index)))?;
        return unsafe { lib.get_platform_display(PLATFORM_DEVICE_EXT, handle, &[egl::ATTRIB_NONE]) }
            .map_err(|e| no_gl(format!("eglGetPlatformDisplay(device {}) failed: {e}", device.index)));
    }
    unsafe { lib.get_platform_display(PLATFORM_SURFACELESS_MESA, egl::DEFAULT_DISPLAY, &[egl::ATTRIB_NONE]) }
        .map_err(|e| no_gl(format!("no EGL device and no surfaceless platform ({e})")))
}

/// A device this process's GL contexts rendered on ([`render_devices_used`]).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
pub struct RenderDevice {
    /// EGL's index of the device; `None` on Mesa's surfaceless platform (no device list).
    pub egl_device: Option<usize>,
    /// As EGL reports it: "NVIDIA", "Mesa Project".
    pub vendor: String,
    /// Mesa's software device (llvmpipe): the renders ran on the CPU. Mesa's surfaceless platform
    /// (no device list) counts as software, as `pipeline doctor` and the GL threads take it.
    pub software: bool,
    /// The CUDA device it is, where the NVIDIA driver says ([`DeviceInfo::cuda`]).
    pub cuda: Option<i64>,
}

impl RenderDevice {
    fn of(gl: &GlContext) -> RenderDevice {
        let device = gl.device();
        RenderDevice {
            egl_device: device.map(|d| d.index),
            vendor: gl.vendor().to_string(),
            software: device.is_none_or(|d| d.software),
            cuda: device.and_then(|d| d.cuda),
        }
    }
}

/// Every device this process has made a GL context on, whatever chose it (the placement below,
/// `MUJOCO_EGL_DEVICE_ID`, or the software fallback).
static RENDER_DEVICES: Mutex<BTreeSet<RenderDevice>> = Mutex::new(BTreeSet::new());

/// The devices this process's cameras rendered on so far, for a run's session record: whether a
/// run rendered on the CPU or on its model's GPU is what its speed depends on most
/// (`data/benchmarks/gpu-renders-h200-2026-11-29`).
pub fn render_devices_used() -> Vec<RenderDevice> {
    RENDER_DEVICES.lock().expect("render devices").iter().cloned().collect()
}

/// Contexts this process has made: each new one goes to the next hardware device in turn.
static CONTEXTS_MADE: AtomicUsize = AtomicUsize::new(0);

/// The CUDA devices this process runs a model on, and whether its renders keep off them
/// ([`keep_renders_off`]) or go to them ([`keep_renders_on`]).
static MODEL_GPUS: Mutex<(Vec<i64>, RenderPlacement)> = Mutex::new((Vec::new(), RenderPlacement::OffModels));

/// Where a process's GL contexts go relative to the GPUs its model runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RenderPlacement {
    /// On GPUs without the model where the machine has such GPUs (a process with the machine's GPUs).
    OffModels,
    /// On the model's own GPUs (a process of `pipeline run --processes`, which has one GPU's share
    /// of the machine, as a one-GPU machine has).
    OnModels,
}

/// Makes the contexts made from now on prefer GPUs other than these CUDA devices (where the
/// process runs a model), when the machine has such GPUs.
///
/// Why: a GL context waits for the GPU's time slices while a model's CUDA kernels run there. On
/// two H100s with OpenVLA on the first, 64 workers' renders took 1,431 ms each spread over both
/// GPUs, while 16 processes rendering on an idle GPU took 49 ms a frame pair
/// (`data/benchmarks/gpu-own-kernels-h100-2026-11-27`).
pub fn keep_renders_off(cuda_devices: &[usize]) {
    *MODEL_GPUS.lock().expect("model GPUs") =
        (cuda_devices.iter().map(|&d| d as i64).collect(), RenderPlacement::OffModels);
}

/// Makes the contexts made from now on go to these CUDA devices' GPUs (in turn), where EGL lists
/// them: for a process that runs its model on part of the machine's GPUs while other processes run
/// on the rest (`pipeline run --processes`). Its renders then share its GPU as on a one-GPU
/// machine, instead of the GPUs of the other processes' models.
pub fn keep_renders_on(cuda_devices: &[usize]) {
    *MODEL_GPUS.lock().expect("model GPUs") =
        (cuda_devices.iter().map(|&d| d as i64).collect(), RenderPlacement::OnModels);
}

/// The device of the `nth` context of the process: `MUJOCO_EGL_DEVICE_ID`'s when set (`wanted`),
/// else the hardware devices that are none of the `models`' CUDA devices in turn
/// ([`RenderPlacement::OffModels`]; those that are, [`RenderPlacement::OnModels`]), else all
/// hardware devices in turn, else the first (software) device.
///
/// Why in turn: each NVIDIA context holds ~0.5 GB of its GPU, and a run keeps one per worker. On a
/// machine with two GPUs, 128 workers all on the first took ~63 GB of it beside a model replica,
/// which then ran out of memory (`data/benchmarks/gpu-quant-replicas-h100-2026-11-26`); in turn,
/// each GPU holds its share and renders its share of the frames.
fn choose_device(
    infos: &[DeviceInfo],
    wanted: Option<&str>,
    nth: usize,
    models: &[i64],
    placement: RenderPlacement,
) -> Result<DeviceInfo, SimError> {
    if let Some(wanted) = wanted {
        let index: usize = wanted.trim().parse().map_err(|_| {
            no_gl(format!("MUJOCO_EGL_DEVICE_ID={wanted:?} is not a device index (0..{})", infos.len()))
        })?;
        return infos
            .get(index)
            .cloned()
            .ok_or_else(|| no_gl(format!("MUJOCO_EGL_DEVICE_ID={index} but EGL lists {} device(s)", infos.len())));
    }
    let hardware: Vec<&DeviceInfo> = infos.iter().filter(|d| !d.software).collect();
    let preferred: Vec<&DeviceInfo> = hardware
        .iter()
        .copied()
        .filter(|d| match placement {
            RenderPlacement::OffModels => d.cuda.is_none_or(|c| !models.contains(&c)),
            RenderPlacement::OnModels => d.cuda.is_some_and(|c| models.contains(&c)),
        })
        .collect();
    let pool = if preferred.is_empty() { &hardware } else { &preferred };
    Ok(match pool.len() {
        0 => infos.first().cloned().expect("non-empty device list"),
        n => pool[nth % n].clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const OFF: RenderPlacement = RenderPlacement::OffModels;

    fn device(index: usize, software: bool) -> DeviceInfo {
        DeviceInfo { index, software, drm_file: None, cuda: (!software).then_some(index as i64) }
    }

    #[test]
    fn contexts_go_to_the_hardware_devices_in_turn_unless_one_is_named() {
        // two GPUs and Mesa's software device, as glvnd lists them on a GPU machine with Mesa installed
        let infos = [device(0, false), device(1, false), device(2, true)];
        let chosen: Vec<usize> = (0..5).map(|nth| choose_device(&infos, None, nth, &[], OFF).unwrap().index).collect();
        assert_eq!(chosen, [0, 1, 0, 1, 0]);
        assert_eq!(choose_device(&infos, Some("1"), 0, &[], OFF).unwrap().index, 1);
        assert_eq!(choose_device(&infos, Some("2"), 7, &[], OFF).unwrap().index, 2);
        assert!(choose_device(&infos, Some("3"), 0, &[], OFF).is_err());
        assert!(choose_device(&infos, Some("gpu"), 0, &[], OFF).is_err());
        // a CPU machine: the software device, every time
        let cpu = [device(0, true)];
        assert!((0..3).all(|nth| choose_device(&cpu, None, nth, &[], OFF).unwrap().index == 0));
        // one GPU: always it, a model on it or not
        let one = [device(0, true), device(1, false)];
        assert!((0..3).all(|nth| choose_device(&one, None, nth, &[1], OFF).unwrap().index == 1));
    }

    #[test]
    fn contexts_keep_off_the_gpus_that_run_a_model_while_others_are_free() {
        let infos = [device(0, false), device(1, false), device(2, false)];
        let chosen = |models: &[i64]| -> Vec<usize> {
            (0..4).map(|nth| choose_device(&infos, None, nth, models, OFF).unwrap().index).collect()
        };
        assert_eq!(chosen(&[0]), [1, 2, 1, 2]);
        assert_eq!(chosen(&[0, 2]), [1, 1, 1, 1]);
        // a model on every GPU: all of them in turn
        assert_eq!(chosen(&[0, 1, 2]), [0, 1, 2, 0]);
        // the variable still decides
        assert_eq!(choose_device(&infos, Some("0"), 1, &[0], OFF).unwrap().index, 0);
    }

    #[test]
    fn a_process_with_one_gpus_share_renders_on_its_models_gpus() {
        // as glvnd lists them: EGL's order need not be CUDA's
        let infos = [
            DeviceInfo { index: 0, software: false, drm_file: None, cuda: Some(1) },
            DeviceInfo { index: 1, software: false, drm_file: None, cuda: Some(0) },
            DeviceInfo { index: 2, software: false, drm_file: None, cuda: Some(2) },
            device(3, true),
        ];
        let on = RenderPlacement::OnModels;
        let chosen = |models: &[i64]| -> Vec<usize> {
            (0..4).map(|nth| choose_device(&infos, None, nth, models, on).unwrap().index).collect()
        };
        assert_eq!(chosen(&[0]), [1, 1, 1, 1]);
        assert_eq!(chosen(&[1, 2]), [0, 2, 0, 2]);
        // no CUDA device listed (a model on the CPU, or none): every GPU in turn
        assert_eq!(chosen(&[]), [0, 1, 2, 0]);
        assert_eq!(choose_device(&infos, Some("3"), 0, &[0], on).unwrap().index, 3);
    }
}
