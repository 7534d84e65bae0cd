//! Shared helpers of the end-to-end tests: where the repository, bundles, golden data and the
//! reference venv are. Tests fail with a set-up hint (never skip) when something is missing.

use libero_sim::bundle::BundleSet;
use libero_sim::npy::{self, Array2};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

pub fn bundles() -> BundleSet {
    BundleSet::open(repo_root().join("data/bundles")).unwrap_or_else(|e| panic!("{e}\nrun ./setup.sh first"))
}

pub fn golden_dir() -> PathBuf {
    let d = repo_root().join("data/golden");
    assert!(d.exists(), "no golden data at {}: run ./setup.sh first", d.display());
    d
}

pub fn reference_python() -> PathBuf {
    let p = repo_root().join(".venv/bin/python");
    assert!(p.exists(), "no reference venv at {}: run ./setup.sh first", p.display());
    p
}

pub fn read_npy(path: &Path) -> Array2 {
    npy::read_f64_2d(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The `pipeline` binary under test: `LIBERO_PIPELINE_BIN` when set (a copy, safe from another
/// build replacing the shared target's binary mid-test), else the one cargo built for these tests.
pub fn pipeline_bin() -> PathBuf {
    if let Some(bin) = std::env::var_os("LIBERO_PIPELINE_BIN") {
        return PathBuf::from(bin);
    }
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| repo_root().join("target"));
    let profile = if cfg!(debug_assertions) { "debug" } else { "release" };
    target.join(profile).join("pipeline")
}

/// Read an RGB PNG as a frame in the given orientation (PNGs carry none).
pub fn read_png(path: &Path, orientation: libero_sim::render::Orientation) -> libero_sim::render::Frame {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    buf.truncate(info.buffer_size());
    libero_sim::render::Frame { width: info.width, height: info.height, rgb: buf, orientation }
}

/// Run the `pipeline` binary from the repository root.
pub fn pipeline(args: &[&str]) -> Output {
    Command::new(pipeline_bin()).args(args).current_dir(repo_root()).output().expect("run pipeline")
}

/// The stdout of a `pipeline` call that must succeed (else both streams, in the panic).
pub fn ok(out: Output) -> String {
    assert!(
        out.status.success(),
        "pipeline failed:\nstdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A fresh, empty folder for one test of one test file (`group`), unique to this process.
pub fn test_dir(group: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("libero-{group}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `pipeline sql` over a run as CSV rows (header dropped; no quoted commas in the values asked for).
pub fn sql_rows(run: &Path, query: &str, extra: &[&str]) -> Vec<Vec<String>> {
    let mut args = vec!["sql", query, "--run", run.to_str().unwrap(), "--csv"];
    args.extend_from_slice(extra);
    let text = ok(pipeline(&args));
    text.lines().skip(1).map(|l| l.split(',').map(str::to_string).collect()).collect()
}
