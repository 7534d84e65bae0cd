//! `pipeline doctor`: what a run on this machine would use, and why, checked before it runs.
//!
//! Why: users of LIBERO evaluations trip over their set-up before their policy: a model silently on
//! the CPU, EGL silently on the software renderer, `MUJOCO_EGL_DEVICE_ID` out of range, a MuJoCo
//! that renders darker, a damaged file. Each check prints OK, WARN or FAIL, what it found and,
//! for a problem, the fix. FAIL: a run would fail or compute something else than intended (a
//! model on the CPU beside a GPU, a damaged bundle); WARN: slower than it could be, or missing
//! only for the tests. The exit status is 1 when any
//! check fails; `--json` prints the same as one JSON object.
//!
//! Read-only and quick (a few seconds: the bundles' hashes dominate); it loads no model.

use anyhow::{Result, bail};
use libero_policies::cuda_backend::{self, CudaBackend};
use libero_schema::Suite;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

pub const EXAMPLES: &str = "Examples:
  pipeline doctor
  pipeline doctor --json
  LIBERO_TORCH_CUDA_LIB=/opt/venv/lib/python3.12/site-packages/torch/lib pipeline doctor
  pipeline doctor --bundles /data/bundles";

#[derive(clap::Args)]
pub struct Args {
    /// Print the checks as one JSON object ({"checks": [{"check", "status", "found", "fix"}],
    /// "fail", "warn"}) instead of a table.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
enum Status {
    #[serde(rename = "OK")]
    Ok,
    #[serde(rename = "WARN")]
    Warn,
    #[serde(rename = "FAIL")]
    Fail,
}

impl Status {
    fn label(self) -> &'static str {
        match self {
            Status::Ok => "OK",
            Status::Warn => "WARN",
            Status::Fail => "FAIL",
        }
    }
}

/// One finding.
#[derive(Debug, Serialize)]
struct Check {
    check: String,
    status: Status,
    found: String,
    /// How to fix it (a problem only).
    fix: Option<String>,
}

fn check(name: impl Into<String>, status: Status, found: impl Into<String>, fix: Option<String>) -> Check {
    Check { check: name.into(), status, found: found.into(), fix }
}

/// `bundles`: the global `--bundles` (or `$LIBERO_BUNDLES`), else where a run would look.
pub fn run(bundles: Option<&Path>, args: Args) -> Result<()> {
    let gpu = cuda_backend::nvidia_driver();
    let mut checks = vec![libtorch()];
    checks.extend(cuda(gpu));
    checks.push(egl(gpu.is_some()));
    checks.push(mujoco());
    checks.extend(task_bundles(bundles));
    checks.push(aloha_bundle());
    checks.push(reference_venv());
    checks.extend(disk());
    let count = |s: Status| checks.iter().filter(|c| c.status == s).count();
    let (fail, warn) = (count(Status::Fail), count(Status::Warn));
    if args.json {
        println!("{}", serde_json::json!({"checks": checks, "fail": fail, "warn": warn}));
    } else {
        let width = checks.iter().map(|c| c.check.len()).max().unwrap_or(0);
        for c in &checks {
            println!("{:<5} {:<width$}  {}", c.status.label(), c.check, c.found);
            if let Some(fix) = &c.fix {
                println!("{:<5} {:<width$}  fix: {fix}", "", "");
            }
        }
        println!("{fail} FAIL, {warn} WARN, {} OK", checks.len() - fail - warn);
    }
    if fail > 0 {
        bail!("{fail} check(s) failed (FAIL above, each with its fix)");
    }
    Ok(())
}

/// The CPU libraries of libtorch this process loaded, and their version.
fn libtorch() -> Check {
    let Some(dir) = cuda_backend::loaded_library("libtorch_cpu.so").and_then(|p| p.parent().map(Path::to_path_buf))
    else {
        return check("libtorch", Status::Fail, "libtorch_cpu.so is not loaded in this process", Some(setup()));
    };
    match cuda_backend::torch_version_of(&dir) {
        Some(v) if v.starts_with(cuda_backend::TORCH_VERSION) => check(
            "libtorch",
            Status::Ok,
            format!("torch {v} (what tch 0.24.0 needs), CPU libraries from {}", dir.display()),
            None,
        ),
        found => check(
            "libtorch",
            Status::Fail,
            format!(
                "{} has torch {} and this binary was built for torch {}: results would differ silently",
                dir.display(),
                found.as_deref().unwrap_or("of unknown version (no ../version.py)"),
                cuda_backend::TORCH_VERSION
            ),
            Some(format!("{} and rebuild (cargo build --release)", setup())),
        ),
    }
}

fn setup() -> String {
    "run ./setup.sh in the repository".into()
}

/// libtorch's CUDA backend and the GPUs: what a model policy would run on.
fn cuda(driver: Option<&str>) -> Vec<Check> {
    let backend = cuda_backend::load();
    let torch_devices = cuda_backend::torch_cuda_devices();
    let default = match torch_devices {
        0 => "model policies run on the CPU in fp32".to_string(),
        n => format!("model policies run on cuda:0 in bf16 by default ({n} device(s) for devices=)"),
    };
    let backend_check = match (backend, driver) {
        (b, _) if b.is_loaded() => check("CUDA backend", Status::Ok, format!("{}; {default}", b.describe()), None),
        (b, None) => check(
            "CUDA backend",
            match b {
                CudaBackend::Failed { .. } => Status::Warn,
                _ => Status::Ok,
            },
            format!(
                "{}; not needed: this machine has no NVIDIA GPU ({default}: the tests' tiny models run, a model of a \
                 billion parameters or more needs devices=cpu)",
                b.describe()
            ),
            matches!(b, CudaBackend::Failed { .. })
                .then(|| format!("harmless here; on a GPU machine: {}", cuda_backend::FIX)),
        ),
        (b, Some(v)) => check(
            "CUDA backend",
            Status::Fail,
            format!(
                "{}, and this machine has an NVIDIA GPU (driver {v}): model policies would be refused (or, with \
                 devices=cpu, run on the CPU in fp32)",
                b.describe()
            ),
            Some(cuda_backend::FIX.to_string()),
        ),
    };
    let gpus = match driver {
        None => check(
            "GPUs",
            Status::Ok,
            "none: no NVIDIA driver (/proc/driver/nvidia/version, nvidia-smi -L); models and rendering use the CPU",
            None,
        ),
        Some(v) => {
            match cuda_backend::driver_devices() {
                Err(e) => check(
                    "GPUs",
                    Status::Fail,
                    format!("NVIDIA driver {v}, but the CUDA driver API fails: {e}"),
                    Some("install the NVIDIA driver's CUDA library (libcuda.so.1) matching the kernel module".into()),
                ),
                Ok((devices, cuda_version)) => {
                    let listed: Vec<String> = devices
                        .iter()
                        .map(|d| {
                            format!(
                                "cuda:{} {} (compute capability {}.{}, {:.0} GiB)",
                                d.index,
                                d.name,
                                d.capability.0,
                                d.capability.1,
                                d.memory_bytes as f64 / (1u64 << 30) as f64
                            )
                        })
                        .collect();
                    let found = format!(
                        "NVIDIA driver {v} (CUDA {}.{}); {} device(s): {}; libtorch sees {torch_devices}{}",
                        cuda_version / 1000,
                        cuda_version % 1000 / 10,
                        devices.len(),
                        listed.join(", "),
                        std::env::var("CUDA_VISIBLE_DEVICES")
                            .map(|c| format!(" (CUDA_VISIBLE_DEVICES={c:?})"))
                            .unwrap_or_default()
                    );
                    if cuda_version < 13000 {
                        check(
                        "GPUs",
                        Status::Fail,
                        found,
                        Some("torch 2.11.0's CUDA 13.0 libraries need a driver for CUDA 13.0 or later (580 or newer)".into()),
                    )
                    } else if devices.is_empty() || torch_devices < devices.len() {
                        let fix = match backend.is_loaded() {
                            true => "check CUDA_VISIBLE_DEVICES and the driver (nvidia-smi)".to_string(),
                            false => cuda_backend::FIX.to_string(),
                        };
                        let status = if torch_devices == 0 { Status::Fail } else { Status::Warn };
                        check("GPUs", status, found, Some(fix))
                    } else {
                        check("GPUs", Status::Ok, found, None)
                    }
                }
            }
        }
    };
    vec![backend_check, gpus]
}

/// The EGL device and vendor a run's first camera context gets.
fn egl(gpu: bool) -> Check {
    let wanted = std::env::var("MUJOCO_EGL_DEVICE_ID").ok();
    let listed = match libero_sim::gl::devices() {
        Ok(Some(d)) => d
            .iter()
            .map(|d| {
                let what = match (d.software, d.cuda) {
                    (true, _) => "software (Mesa llvmpipe)".to_string(),
                    (false, Some(c)) => format!("hardware, CUDA device {c}"),
                    (false, None) => {
                        format!("hardware{}", d.drm_file.as_ref().map(|f| format!(" {f}")).unwrap_or_default())
                    }
                };
                format!("{}: {what}", d.index)
            })
            .collect::<Vec<_>>()
            .join(", "),
        Ok(None) => "EGL lists no devices (Mesa's surfaceless platform)".into(),
        Err(e) => return check("EGL", Status::Fail, e.to_string(), None),
    };
    let chosen = libero_sim::gl::next_device()
        .and_then(|d| libero_sim::gl::GlContext::on(d.as_ref()).map(|ctx| (d, ctx.vendor().to_string())));
    let env = wanted.as_ref().map(|w| format!(", MUJOCO_EGL_DEVICE_ID={w}")).unwrap_or_default();
    match chosen {
        Err(e) => check("EGL", Status::Fail, format!("devices [{listed}]{env}: {e}"), None),
        Ok((device, vendor)) => {
            let software = device.as_ref().is_none_or(|d| d.software);
            let on = device.as_ref().map_or("the surfaceless platform".to_string(), |d| format!("device {}", d.index));
            let found = format!("renders with {vendor} on {on} (devices [{listed}]{env})");
            match (software, gpu) {
                (false, _) => check("EGL", Status::Ok, found, None),
                (true, false) => check(
                    "EGL",
                    Status::Ok,
                    format!("{found}: the software renderer, on the CPU (a LIBERO camera at 256² costs ~0.2 s)"),
                    None,
                ),
                (true, true) => check(
                    "EGL",
                    Status::Warn,
                    format!("{found}: the software renderer on the CPU, although this machine has an NVIDIA GPU"),
                    Some(
                        "install the NVIDIA driver's EGL library (libnvidia-egl, listed in /usr/share/glvnd/egl_vendor.d/10_nvidia.json) \
                         and glvnd's libEGL.so.1, or set MUJOCO_EGL_DEVICE_ID to an NVIDIA device's index"
                            .into(),
                    ),
                ),
            }
        }
    }
}

/// The MuJoCo library this binary linked against the one the bundles are made for.
fn mujoco() -> Check {
    let version = libero_sim::mujoco_version();
    let expected = libero_schema::bundle_format::MUJOCO_VERSION;
    let from = cuda_backend::loaded_library(&format!("libmujoco.so.{version}"))
        .map(|p| format!(" from {}", p.display()))
        .unwrap_or_default();
    match version == expected {
        true => check(
            "MuJoCo",
            Status::Ok,
            format!("{version}{from} (the reference env's; renders with the published 3.2.3 look where asked)"),
            None,
        ),
        false => check(
            "MuJoCo",
            Status::Fail,
            format!(
                "{version}{from}, and the bundles and the reference env are {expected}: physics and pictures differ"
            ),
            Some(format!("{} and rebuild (cargo build --release)", setup())),
        ),
    }
}

/// Which suites have bundles, and whether their files are the ones the exporter wrote.
fn task_bundles(explicit: Option<&Path>) -> Vec<Check> {
    let root = match crate::bundles_location::resolve(explicit) {
        Ok(root) => root,
        Err(e) => return vec![check("bundles", Status::Fail, e.to_string(), Some(setup()))],
    };
    let set = match libero_sim::bundle::BundleSet::open(&root) {
        Ok(set) => set,
        Err(e) => return vec![check("bundles", Status::Fail, e.to_string(), Some(setup()))],
    };
    let mut suites: BTreeMap<String, BTreeSet<u32>> = BTreeMap::new();
    for t in set.tasks() {
        suites.entry(t.suite.clone()).or_default().insert(t.task_id);
    }
    let mut out = Vec::new();
    for canonical in Suite::CANONICAL {
        if !suites.contains_key(&canonical.name()) {
            out.push(check(
                format!("bundles {canonical}"),
                Status::Warn,
                format!("no bundles in {}", root.display()),
                Some(format!("./setup.sh --suites {canonical}")),
            ));
        }
    }
    for (name, ids) in suites {
        let name_check = format!("bundles {name}");
        let Ok(suite) = name.parse::<Suite>() else {
            out.push(check(name_check, Status::Warn, format!("{name}: a suite this build does not know"), None));
            continue;
        };
        let tasks: BTreeSet<(Suite, u32)> = ids.iter().map(|&id| (suite, id)).collect();
        out.push(match libero_sim::bundle_integrity::verify_tasks(&set, &tasks) {
            Ok(()) => {
                check(name_check, Status::Ok, format!("{} task(s) intact in {}", ids.len(), root.display()), None)
            }
            Err(e) => check(name_check, Status::Fail, e.to_string(), None),
        });
    }
    out
}

/// ALOHA-sim's bundle (needed only for its runs).
fn aloha_bundle() -> Check {
    let dir = crate::bundles_location::resolve_aloha(None);
    match dir.join("provenance.json").is_file() {
        true => check("ALOHA-sim bundle", Status::Ok, dir.display().to_string(), None),
        false => check(
            "ALOHA-sim bundle",
            Status::Warn,
            format!("none at {} (only ALOHA-sim runs need it)", dir.display()),
            Some("./setup.sh --suites aloha_sim".into()),
        ),
    }
}

/// The reference env's venv (`.venv`): the parity tests and the reference data need it.
fn reference_venv() -> Check {
    let built_in = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv");
    let venv = [PathBuf::from(".venv"), built_in].into_iter().find(|v| v.join("bin/python").exists());
    let Some(venv) = venv else {
        return check(
            "reference venv",
            Status::Warn,
            "no .venv here or in the checkout this binary was built in (only the parity tests and the reference data need it)",
            Some(setup()),
        );
    };
    let venv = venv.canonicalize().unwrap_or(venv);
    let out = std::process::Command::new(venv.join("bin/python"))
        .args(["-c", "import mujoco, robosuite; print(mujoco.__version__, robosuite.__version__)"])
        .output();
    let expected = libero_schema::bundle_format::MUJOCO_VERSION;
    match out {
        Ok(o) if o.status.success() => {
            let text = String::from_utf8_lossy(&o.stdout).trim().to_string();
            let mut words = text.split_whitespace();
            let (mujoco, robosuite) = (words.next().unwrap_or("?"), words.next().unwrap_or("?"));
            let found = format!("{} (mujoco {mujoco}, robosuite {robosuite})", venv.display());
            match mujoco == expected {
                true => check("reference venv", Status::Ok, found, None),
                false => check(
                    "reference venv",
                    Status::Warn,
                    format!("{found}: its MuJoCo is not this build's {expected}, so parity tests would differ"),
                    Some(setup()),
                ),
            }
        }
        Ok(o) => check(
            "reference venv",
            Status::Warn,
            format!(
                "{}: importing mujoco and robosuite failed: {}",
                venv.display(),
                String::from_utf8_lossy(&o.stderr).trim()
            ),
            Some(setup()),
        ),
        Err(e) => check("reference venv", Status::Warn, format!("{}: {e}", venv.display()), Some(setup())),
    }
}

/// Free space where a run writes (the working folder) and where the set-up caches.
fn disk() -> Vec<Check> {
    let cache = std::env::var_os("LIBERO_EVAL_CACHE")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/libero-eval")));
    let mut places = vec![("working folder", PathBuf::from("."))];
    places.extend(cache.map(|c| ("set-up cache", c)));
    places
        .into_iter()
        .map(|(what, path)| {
            let name = format!("disk ({what})");
            // the nearest folder that exists (a cache not made yet is made under its parent)
            let existing = path.ancestors().find(|p| p.exists()).unwrap_or(Path::new("/")).to_path_buf();
            let shown = existing.canonicalize().unwrap_or(existing.clone());
            match free_bytes(&existing) {
                Err(e) => check(name, Status::Warn, format!("{}: {e}", shown.display()), None),
                Ok(free) => {
                    let gb = free as f64 / 1e9;
                    let found = format!("{gb:.1} GB free at {}", shown.display());
                    if gb < 1.0 {
                        check(
                            name,
                            Status::Fail,
                            found,
                            Some("free space: a run's parts and the set-up's caches need it".into()),
                        )
                    } else if gb < 10.0 {
                        check(
                            name,
                            Status::Warn,
                            found,
                            Some(
                                "a fresh set-up needs ~10 GB (libtorch, venvs, bundles); a GPU set-up ~4 GB more"
                                    .into(),
                            ),
                        )
                    } else {
                        check(name, Status::Ok, found, None)
                    }
                }
            }
        })
        .collect()
}

/// Bytes available to this user on the file system holding `path` (`statvfs`).
fn free_bytes(path: &Path) -> std::io::Result<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).map_err(std::io::Error::other)?;
    let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: a valid C string and an out struct of the right type
    if unsafe { libc::statvfs(c.as_ptr(), &mut stat) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(stat.f_bavail as u64 * stat.f_frsize as u64)
}
