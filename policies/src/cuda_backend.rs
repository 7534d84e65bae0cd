//! libtorch's CUDA backend, loaded at start beside the CPU libraries this binary links, and
//! whether this machine has an NVIDIA GPU at all.
//!
//! Why: libtorch registers its CUDA backend when `libtorch_cuda.so` is loaded (its static
//! initialisers register the CUDA hooks), and torch-sys links that library only when it is in the
//! libtorch it builds against. The set-up builds against the CPU libraries of the torch 2.11.0
//! wheel (`third_party/libtorch`, ~500 MB instead of several GB of CUDA libraries on every CPU
//! machine and in CI), so without this module a GPU machine runs every model on its CPU in fp32,
//! silently: OpenVLA-7B took 26 s for 2 policy steps and 33 GB of memory there. `dlopen(RTLD_NOW | RTLD_GLOBAL)` of `libtorch_cuda.so`
//! before the first tch call is what `LD_PRELOAD` did by hand: one binary for CPU and GPU machines.
//!
//! Where it looks, in order (the first folder that holds a `libtorch_cuda.so` decides; one that
//! fails to load is reported, never skipped for the next):
//! 1. `$LIBERO_TORCH_CUDA_LIB` (a folder: a torch 2.11.0 installation's `torch/lib`). When set,
//!    it is the only place looked at: the user's choice is not second-guessed.
//! 2. The folder of the `libtorch_cpu.so` this process loaded (a libtorch that has both).
//! 3. `third_party/libtorch-cuda` of the checkout this binary was built in, which `./setup.sh`
//!    links on a GPU machine (`scripts/setup/libtorch_cuda.sh`).
//!
//! The library's own CUDA dependencies (cuBLAS, cuDNN, NCCL, ...) resolve through its RPATH,
//! `$ORIGIN/../../nvidia/<lib>/lib`: the `nvidia-*` wheels unpacked beside `torch/`, as in a
//! site-packages folder. A folder whose `../version.py` names another torch than 2.11.0 is
//! refused (its C++ ABI differs from the CPU libraries this binary links).
//!
//! [`load`] runs once per process and records the outcome ([`CudaBackend`]): the model loaders
//! refuse a silent CPU fallback with it (`models::cpu_fallback`), `pipeline doctor` prints it.

use std::ffi::{CStr, CString, OsString};
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The user's override: a folder holding `libtorch_cuda.so`.
pub const ENV_DIR: &str = "LIBERO_TORCH_CUDA_LIB";
/// The library that registers libtorch's CUDA backend.
pub const LIBRARY: &str = "libtorch_cuda.so";
/// The torch version of the CPU libraries this binary links (tch 0.24.0's; `build.rs` checks it).
pub const TORCH_VERSION: &str = "2.11.0";
/// What makes the CUDA backend loadable on a GPU machine.
pub const FIX: &str = "run ./setup.sh on this machine (on a GPU machine it links third_party/libtorch-cuda to torch \
     2.11.0's CUDA libraries), or set LIBERO_TORCH_CUDA_LIB to the torch/lib folder of a torch 2.11.0 with CUDA \
     (e.g. `python3 -c 'import torch, os; print(os.path.dirname(torch.__file__))'`/lib)";

/// Where a candidate folder came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// `$LIBERO_TORCH_CUDA_LIB`.
    Override,
    /// The folder of the `libtorch_cpu.so` this process loaded.
    BesideCpu,
    /// `third_party/libtorch-cuda` of the checkout the binary was built in.
    Checkout,
}

impl Source {
    pub fn describe(self) -> &'static str {
        match self {
            Source::Override => "LIBERO_TORCH_CUDA_LIB",
            Source::BesideCpu => "beside the libtorch_cpu.so this process loaded",
            Source::Checkout => "the set-up's third_party/libtorch-cuda",
        }
    }
}

/// A folder looked in for [`LIBRARY`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Candidate {
    pub source: Source,
    pub dir: PathBuf,
}

/// What [`load`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CudaBackend {
    /// `libtorch_cuda.so` was in the process before the search (linked, or `LD_PRELOAD`).
    AlreadyLoaded { path: PathBuf },
    /// Loaded by [`load`].
    Loaded { path: PathBuf, source: Source },
    /// No candidate folder holds it.
    NotFound { looked: Vec<Candidate> },
    /// The first one found could not be loaded: `dlerror`'s text, or why it was refused.
    Failed { path: PathBuf, source: Source, error: String },
}

impl CudaBackend {
    pub fn is_loaded(&self) -> bool {
        matches!(self, CudaBackend::AlreadyLoaded { .. } | CudaBackend::Loaded { .. })
    }

    /// The loaded library's path.
    pub fn library(&self) -> Option<&Path> {
        match self {
            CudaBackend::AlreadyLoaded { path } | CudaBackend::Loaded { path, .. } => Some(path),
            _ => None,
        }
    }

    /// One line: loaded from where, or why not.
    pub fn describe(&self) -> String {
        match self {
            CudaBackend::AlreadyLoaded { path } => {
                format!("loaded: {} was already in the process (linked, or LD_PRELOAD)", path.display())
            }
            CudaBackend::Loaded { path, source } => format!("loaded from {} ({})", path.display(), source.describe()),
            CudaBackend::NotFound { looked } => {
                let places: Vec<String> =
                    looked.iter().map(|c| format!("{} ({})", c.dir.display(), c.source.describe())).collect();
                format!("not loaded: no {LIBRARY} in {}", places.join(", "))
            }
            CudaBackend::Failed { path, source, error } => {
                format!("not loaded: {} ({}) failed to load: {error}", path.display(), source.describe())
            }
        }
    }
}

/// Loads libtorch's CUDA backend if it can be found (see the module doc), once per process, and
/// returns the outcome; later calls return the same outcome. Call it first thing in `main`,
/// before any tch call: libtorch looks up its CUDA hooks once, at the first CUDA query.
pub fn load() -> &'static CudaBackend {
    static OUTCOME: OnceLock<CudaBackend> = OnceLock::new();
    OUTCOME.get_or_init(|| {
        let checkout =
            Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(|root| root.join("third_party/libtorch-cuda"));
        let candidates = candidates(
            std::env::var_os(ENV_DIR),
            loaded_library("libtorch_cpu.so").and_then(|p| p.parent().map(Path::to_path_buf)),
            checkout,
        );
        search(&candidates, loaded_library(LIBRARY))
    })
}

/// The folders to look in, in order: the override alone when it is set (non-empty), else the
/// CPU library's folder and the checkout's `third_party/libtorch-cuda`.
pub fn candidates(
    override_dir: Option<OsString>,
    cpu_dir: Option<PathBuf>,
    checkout: Option<PathBuf>,
) -> Vec<Candidate> {
    if let Some(dir) = override_dir.filter(|d| !d.is_empty()) {
        return vec![Candidate { source: Source::Override, dir: dir.into() }];
    }
    let mut out = Vec::new();
    out.extend(cpu_dir.map(|dir| Candidate { source: Source::BesideCpu, dir }));
    out.extend(checkout.map(|dir| Candidate { source: Source::Checkout, dir }));
    out
}

/// The outcome of looking in `candidates` ([`load`]'s, without the process-wide record):
/// `already` (a `libtorch_cuda.so` the process has) wins; else the first candidate holding the
/// library is loaded, or its failure is the outcome.
pub fn search(candidates: &[Candidate], already: Option<PathBuf>) -> CudaBackend {
    if let Some(path) = already {
        return CudaBackend::AlreadyLoaded { path };
    }
    for c in candidates {
        if !c.dir.join(LIBRARY).exists() {
            continue;
        }
        // the real folder (the set-up's link resolved): the library's RPATH, `$ORIGIN/../../nvidia/...`,
        // is relative to where it really lies
        let path = c.dir.canonicalize().unwrap_or_else(|_| c.dir.clone()).join(LIBRARY);
        let failed = |error: String| CudaBackend::Failed { path: path.clone(), source: c.source, error };
        if let Some(version) = torch_version_of(&c.dir)
            && !version.starts_with(TORCH_VERSION)
        {
            return failed(format!(
                "it is torch {version}, and this binary links torch {TORCH_VERSION}'s CPU libraries (another version's \
                 CUDA library would not match them)"
            ));
        }
        return match dlopen_global(&path) {
            Ok(()) => CudaBackend::Loaded { path, source: c.source },
            Err(e) => failed(e),
        };
    }
    CudaBackend::NotFound { looked: candidates.to_vec() }
}

/// The torch version of a `torch/lib` folder: `../version.py`'s `__version__` (a wheel), else
/// `../build-version` (a libtorch archive); `None` when neither says.
pub fn torch_version_of(lib_dir: &Path) -> Option<String> {
    let root = lib_dir.parent()?;
    if let Ok(text) = std::fs::read_to_string(root.join("version.py")) {
        return text.lines().find_map(|l| {
            let v = l.strip_prefix("__version__ = ")?;
            Some(v.trim().trim_matches(|c| c == '\'' || c == '"').to_string())
        });
    }
    std::fs::read_to_string(root.join("build-version")).ok().map(|v| v.trim().to_string())
}

/// `dlopen(path, RTLD_NOW | RTLD_GLOBAL)`, kept open for the life of the process: NOW so that a
/// missing dependency or symbol fails here, with its name, instead of at the first CUDA call;
/// GLOBAL so that the backend's symbols serve the libraries loaded after it.
fn dlopen_global(path: &Path) -> Result<(), String> {
    let c_path = CString::new(path.as_os_str().as_bytes()).map_err(|_| "the path has a NUL byte".to_string())?;
    // SAFETY: a valid C string; the handle is never closed (libtorch's registrations must stay).
    let handle = unsafe { libc::dlopen(c_path.as_ptr(), libc::RTLD_NOW | libc::RTLD_GLOBAL) };
    if handle.is_null() {
        // SAFETY: dlerror returns NULL or a C string valid until the next dl* call on this thread
        let e = unsafe { libc::dlerror() };
        let text = if e.is_null() {
            "dlopen failed without a reason".to_string()
        } else {
            unsafe { CStr::from_ptr(e) }.to_string_lossy().into_owned()
        };
        return Err(text);
    }
    Ok(())
}

/// The CUDA devices libtorch sees (0 without its CUDA backend): where a model can run.
pub fn torch_cuda_devices() -> usize {
    tch::Cuda::device_count().max(0) as usize
}

/// The path of a shared library this process has mapped, by file name (`/proc/self/maps`).
pub fn loaded_library(name: &str) -> Option<PathBuf> {
    let maps = std::fs::read_to_string("/proc/self/maps").ok()?;
    maps.lines()
        .filter_map(|l| l.split_whitespace().nth(5))
        .find(|p| Path::new(p).file_name().is_some_and(|f| f == name))
        .map(PathBuf::from)
}

/// This machine's NVIDIA driver version, when it has one: the kernel module's
/// (`/proc/driver/nvidia/version`), else `nvidia-smi`'s where it lists a GPU (a container may
/// not show `/proc/driver/nvidia`). Read once per process.
pub fn nvidia_driver() -> Option<&'static str> {
    static DRIVER: OnceLock<Option<String>> = OnceLock::new();
    DRIVER
        .get_or_init(|| {
            if let Ok(text) = std::fs::read_to_string("/proc/driver/nvidia/version") {
                return Some(kernel_module_version(&text).unwrap_or_else(|| "unknown version".into()));
            }
            let smi = |args: &[&str]| {
                let out = std::process::Command::new("nvidia-smi").args(args).output().ok()?;
                out.status.success().then(|| String::from_utf8_lossy(&out.stdout).into_owned())
            };
            let gpus = smi(&["-L"])?;
            if !gpus.lines().any(|l| l.starts_with("GPU ")) {
                return None;
            }
            let version = smi(&["--query-gpu=driver_version", "--format=csv,noheader"]);
            Some(version.and_then(|v| v.lines().next().map(|l| l.trim().to_string())).unwrap_or_default())
        })
        .as_deref()
}

/// `570.86.15` of `NVRM version: NVIDIA UNIX x86_64 Kernel Module  570.86.15  Tue ...` (or of
/// the open module's `... Open Kernel Module for x86_64  570.86.15  Release Build ...`): the first
/// word after "Kernel Module" made of digits and dots.
fn kernel_module_version(text: &str) -> Option<String> {
    let line = text.lines().next()?;
    let rest = line.split("Kernel Module").nth(1)?;
    rest.split_whitespace()
        .find(|w| w.contains('.') && w.chars().all(|c| c.is_ascii_digit() || c == '.'))
        .map(str::to_string)
}

/// One CUDA device as the driver describes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GpuInfo {
    pub index: usize,
    pub name: String,
    /// Compute capability (major, minor): 9.0 for an H100/H200.
    pub capability: (i32, i32),
    pub memory_bytes: u64,
}

/// The CUDA devices the driver lists (respecting `CUDA_VISIBLE_DEVICES`) and its CUDA version
/// (e.g. 13000), through the driver API (`libcuda.so.1`, opened at run time); an error names
/// what is missing. Independent of libtorch: it tells a driver problem from a libtorch one.
pub fn driver_devices() -> Result<(Vec<GpuInfo>, i32), String> {
    use cudarc::driver::{result, sys};
    // SAFETY: only probes whether the library can be opened
    if !unsafe { sys::is_culib_present() } {
        return Err("no libcuda.so.1 (the NVIDIA driver's CUDA library) on this machine".into());
    }
    result::init().map_err(|e| format!("cuInit: {e}"))?;
    let mut version = 0;
    // SAFETY: a valid out pointer
    unsafe { sys::cuDriverGetVersion(&mut version) }.result().map_err(|e| format!("cuDriverGetVersion: {e}"))?;
    let count = result::device::get_count().map_err(|e| format!("cuDeviceGetCount: {e}"))?;
    let mut out = Vec::new();
    for index in 0..count {
        let dev = result::device::get(index).map_err(|e| format!("cuDeviceGet({index}): {e}"))?;
        let attribute = |a| unsafe { result::device::get_attribute(dev, a) }.unwrap_or(-1);
        out.push(GpuInfo {
            index: index as usize,
            name: result::device::get_name(dev).unwrap_or_else(|e| format!("(name unknown: {e})")),
            capability: (
                attribute(sys::CUdevice_attribute::CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MAJOR),
                attribute(sys::CUdevice_attribute::CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MINOR),
            ),
            memory_bytes: unsafe { result::device::total_mem(dev) }.unwrap_or(0) as u64,
        });
    }
    Ok((out, version))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// An empty folder of this process's for one test (`group`: the module, `name`: the case).
    pub(crate) fn temp_dir_of(group: &str, name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("libero-{group}-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn temp_dir(name: &str) -> PathBuf {
        temp_dir_of("cuda-backend", name)
    }

    #[test]
    fn cuda_override_replaces_the_search_and_an_empty_one_is_unset() {
        let (cpu, checkout) = (PathBuf::from("/t/torch/lib"), PathBuf::from("/repo/third_party/libtorch-cuda"));
        let all = candidates(None, Some(cpu.clone()), Some(checkout.clone()));
        assert_eq!(
            all,
            [
                Candidate { source: Source::BesideCpu, dir: cpu.clone() },
                Candidate { source: Source::Checkout, dir: checkout.clone() }
            ]
        );
        assert_eq!(candidates(Some("".into()), Some(cpu.clone()), Some(checkout.clone())), all);
        assert_eq!(
            candidates(Some("/mine/lib".into()), Some(cpu), Some(checkout)),
            [Candidate { source: Source::Override, dir: "/mine/lib".into() }]
        );
    }

    /// The first folder holding the library decides: a fake one that cannot be loaded is the
    /// outcome, with dlopen's reason, and the next folder (which has none) is not reached; a
    /// library already in the process wins over all.
    #[test]
    fn cuda_search_stops_at_the_first_library_found_and_reports_dlerror() {
        let empty = temp_dir("empty");
        let fake = temp_dir("fake");
        std::fs::write(fake.join(LIBRARY), b"not an ELF file").unwrap();
        let looked = [
            Candidate { source: Source::BesideCpu, dir: empty.clone() },
            Candidate { source: Source::Checkout, dir: fake.clone() },
            Candidate { source: Source::Checkout, dir: empty.clone() },
        ];
        let outcome = search(&looked, None);
        let CudaBackend::Failed { path, source, error } = &outcome else { panic!("{outcome:?}") };
        assert_eq!((path, *source), (&fake.canonicalize().unwrap().join(LIBRARY), Source::Checkout));
        // glibc's dlerror names the file and why ("invalid ELF header" or "file too short")
        assert!(error.contains(LIBRARY) && (error.contains("ELF") || error.contains("too short")), "{error}");
        assert!(!outcome.is_loaded() && outcome.library().is_none());
        assert!(outcome.describe().contains("failed to load") && outcome.describe().contains(error.as_str()));

        let none = search(&looked[..1], None);
        assert_eq!(none, CudaBackend::NotFound { looked: looked[..1].to_vec() });
        assert!(none.describe().contains(&empty.display().to_string()), "{}", none.describe());

        let already = search(&looked, Some("/x/libtorch_cuda.so".into()));
        assert!(already.is_loaded() && already.library() == Some(Path::new("/x/libtorch_cuda.so")));
    }

    /// Another torch's CUDA library is refused before dlopen, naming both versions.
    #[test]
    fn cuda_library_of_another_torch_version_is_refused() {
        let root = temp_dir("other-version");
        let lib = root.join("lib");
        std::fs::create_dir_all(&lib).unwrap();
        std::fs::write(lib.join(LIBRARY), b"not an ELF file").unwrap();
        std::fs::write(root.join("version.py"), "__version__ = '2.9.1+cu128'\ndebug = False\n").unwrap();
        assert_eq!(torch_version_of(&lib).as_deref(), Some("2.9.1+cu128"));
        let outcome = search(&[Candidate { source: Source::Override, dir: lib }], None);
        let CudaBackend::Failed { error, source, .. } = &outcome else { panic!("{outcome:?}") };
        assert_eq!(*source, Source::Override);
        assert!(error.contains("2.9.1+cu128") && error.contains(TORCH_VERSION), "{error}");
    }

    #[test]
    fn cuda_driver_version_is_read_from_the_kernel_module_line() {
        let text = "NVRM version: NVIDIA UNIX x86_64 Kernel Module  570.86.15  Tue Jan  7 00:00:00 UTC 2025\nGCC version: gcc 12\n";
        assert_eq!(kernel_module_version(text).as_deref(), Some("570.86.15"));
        let open =
            "NVRM version: NVIDIA UNIX Open Kernel Module for x86_64  580.65.06  Release Build  (dvs-builder@U16)\n";
        assert_eq!(kernel_module_version(open).as_deref(), Some("580.65.06"));
        assert_eq!(kernel_module_version("something else"), None);
    }

    /// In this test process the CPU libraries are mapped (tch links them), so the second
    /// candidate folder is real.
    #[test]
    fn cuda_candidates_find_the_loaded_cpu_library() {
        let _ = tch::Tensor::from_slice(&[1.0f32]);
        let cpu = loaded_library("libtorch_cpu.so").expect("libtorch_cpu.so mapped");
        assert!(cpu.is_file(), "{}", cpu.display());
    }
}
