//! Shared build script of every crate that produces binaries or tests linking MuJoCo.
//!
//! `.cargo/config.toml` sets `MUJOCO_DYNAMIC_LINK_DIR` to the library that `setup.sh` fetched;
//! embedding it as an RUNPATH lets `pipeline` and `cargo test` run without `LD_LIBRARY_PATH`.
//! (`rustc-link-arg` applies only to the package owning the build script, hence one per crate.)
//! For the `pipeline` binary it also records the git revision for run manifests.
fn main() {
    if std::env::var("CARGO_PKG_NAME").as_deref() == Ok("pipeline") {
        record_git_revision();
    }
    println!("cargo:rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    // libtorch (policies' tch): only linked where used (--as-needed), harmless elsewhere.
    if let Ok(torch) = std::env::var("LIBTORCH") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{torch}/lib");
    }
    match std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        Ok(dir) => {
            if !std::path::Path::new(&dir).join("libmujoco.so").exists() {
                println!(
                    "cargo:warning=libmujoco.so not found in {dir}: run ./setup.sh first (it fetches MuJoCo 3.3.7)"
                );
            }
            println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
        }
        Err(_) => println!(
            "cargo:warning=MUJOCO_DYNAMIC_LINK_DIR is unset: build from inside the repository (see .cargo/config.toml)"
        ),
    }
}

/// `PIPELINE_GIT_REVISION`: `git describe --always --dirty` of the workspace, or "unknown".
fn record_git_revision() {
    for p in [".git/HEAD", ".git/index", "schema/src", "sim/src", "policies/src", "udfs/src", "pipeline/src", "queries"]
    {
        println!("cargo:rerun-if-changed=../{p}");
    }
    let rev = std::process::Command::new("git")
        .args(["describe", "--always", "--dirty", "--abbrev=12"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=PIPELINE_GIT_REVISION={rev}");
}
