//! `pipeline doctor` on this machine (CI's kind: a CPU machine with Mesa's EGL, no GPU), its
//! findings read from `--json`: the CPU-only libtorch's CUDA backend not loaded and no GPU are
//! fine here (OK, not FAIL), the renderer is Mesa's, the set-up's bundles are intact; a damaged
//! bundle file is a FAIL naming the file, and the exit status says so.

use libero_e2e::{pipeline_bin, repo_root, test_dir};
use serde_json::Value;
use std::path::Path;
use std::process::Output;

/// `pipeline doctor --json EXTRA..` without the user's CUDA override or EGL device choice, and
/// its findings by check name.
fn doctor(extra: &[&str]) -> (Output, Vec<Value>) {
    let out = std::process::Command::new(pipeline_bin())
        .arg("doctor")
        .arg("--json")
        .args(extra)
        .current_dir(repo_root())
        .env_remove("LIBERO_TORCH_CUDA_LIB")
        .env_remove("MUJOCO_EGL_DEVICE_ID")
        .env_remove("LIBERO_BUNDLES")
        .output()
        .expect("run pipeline doctor");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let report: Value = serde_json::from_str(stdout.trim()).unwrap_or_else(|e| {
        panic!("doctor --json is not JSON ({e}):\n{stdout}\nstderr:\n{}", String::from_utf8_lossy(&out.stderr))
    });
    let checks = report["checks"].as_array().expect("checks").clone();
    assert_eq!(
        report["fail"].as_u64().unwrap() as usize,
        checks.iter().filter(|c| c["status"] == "FAIL").count(),
        "the FAIL count"
    );
    (out, checks)
}

fn find<'a>(checks: &'a [Value], name: &str) -> &'a Value {
    checks.iter().find(|c| c["check"] == name).unwrap_or_else(|| panic!("no check {name:?} in {checks:#?}"))
}

fn found(c: &Value) -> &str {
    c["found"].as_str().unwrap_or_default()
}

#[test]
fn this_cpu_machine_is_fine_without_cuda_and_renders_with_mesa() {
    let (out, checks) = doctor(&[]);
    let failed: Vec<&Value> = checks.iter().filter(|c| c["status"] == "FAIL").collect();
    assert!(failed.is_empty(), "FAIL on the set-up machine: {failed:#?}");
    assert!(out.status.success(), "exit status {:?} without a FAIL", out.status);

    let libtorch = find(&checks, "libtorch");
    assert_eq!(libtorch["status"], "OK");
    assert!(found(libtorch).contains("torch 2.11.0"), "{libtorch}");

    // the set-up's CPU-only libtorch: the backend is not there, and not needed without a GPU
    let backend = find(&checks, "CUDA backend");
    assert_eq!(backend["status"], "OK", "{backend}");
    assert!(found(backend).contains("not loaded: no libtorch_cuda.so in"), "{backend}");
    assert!(found(backend).contains("third_party/libtorch-cuda"), "the places looked in: {backend}");
    assert!(found(backend).contains("no NVIDIA GPU") && found(backend).contains("CPU in fp32"), "{backend}");
    let gpus = find(&checks, "GPUs");
    assert_eq!(gpus["status"], "OK");
    assert!(found(gpus).starts_with("none"), "{gpus}");

    let egl = find(&checks, "EGL");
    assert_eq!(egl["status"], "OK", "{egl}");
    assert!(found(egl).contains("Mesa") && found(egl).contains("software"), "{egl}");

    let mujoco = find(&checks, "MuJoCo");
    assert_eq!(mujoco["status"], "OK");
    assert!(found(mujoco).starts_with(libero_schema::bundle_format::MUJOCO_VERSION), "{mujoco}");

    // every suite the set-up built is checked, the four canonical ones among them
    for suite in ["libero_spatial", "libero_object", "libero_goal", "libero_10"] {
        let c = find(&checks, &format!("bundles {suite}"));
        assert_eq!(c["status"], "OK", "{c}");
        assert!(found(c).contains("task(s) intact"), "{c}");
    }
    assert!(checks.iter().any(|c| c["check"] == "disk (working folder)" && found(c).contains("GB free")));
}

/// A copy of the bundles holding libero_object task 0 with its scene cut short: that suite is a
/// FAIL naming the file and the command that rebuilds it; the suites the copy lacks are WARN.
#[test]
fn a_damaged_bundle_file_is_a_fail_naming_the_file() {
    let d = test_dir("doctor", "damaged-bundle");
    let real = libero_e2e::bundles().root().to_path_buf();
    let copy = d.join("bundles");
    let task = copy.join("libero_object/00");
    std::fs::create_dir_all(&task).unwrap();
    // the index of this one task
    let mut index: Value = serde_json::from_str(&std::fs::read_to_string(real.join("index.json")).unwrap()).unwrap();
    let tasks = index["tasks"].as_array_mut().unwrap();
    tasks.retain(|t| t["suite"] == "libero_object" && t["task_id"] == 0);
    assert_eq!(tasks.len(), 1);
    std::fs::write(copy.join("index.json"), index.to_string()).unwrap();
    std::os::unix::fs::symlink(real.join("assets").canonicalize().unwrap(), copy.join("assets")).unwrap();
    copy_dir(&real.join("libero_object/00"), &task);
    let scene = std::fs::read(task.join("scene.xml")).unwrap();
    std::fs::write(task.join("scene.xml"), &scene[..scene.len() / 2]).unwrap();

    let (out, checks) = doctor(&["--bundles", copy.to_str().unwrap()]);
    assert!(!out.status.success(), "a FAIL must give a non-zero exit status");
    let damaged = find(&checks, "bundles libero_object");
    assert_eq!(damaged["status"], "FAIL", "{damaged}");
    let text = found(damaged);
    assert!(text.contains(&task.join("scene.xml").display().to_string()), "the file is named: {text}");
    assert!(text.contains("./setup.sh --suites libero_object"), "the fix: {text}");
    let missing = find(&checks, "bundles libero_goal");
    assert_eq!(missing["status"], "WARN", "{missing}");
    assert_eq!(missing["fix"], "./setup.sh --suites libero_goal");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("1 check(s) failed"), "{stderr}");
}

fn copy_dir(from: &Path, to: &Path) {
    for f in std::fs::read_dir(from).unwrap() {
        let f = f.unwrap();
        std::fs::copy(f.path(), to.join(f.file_name())).unwrap();
    }
}
