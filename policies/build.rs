//! With the `torch` feature: refuse to build against any libtorch but the one tch 0.24.0 was
//! made for (torch 2.11.0, also the GPU machine's). A mismatched libtorch links fine and computes
//! wrong results silently, so this is a build error, not a warning. Also embeds the RUNPATH to
//! libtorch for this crate's tests.

const TORCH_EXPECTED: &str = "2.11.0";

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var_os("CARGO_FEATURE_TORCH").is_none() {
        return;
    }
    let lib = std::env::var("DEP_TCH_LIBTORCH_LIB")
        .expect("torch-sys must be a direct dependency so that DEP_TCH_LIBTORCH_LIB is set");
    let version_py = std::path::Path::new(&lib).join("../version.py");
    let text = std::fs::read_to_string(&version_py).unwrap_or_else(|e| {
        panic!(
            "cannot read {} ({e}): is LIBTORCH a torch {TORCH_EXPECTED} wheel's torch/ folder? Run ./setup.sh",
            version_py.display()
        )
    });
    assert!(
        text.contains(&format!("__version__ = '{TORCH_EXPECTED}")),
        "libtorch at {lib} is not torch {TORCH_EXPECTED} (tch 0.24.0 needs exactly it): run ./setup.sh, or point LIBTORCH at a torch {TORCH_EXPECTED} torch/ folder"
    );
    println!("cargo:rerun-if-changed={}", version_py.display());
    println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
}
