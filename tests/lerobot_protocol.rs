//! lerobot's LIBERO protocol as spec rows (issue 45): `pipeline specs --protocol lerobot` writes
//! lerobot-eval's episodes (episode k of a task: init state k, `env.seed(1000 + k)` right before its
//! one reset) with a `protocol` column; a run of them applies lerobot's caps (libero_spatial 280),
//! starts each episode from the fixture poses the set-up recorded after `env.seed(1000 + k)` and one
//! hard reset (`scripts/reference/seeded_fixtures.py`, checked there bit for bit against the
//! reference env's real reset), and stores the protocol in its episodes and manifest; a resume
//! under the other protocol is refused, and so is a seed without recorded poses, before any
//! episode, naming the set-up flag. A spec table without the column means what it always meant.

use arrow::array::{Array, ArrayRef, AsArray, Int32Array, Int64Array, RecordBatch, StringArray};
use arrow::datatypes::{Float64Type, Int32Type, Int64Type};
use libero_e2e::{bundles, ok, pipeline, sql_rows, test_dir};
use libero_schema::{EvalProtocol, Suite};
use libero_sim::bundle::Pose;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The task the tests' set-up records lerobot's seeds 1000 and 1001 for (keep equal to setup.sh
/// LEROBOT_TEST_TASK): libero_spatial, whose lerobot cap (280) differs from the canonical one
/// (220), and a task whose fixture poses depend on LIBERO's property samplers (issue 17).
const TEST_TASK: (Suite, u32) = (Suite::LIBERO_SPATIAL, 4);

fn read_batches(path: &Path) -> Vec<RecordBatch> {
    let file = std::fs::File::open(path).unwrap();
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file).unwrap().build().unwrap();
    reader.map(Result::unwrap).collect()
}

fn write_specs(path: &Path, columns: Vec<(&str, ArrayRef)>) -> PathBuf {
    let batch = RecordBatch::try_from_iter(columns).unwrap();
    std::fs::write(path, libero_udfs::run_store::parquet_bytes(&batch, None).unwrap()).unwrap();
    path.to_path_buf()
}

fn lerobot_specs(dir: &Path, trials: u32) -> PathBuf {
    let specs = dir.join(format!("lerobot-{trials}.parquet"));
    let (suite, task) = TEST_TASK;
    ok(pipeline(&[
        "specs",
        "--protocol",
        "lerobot",
        "--suites",
        &suite.name(),
        "--tasks",
        &task.to_string(),
        "--trials",
        &trials.to_string(),
        "-o",
        specs.to_str().unwrap(),
    ]));
    specs
}

/// The recorded poses, read from the file as the set-up wrote it (not through the bundle loader).
fn seeded_poses_on_disk(seed: u64) -> BTreeMap<String, Pose> {
    let (suite, task) = TEST_TASK;
    let path = bundles().root().join(suite.name()).join(format!("{task:02}")).join("fixtures_seeded.json");
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e}; the tests' set-up (./setup.sh --tests) records it", path.display()));
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    json["seeds"][seed.to_string()]
        .as_object()
        .unwrap_or_else(|| panic!("seed {seed} not in {}", path.display()))
        .iter()
        .map(|(body, p)| {
            let v = |k: &str| p[k].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect::<Vec<_>>();
            let (pos, quat) = (v("pos"), v("quat"));
            (body.clone(), Pose { pos: [pos[0], pos[1], pos[2]], quat: [quat[0], quat[1], quat[2], quat[3]] })
        })
        .collect()
}

#[test]
fn lerobot_spec_rows_are_episode_k_on_init_state_k_seeded_1000_plus_k() {
    let d = test_dir("lerobot_protocol", "spec_rows");
    let out = d.join("all.parquet");
    ok(pipeline(&["specs", "--protocol", "lerobot", "-o", out.to_str().unwrap()]));
    let batches = read_batches(&out);
    let names: Vec<String> = batches[0].schema().fields().iter().map(|f| f.name().clone()).collect();
    assert_eq!(names, ["suite", "task_id", "init_state_id", "seed", "protocol"]);
    let mut per_task: BTreeMap<(String, i32), Vec<(i32, i64)>> = BTreeMap::new();
    for b in &batches {
        let (suite, task) = (b.column(0).as_string::<i32>(), b.column(1).as_primitive::<Int32Type>());
        let (init, seed) = (b.column(2).as_primitive::<Int32Type>(), b.column(3).as_primitive::<Int64Type>());
        let protocol = b.column(4).as_string::<i32>();
        for r in 0..b.num_rows() {
            assert_eq!(protocol.value(r), "lerobot");
            per_task
                .entry((suite.value(r).to_string(), task.value(r)))
                .or_default()
                .push((init.value(r), seed.value(r)));
        }
    }
    assert_eq!(per_task.len(), 40, "the four canonical suites' 40 tasks");
    for (task, rows) in &per_task {
        // restarting at 1000 for every task, as lerobot-eval's start_seed does
        let expected: Vec<(i32, i64)> = (0..50).map(|k| (k, 1000 + k as i64)).collect();
        assert_eq!(rows, &expected, "{task:?}");
    }
    // --seeds has no meaning under lerobot's seeding; --first-seed moves it
    let refused = pipeline(&["specs", "--protocol", "lerobot", "--seeds", "7", "-o", out.to_str().unwrap()]);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--first-seed"));
    let moved = d.join("moved.parquet");
    ok(pipeline(&[
        "specs",
        "--protocol",
        "lerobot",
        "--suites",
        "libero_goal",
        "--tasks",
        "2",
        "--trials",
        "2",
        "--first-seed",
        "2000",
        "-o",
        moved.to_str().unwrap(),
    ]));
    let b = &read_batches(&moved)[0];
    assert_eq!(b.column(3).as_primitive::<Int64Type>().values().to_vec(), [2000, 2001]);
    // and a canonical table is the four key columns, as before the column existed
    let canonical = d.join("canonical.parquet");
    ok(pipeline(&["specs", "--suites", "libero_goal", "--trials", "1", "-o", canonical.to_str().unwrap()]));
    assert_eq!(read_batches(&canonical)[0].num_columns(), 4);
}

/// One run of lerobot rows carries the whole check: caps, stored protocol, the fixture poses the
/// episodes started from, and the refusals around it.
#[test]
fn a_lerobot_run_uses_lerobots_caps_and_seeded_fixture_poses_and_refuses_the_other_protocol() {
    let d = test_dir("lerobot_protocol", "run");
    let (suite, task) = TEST_TASK;
    let bundle = bundles().load(suite, task).unwrap();
    // the set-up's own check: recorded poses equal the reference env's after seed(s) + one hard reset
    let record = &bundle.provenance["seeded_at_reset"];
    assert_eq!(record["checks"]["max_abs_diff"].as_f64(), Some(0.0), "{record}");
    assert_eq!(record["checks"]["reference_hard_reset_seeds"], serde_json::json!([1000, 1001]), "{record}");
    assert_eq!(record["checks"]["property_samplers_per_load"], serde_json::json!(1), "{record}");
    assert_eq!(bundle.seeded_fixture_seeds(), [1000, 1001]);

    // The env starts a lerobot episode from exactly the recorded poses (parsed here from the file).
    let mut env = libero_sim::env::LiberoEnv::new(&bundle).unwrap();
    for (k, seed) in [(0usize, 1000u64), (1, 1001)] {
        env.reset_under(EvalProtocol::Lerobot, k, seed).unwrap();
        assert_eq!(env.fixture_poses().unwrap(), seeded_poses_on_disk(seed), "episode {k}, seed {seed}");
    }
    // which are not the canonical loop's episode k after env.seed(0): the seeding is what changed
    env.reset(0, 0).unwrap();
    assert_ne!(env.fixture_poses().unwrap(), seeded_poses_on_disk(1000));

    let specs = lerobot_specs(&d, 2);
    let run = d.join("run");
    let run_s = run.to_str().unwrap();
    ok(pipeline(&["run", specs.to_str().unwrap(), "--out", run_s, "--policy", "random"]));
    let rows = sql_rows(
        &run,
        "SELECT init_state_id, seed, protocol, max_steps, n_policy_steps, error_kind IS NULL, start_sha256 \
         FROM episodes ORDER BY init_state_id",
        &[],
    );
    assert_eq!(rows.len(), 2, "{rows:?}");
    for (k, row) in rows.iter().enumerate() {
        assert_eq!(
            row[..6],
            [k.to_string(), (1000 + k).to_string(), "lerobot".into(), "280".into(), "280".into(), "true".into()],
            "{row:?}"
        );
    }
    assert_ne!(rows[0][6], rows[1][6], "different seeds, different fixture poses, different starts");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["protocol"], "lerobot");
    assert_eq!(manifest["max_steps"], serde_json::json!({"libero_spatial": 280}));
    let stored_specs = read_batches(&run.join("specs.parquet"));
    assert_eq!(stored_specs[0].column_by_name("protocol").unwrap().as_string::<i32>().value(0), "lerobot");

    // The steps show the fixtures where the recorded poses put them (a fixture's root body hangs off
    // the world body, so its world pose is the pose applied).
    let fixtures: BTreeMap<String, String> = bundle
        .task
        .objects
        .iter()
        .filter(|(_, o)| o.fixture)
        .map(|(name, o)| (name.clone(), o.root_body.clone()))
        .collect();
    let recorded = seeded_poses_on_disk(1000);
    let mut seen = 0;
    let steps = std::fs::read_dir(run.join("steps"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.file_name().unwrap().to_str().unwrap().contains("-i000-s1000"));
    // (fixtures have no joint: every step of the episode shows them there)
    for b in read_batches(&steps.expect("episode 0's steps part")) {
        let list = b.column_by_name("object_poses").unwrap().as_list::<i32>();
        for row in 0..b.num_rows() {
            let poses = list.value(row);
            let poses = poses.as_struct();
            let names = poses.column_by_name("name").unwrap().as_string::<i32>();
            let pos = poses.column_by_name("pos").unwrap().as_fixed_size_list();
            for i in 0..poses.len() {
                let Some(body) = fixtures.get(names.value(i)) else { continue };
                let p = pos.value(i);
                let p = p.as_primitive::<Float64Type>().values();
                let expected = recorded[body].pos;
                let gap = (0..3).map(|j| (p[j] - expected[j]).abs()).fold(0.0, f64::max);
                assert!(gap < 1e-12, "step row {row}: {} at {p:?}, recorded {expected:?}", names.value(i));
                seen += 1;
            }
        }
    }
    assert!(seen > 0, "the task has fixtures");

    // A resume under the canonical protocol is refused, naming the difference.
    let canonical = d.join("canonical.parquet");
    ok(pipeline(&[
        "specs",
        "--suites",
        "libero_spatial",
        "--tasks",
        "4",
        "--trials",
        "1",
        "-o",
        canonical.to_str().unwrap(),
    ]));
    let refused = pipeline(&["run", canonical.to_str().unwrap(), "--out", run_s, "--policy", "random"]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && err.contains("another configuration") && err.contains("protocol"), "{err}");

    // A seed the set-up did not record is refused before any episode, naming the fix.
    let three = lerobot_specs(&d, 3);
    let refused =
        pipeline(&["run", three.to_str().unwrap(), "--out", d.join("run3").to_str().unwrap(), "--policy", "random"]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success(), "{err}");
    assert!(
        err.contains("seed 1002") && err.contains("./setup.sh --lerobot-fixtures") && err.contains("1000..=1001"),
        "{err}"
    );
    assert!(!d.join("run3/episodes").exists(), "no episode was started");
}

#[test]
fn a_protocol_column_must_be_one_known_protocol_and_canonical_means_the_old_rows() {
    let d = test_dir("lerobot_protocol", "column");
    let keys = |n: usize| -> Vec<(&str, ArrayRef)> {
        vec![
            ("suite", Arc::new(StringArray::from(vec!["libero_spatial"; n])) as ArrayRef),
            ("task_id", Arc::new(Int32Array::from(vec![4; n]))),
            ("init_state_id", Arc::new(Int32Array::from((0..n as i32).collect::<Vec<_>>()))),
            ("seed", Arc::new(Int64Array::from(vec![7; n]))),
        ]
    };
    let run = |specs: &Path, name: &str| {
        pipeline(&[
            "run",
            specs.to_str().unwrap(),
            "--out",
            d.join(name).to_str().unwrap(),
            "--policy",
            "random",
            "--max-steps",
            "3",
        ])
    };
    let with = |values: Vec<Option<&str>>| {
        let mut c = keys(values.len());
        c.push(("protocol", Arc::new(StringArray::from(values))));
        c
    };
    let mixed = write_specs(&d.join("mixed.parquet"), with(vec![Some("canonical"), Some("lerobot")]));
    let err = String::from_utf8_lossy(&run(&mixed, "mixed").stderr).into_owned();
    assert!(err.contains("mixes protocols") && err.contains("row 1 is lerobot"), "{err}");
    let unknown = write_specs(&d.join("unknown.parquet"), with(vec![Some("openvla"), Some("openvla")]));
    let err = String::from_utf8_lossy(&run(&unknown, "unknown").stderr).into_owned();
    assert!(err.contains("unknown protocol \"openvla\""), "{err}");

    // absent, null or "canonical": the same episodes, bit for bit
    let plain = write_specs(&d.join("plain.parquet"), keys(2));
    let named = write_specs(&d.join("named.parquet"), with(vec![Some("canonical"), None]));
    ok(run(&plain, "plain"));
    ok(run(&named, "named"));
    let q = "SELECT e.init_state_id, e.protocol, e.max_steps, e.start_sha256, s.step, s.eef_pos, s.object_poses \
             FROM episodes e JOIN steps s USING (episode_key) ORDER BY e.init_state_id, s.step";
    let a = sql_rows(&d.join("plain"), q, &[]);
    let b = sql_rows(&d.join("named"), q, &[]);
    assert_eq!(a.len(), 2 * (10 + 3));
    assert_eq!(a, b);
    assert_eq!(a[0][1], "canonical");
}
