//! Every bundle loads and compiles in MuJoCo from Rust into the model the reference compiled:
//! the same sizes (nq, nv, nbody, ngeom, ...), options and parameter arrays, and init states of
//! length 1+nq+nv. Bad bundles fail with errors that say how to rebuild.

use libero_e2e::{bundles, repo_root};
use libero_schema::Suite;
use libero_sim::bundle::{BundleSet, TaskBundle};
use libero_sim::env::LiberoEnv;
use libero_sim::{SimError, scene};

#[test]
fn every_canonical_task_has_a_bundle_that_compiles_to_the_reference_model() {
    let set = bundles();
    let mut n = 0;
    for suite in Suite::CANONICAL {
        for task_id in 0..10 {
            let bundle = set.load(suite, task_id).unwrap();
            let model = scene::compile(&bundle).unwrap();
            let diffs = scene::compare_with_reference(&model, &bundle.reference_model().unwrap());
            assert!(diffs.is_empty(), "{suite} task {task_id}: {diffs:#?}");
            let (nq, nv) = (model.ffi().nq as usize, model.ffi().nv as usize);
            assert_eq!(bundle.init_states.cols, 1 + nq + nv, "{suite} task {task_id}");
            assert_eq!(bundle.init_states.rows, 50, "{suite} task {task_id}");
            assert!(!bundle.task.instructions.bddl.is_empty() && !bundle.task.goal.is_empty());
            assert_eq!(
                (bundle.task.base_suite.as_str(), bundle.task.perturbation.as_deref()),
                (suite.name().as_str(), None)
            );
            assert_eq!(bundle.fixture_seeds(), vec![0, 7], "fixture poses for OpenVLA's and openpi's seeds");
            assert!(bundle.task.cameras.iter().any(|c| c == "agentview"));
            n += 1;
        }
    }
    assert_eq!(n, 40);
}

#[test]
fn fixture_poses_change_between_episodes_and_seeds_like_the_reference() {
    let bundle = bundles().load(Suite::LIBERO_GOAL, 0).unwrap();
    let body = &bundle.task.fixture_bodies[0];
    let p = |seed, ep| bundle.fixture_poses(seed, ep).unwrap()[body].pos;
    assert_ne!(p(0, 0), p(0, 1), "each reset re-samples fixture poses");
    assert_ne!(p(0, 0), p(7, 0), "the env seed changes them");
    let err = bundle.fixture_poses(3, 0).unwrap_err().to_string();
    assert!(err.contains("seed 3") && err.contains("[0, 7]"), "{err}");
}

/// The set-up compared every task's recorded fixture poses, for every seed, with the published
/// loop's real hard resets (episodes 0-1 by the loop itself, a middle one and the last one by one
/// hard reset each) and found them equal; the tasks whose `:init` sets an articulated object's
/// state (open/close/turnon/turnoff) are exactly the four whose poses depend on LIBERO's growing
/// property-sampler list (issue 17).
#[test]
fn recorded_fixture_poses_were_checked_against_the_published_loop_on_every_task_and_seed() {
    let set = bundles();
    let mut with_property_samplers = Vec::new();
    let mut spots = std::collections::BTreeSet::new();
    for suite in Suite::CANONICAL {
        for task_id in 0..10 {
            let bundle = set.load(suite, task_id).unwrap();
            let check = &bundle.provenance["checks"]["published_loop"];
            let what = format!("{suite} task {task_id}: {check}");
            let seeds: Vec<u64> = check["seeds"].as_array().expect(&what).iter().map(|v| v.as_u64().unwrap()).collect();
            assert_eq!(seeds, bundle.fixture_seeds(), "{what}");
            assert_eq!(check["max_abs_diff"].as_f64(), Some(0.0), "{what}");
            assert_eq!(check["loop_episodes"], serde_json::json!([0, 1]), "{what}");
            let spot: Vec<u64> =
                check["spot_episodes"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
            assert_eq!(spot.last(), Some(&(bundle.task.fixture_episodes as u64 - 1)), "{what}: the last episode");
            spots.extend(spot);
            if check["property_samplers_per_load"].as_u64().unwrap() > 0 {
                with_property_samplers.push(format!("{suite} {task_id}"));
            }
        }
    }
    assert_eq!(with_property_samplers, ["libero_spatial 4", "libero_10 3", "libero_10 8", "libero_10 9"]);
    assert!(spots.len() >= 8, "the middle spot episodes should spread over 2..48: {spots:?}");
}

/// A LIBERO task has two instruction texts; the published loops (OpenVLA's and openpi's
/// `task_description = task.language`) give the file-name one, which can say something else than
/// the BDDL tag.
#[test]
fn base_tasks_record_both_instructions_and_give_the_published_loops_one_by_default() {
    use libero_schema::InstructionSource;
    let b = bundles().load(Suite::LIBERO_GOAL, 0).unwrap();
    assert_eq!(b.task.name, "open_the_middle_drawer_of_the_cabinet");
    assert_eq!(b.task.instructions.filename, "open the middle drawer of the cabinet");
    assert_eq!(
        b.task.instructions.bddl, "open the middle layer of the drawer",
        "lowercased, as env.language_instruction"
    );
    assert_eq!(b.task.instruction(InstructionSource::Published), ("open the middle drawer of the cabinet", "filename"));
    assert_eq!(b.task.instruction(InstructionSource::Bddl), ("open the middle layer of the drawer", "bddl"));
    let mut differ = 0;
    for suite in Suite::CANONICAL {
        for task_id in 0..10 {
            let t = bundles().load(suite, task_id).unwrap().task;
            assert_eq!(t.instruction(InstructionSource::Published).0, t.instructions.published, "{suite} {task_id}");
            differ += usize::from(t.instructions.bddl != t.instructions.filename);
        }
    }
    assert!(differ >= 20, "only {differ} of 40 canonical tasks have two different texts");
}

fn copy_bundle(suite: Suite, task: u32) -> (tempdir::Dir, std::path::PathBuf) {
    let src = bundles().root().join(format!("{}/{task:02}", suite.name()));
    let dir = tempdir::Dir::new();
    let dst = dir.0.join("bundle");
    std::fs::create_dir_all(&dst).unwrap();
    for f in std::fs::read_dir(&src).unwrap() {
        let f = f.unwrap();
        std::fs::copy(f.path(), dst.join(f.file_name())).unwrap();
    }
    (dir, dst)
}

mod tempdir {
    pub struct Dir(pub std::path::PathBuf);
    impl Dir {
        pub fn new() -> Self {
            let p = std::env::temp_dir().join(format!("libero-test-{}-{}", std::process::id(), rand_suffix()));
            std::fs::create_dir_all(&p).unwrap();
            Dir(p)
        }
    }
    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
    fn rand_suffix() -> u64 {
        use std::sync::atomic::{AtomicU64, Ordering};
        static N: AtomicU64 = AtomicU64::new(0);
        N.fetch_add(1, Ordering::Relaxed)
    }
}

#[test]
fn missing_corrupt_or_foreign_bundles_say_how_to_rebuild() {
    let missing = BundleSet::open(repo_root().join("no/such/bundles")).unwrap_err();
    assert!(
        matches!(missing, SimError::BundleMissing { .. }) && missing.to_string().contains("./setup.sh"),
        "{missing}"
    );

    let (_d, dir) = copy_bundle(Suite::LIBERO_SPATIAL, 0);
    std::fs::write(dir.join("task.json"), "{ not json").unwrap();
    let corrupt = TaskBundle::load(&dir).unwrap_err();
    assert!(corrupt.to_string().contains("task.json") && corrupt.to_string().contains("./setup.sh"), "{corrupt}");

    let (_d2, dir2) = copy_bundle(Suite::LIBERO_SPATIAL, 0);
    let prov = std::fs::read_to_string(dir2.join("provenance.json")).unwrap().replace("\"3.3.7\"", "\"3.2.3\"");
    std::fs::write(dir2.join("provenance.json"), prov).unwrap();
    let foreign = TaskBundle::load(&dir2).unwrap_err();
    assert!(matches!(foreign, SimError::BundleVersion { .. }) && foreign.to_string().contains("3.2.3"), "{foreign}");

    let (_d3, dir3) = copy_bundle(Suite::LIBERO_SPATIAL, 0);
    std::fs::write(dir3.join("init_states.npy"), b"\x93NUMPY truncated").unwrap();
    let npy = TaskBundle::load(&dir3).unwrap_err();
    assert!(npy.to_string().contains("init_states.npy"), "{npy}");
}

#[test]
fn unknown_tasks_and_init_states_list_what_exists() {
    let set = bundles();
    let err = set.load(Suite::LIBERO_SPATIAL, 10).unwrap_err().to_string();
    assert!(err.contains("0, 1, 2") && err.contains("task 10"), "{err}");
    let bundle = set.load(Suite::LIBERO_SPATIAL, 0).unwrap();
    let mut env = LiberoEnv::new(&bundle).unwrap();
    let err = env.reset(50, 0).unwrap_err().to_string();
    assert!(err.contains("50 init states"), "{err}");
}
