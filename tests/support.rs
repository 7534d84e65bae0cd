//! Shared helpers of the end-to-end tests: where the repository, bundles, golden data and the
//! reference venv are. Tests fail with a set-up hint (never skip) when something is missing.

use libero_sim::bundle::BundleSet;
use libero_sim::npy::{self, Array2};
use std::path::{Path, PathBuf};

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

/// The `pipeline` binary built by cargo for these tests.
pub fn pipeline_bin() -> PathBuf {
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
