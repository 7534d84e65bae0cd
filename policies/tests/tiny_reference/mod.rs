//! What the parity tests of the in-process ports share: the OpenVLA reference venv, a tiny
//! random-weight checkpoint built by one of its scripts (`scripts/reference/*_tiny.py`), and the
//! reference outputs it writes under `<dir>/reference/`.

use std::path::{Path, PathBuf};
use std::process::Command;
use tch::{Kind, Tensor};

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// The venv of `scripts/setup/openvla_ref_venv.sh`: `$LIBERO_OPENVLA_VENV`, else
/// `<repo>/.openvla-venv`; a missing one fails the test, never skips it.
pub fn python() -> PathBuf {
    let venv =
        std::env::var_os("LIBERO_OPENVLA_VENV").map(PathBuf::from).unwrap_or_else(|| repo().join(".openvla-venv"));
    let py = venv.join("bin/python");
    assert!(
        py.exists(),
        "no OpenVLA reference venv at {} ({} missing): run ./setup.sh --tests, or `bash scripts/setup/openvla_ref_venv.sh DIR` \
         and set LIBERO_OPENVLA_VENV=DIR",
        venv.display(),
        py.display()
    );
    py
}

/// Runs `scripts/reference/<script>` into a fresh directory (named after it, unique to this
/// process): the tiny checkpoint and its reference outputs.
pub fn build(script: &str) -> PathBuf {
    let stem = script.trim_end_matches(".py").replace('_', "-");
    let dir = std::env::temp_dir().join(format!("{stem}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(python())
        .arg(repo().join("scripts/reference").join(script))
        .arg(&dir)
        .output()
        .unwrap_or_else(|e| panic!("run {script}: {e}"));
    assert!(
        out.status.success(),
        "{script} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    dir
}

/// `<dir>/reference/<name>`.
pub fn npy(dir: &Path, name: &str) -> Tensor {
    Tensor::read_npy(dir.join("reference").join(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

pub fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    assert_eq!(a.size(), b.size(), "shapes differ");
    (a.to_kind(Kind::Double) - b.to_kind(Kind::Double)).abs().max().double_value(&[])
}
