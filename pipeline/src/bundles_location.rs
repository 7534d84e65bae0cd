//! Where the task bundles are, wherever the binary is started from.
//!
//! In order: `--bundles` / `$LIBERO_BUNDLES` (taken as given); `data/bundles` under the working
//! directory (a checkout); `data/bundles` of the checkout this binary was built in; the newest
//! bundle folder of the set-up's cache (`$LIBERO_EVAL_CACHE`, default `~/.cache/libero-eval`,
//! `bundles-*/index.json`). When none has bundles, the error lists every place it looked.

use anyhow::{Result, bail};
use std::path::{Path, PathBuf};

/// The bundle folder to use: `explicit` when given, else the first candidate that holds bundles.
pub fn resolve(explicit: Option<&Path>) -> Result<PathBuf> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    let candidates = candidates();
    if let Some(found) = candidates.iter().find(|p| p.join("index.json").is_file()) {
        return Ok(found.clone());
    }
    let looked: Vec<String> = candidates.iter().map(|p| format!("  {}", p.display())).collect();
    bail!(
        "no task bundles found; looked in:\n{}\nBuild them with ./setup.sh in the repository, or point \
         --bundles (or LIBERO_BUNDLES) at a bundle folder",
        looked.join("\n")
    )
}

/// The ALOHA-sim bundle folder: `explicit` when given, else `data/aloha` under the working
/// directory, else that of the checkout this binary was built in (`AlohaBundle::open` names the
/// set-up command when it is not there).
pub fn resolve_aloha(explicit: Option<&Path>) -> PathBuf {
    if let Some(p) = explicit {
        return p.to_path_buf();
    }
    let here = PathBuf::from(libero_sim::aloha::bundle::DEFAULT_DIR);
    if here.join("provenance.json").is_file() {
        return here;
    }
    // pipeline/.. without a literal `..` (named in the error when the bundle is missing)
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap_or(Path::new(".."));
    let built_in = root.join(libero_sim::aloha::bundle::DEFAULT_DIR);
    built_in.canonicalize().unwrap_or(built_in)
}

fn candidates() -> Vec<PathBuf> {
    let mut out = vec![PathBuf::from("data/bundles")];
    // the checkout this binary was built from (pipeline/.. = the repository root)
    let built_in = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/bundles");
    out.push(built_in.canonicalize().unwrap_or(built_in));
    let cache = std::env::var_os("LIBERO_EVAL_CACHE")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/libero-eval")));
    if let Some(cache) = cache {
        let mut built: Vec<(std::time::SystemTime, PathBuf)> = std::fs::read_dir(&cache)
            .into_iter()
            .flatten()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with("bundles-"))
            .filter_map(|e| Some((e.path().join("index.json").metadata().ok()?.modified().ok()?, e.path())))
            .collect();
        built.sort();
        match built.pop() {
            Some((_, newest)) => out.push(newest),
            None => out.push(cache.join("bundles-*")),
        }
    }
    out
}
