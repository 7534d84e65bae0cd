//! Are a bundle's files the ones the exporter wrote? Checked before a run starts.
//!
//! `provenance.json` holds the sha256 of every file the exporter wrote or linked (scene, task,
//! fixture poses, init states, assets). A file changed or cut short after the build (a full disk,
//! a copy interrupted, a hand edit) would otherwise surface as an error row in every episode of
//! its task, or worse, as a different scene; [`verify_tasks`] finds it first and names it with
//! the command that rebuilds it. Hashing the per-task files and the assets they use (each asset
//! once) takes about a second for the four canonical suites.

use crate::SimError;
use crate::bundle::{BundleSet, TaskBundle};
use libero_schema::Suite;
use sha2::{Digest, Sha256};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Check the files of every listed task against its provenance; the first damaged file is an
/// error naming it and how to rebuild.
pub fn verify_tasks(set: &BundleSet, tasks: &BTreeSet<(Suite, u32)>) -> Result<(), SimError> {
    let mut assets_checked: BTreeSet<PathBuf> = BTreeSet::new();
    for &(suite, task_id) in tasks {
        let bundle = set.load(suite, task_id).map_err(|e| with_rebuild_hint(set, suite, e))?;
        verify_task(set.root(), &bundle, &mut assets_checked).map_err(|e| with_rebuild_hint(set, suite, e))?;
    }
    Ok(())
}

fn verify_task(root: &Path, bundle: &TaskBundle, assets_checked: &mut BTreeSet<PathBuf>) -> Result<(), SimError> {
    let hashes = &bundle.provenance["sha256"];
    for (key, file) in [("scene_xml", "scene.xml"), ("task_json", "task.json"), ("fixtures_json", "fixtures.json")] {
        if let Some(expected) = hashes[key].as_str() {
            check_file(&bundle.dir.join(file), expected)?;
        }
    }
    if let Some(expected) = bundle.provenance[crate::bundle::SEEDED_RECORD]["sha256"].as_str() {
        check_file(&bundle.dir.join(crate::bundle::SEEDED_FIXTURES_FILE), expected)?;
    }
    if let Some(expected) = hashes["init_states"].as_str() {
        // the exporter hashes the array's float64 bytes (numpy's tobytes), not the .npy file
        let mut h = Sha256::new();
        for v in &bundle.init_states.data {
            h.update(v.to_le_bytes());
        }
        if format!("{:x}", h.finalize()) != expected {
            return Err(damaged(
                &bundle.dir.join(&bundle.task.init_states.file),
                "its values differ from those exported",
            ));
        }
    }
    if let Some(assets) = hashes["assets"].as_object() {
        for (rel, expected) in assets {
            let path = root.join("assets").join(rel);
            if assets_checked.insert(path.clone()) {
                check_file(&path, expected.as_str().unwrap_or_default())?;
            }
        }
    }
    Ok(())
}

/// Hash a file in chunks (assets reach 20 MB; reading them whole would grow the heap for nothing).
pub(crate) fn check_file(path: &Path, expected: &str) -> Result<(), SimError> {
    let unreadable = |e: std::io::Error| damaged(path, &format!("cannot read it: {e}"));
    let mut file = std::fs::File::open(path).map_err(unreadable)?;
    let mut h = Sha256::new();
    let len = std::io::copy(&mut file, &mut h).map_err(unreadable)?;
    if format!("{:x}", h.finalize()) != expected {
        return Err(damaged(path, &format!("its sha256 differs from provenance.json ({len} bytes now)")));
    }
    Ok(())
}

fn damaged(path: &Path, why: &str) -> SimError {
    SimError::BundleCorrupt { path: path.into(), detail: format!("damaged since it was built: {why}") }
}

/// Replace the generic rebuild hint with the command that rebuilds this suite's bundles.
fn with_rebuild_hint(set: &BundleSet, suite: Suite, e: SimError) -> SimError {
    match e {
        SimError::BundleCorrupt { path, detail } => SimError::BundleDamaged {
            path,
            detail,
            rebuild: format!("rm {root}/.complete-{suite} && ./setup.sh --suites {suite}", root = set.root().display()),
        },
        other => other,
    }
}
