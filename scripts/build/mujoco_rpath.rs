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
    // Not .git/index: `git describe --dirty` below rewrites it (a refresh of its stat data, on a
    // fresh clone or after a touch), so watching it rebuilt the binary on the next cargo call, ~4 min
    // of a 2-core CI's test set-up. A commit moves the branch's ref; an edit changes the sources.
    // (A path that does not exist would rerun this script on every build: only those that do.)
    let mut watched = vec![".git/HEAD".to_string(), ".git/packed-refs".to_string()];
    if let Ok(head) = std::fs::read_to_string("../.git/HEAD") {
        if let Some(branch) = head.trim().strip_prefix("ref: ") {
            watched.push(format!(".git/{branch}"));
        }
    }
    watched.extend(["schema/src", "sim/src", "policies/src", "udfs/src", "pipeline/src", "queries"].map(String::from));
    for p in watched.iter().filter(|p| std::path::Path::new("..").join(p).exists()) {
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
