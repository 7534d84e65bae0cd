//! Shared build script of every crate that produces binaries or tests linking MuJoCo.
//!
//! `.cargo/config.toml` sets `MUJOCO_DYNAMIC_LINK_DIR` to the library that `setup.sh` fetched;
//! embedding it as an RUNPATH lets `pipeline` and `cargo test` run without `LD_LIBRARY_PATH`.
//! (`rustc-link-arg` applies only to the package owning the build script, hence one per crate.)
fn main() {
    println!("cargo:rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
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
