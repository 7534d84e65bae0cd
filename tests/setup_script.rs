//! `./setup.sh --suites` adds and never takes away: a user who adds suites after the set-up keeps
//! the four canonical suites' bundles and the tests' reference data linked where the tests read
//! them. (Before the split of the set-up, `--suites` replaced the canonical list, and `data/frames`
//! was relinked to a frame set of the added suites only: five tests failed on missing PNGs.)
//!
//! The set-up runs for real, as a user adding two LIBERO-PRO tasks would, on a copy of the
//! checkout's scripts (its links land in the copy, not under the running tests' feet) and the real
//! cache, where every step is already done: it takes seconds and builds nothing.

use libero_e2e::{repo_root, test_dir};
use std::path::Path;
use std::process::Command;

const CANONICAL: [&str; 4] = ["libero_spatial", "libero_object", "libero_goal", "libero_10"];
/// Already built for the tests (tests/support.rs PRO_TEST_TASKS), so nothing is built here.
const ADDED: &str = "libero_spatial_object/01,libero_10_task/02";

fn copy_tree(from: &Path, to: &Path) {
    let status = Command::new("cp").arg("-a").arg(from).arg(to).status().unwrap();
    assert!(status.success(), "cp -a {} {}", from.display(), to.display());
}

#[test]
fn adding_suites_keeps_the_canonical_suites_and_the_tests_reference_data() {
    let root = repo_root();
    let copy = test_dir("setup_script", "adding_suites");
    copy_tree(&root.join("setup.sh"), &copy.join("setup.sh"));
    copy_tree(&root.join("scripts"), &copy.join("scripts"));
    // MuJoCo is unpacked into the checkout, not cached: copied, so that nothing is downloaded.
    std::fs::create_dir_all(copy.join("third_party")).unwrap();
    copy_tree(&root.join("third_party/mujoco-3.3.7"), &copy.join("third_party/mujoco-3.3.7"));

    let out = Command::new("bash")
        .args(["setup.sh", "--no-build", "--tests", "--suites", ADDED])
        .current_dir(&copy)
        .output()
        .unwrap();
    let log = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "./setup.sh --no-build --tests --suites {ADDED} failed:\n{log}");
    assert!(!log.contains("use tasks of all four canonical suites"), "reference data skipped after adding suites:\n{log}");

    // The same bundles, golden data, frames and reference episodes as the checkout's own set-up.
    for link in [
        "data/bundles",
        "data/golden",
        "data/frames",
        "data/aloha",
        "data/plus_golden",
        "data/pro_robustness_golden",
        "data/pro_occlusion_golden",
        "data/plus_layout_golden",
    ] {
        let ours = std::fs::canonicalize(copy.join(link)).unwrap_or_else(|e| panic!("{link} in the copy: {e}\n{log}"));
        let checkout = std::fs::canonicalize(root.join(link)).unwrap();
        assert_eq!(ours, checkout, "{link} after adding {ADDED}");
    }

    // What the render, media and noise tests read: every canonical suite's frames on both stacks.
    let frames = copy.join("data/frames");
    for suite in CANONICAL {
        for task in 0..10 {
            let f = frames.join(format!("mujoco-3.2.3/{suite}__{task:02}__init0__s000__agentview.png"));
            assert!(f.is_file(), "missing {} after adding {ADDED}", f.display());
        }
        for init in 0..3 {
            for step in ["000", "040"] {
                let f = frames.join(format!("mujoco-3.3.7/{suite}__00__init{init}__s{step}__agentview.png"));
                assert!(f.is_file(), "missing {} after adding {ADDED}", f.display());
            }
        }
    }

    // The canonical suites' bundles and the added tasks, side by side in the one bundle set.
    let index: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(copy.join("data/bundles/index.json")).unwrap()).unwrap();
    let paths: Vec<&str> = index["tasks"].as_array().unwrap().iter().filter_map(|t| t["path"].as_str()).collect();
    for suite in CANONICAL {
        let n = paths.iter().filter(|p| p.starts_with(&format!("{suite}/"))).count();
        assert_eq!(n, 10, "{suite}: {n} bundles listed after adding {ADDED}");
    }
    for added in ADDED.split(',') {
        assert!(paths.contains(&added), "{added} not in the bundle index");
    }
    std::fs::remove_dir_all(&copy).unwrap();
}
