//! A model served by starVLA's policy server, evaluated through the whole pipeline on real LIBERO
//! episodes: `pipeline run --policy starvla:ws://...` against `scripts/reference/starvla_toy_server.py`,
//! a toy policy behind starVLA's protocol (its routing and reply envelope, openpi-client's
//! msgpack-numpy, websockets) in both payload generations. The server logs what it decoded from
//! every request and the actions it sent; the test checks that against the stored steps.

use libero_e2e::{LoggedServer, ok, pipeline, repo_root, spatial_task0_specs, sql_rows, test_dir};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

/// Wait steps before the first policy step (`--wait-steps` default, both LIBERO loops' 10).
const WAIT: usize = 10;
/// Policy steps per episode (`--max-steps`).
const STEPS: usize = 12;

fn python() -> PathBuf {
    let venv =
        std::env::var_os("LIBERO_REMOTE_VENV").map(PathBuf::from).unwrap_or_else(|| repo_root().join(".remote-venv"));
    let py = venv.join("bin/python");
    assert!(py.exists(), "no remote-policy venv at {}: run ./setup.sh --tests", venv.display());
    py
}

/// The starVLA toy server, `args` its options.
fn start_server(dir: &Path, name: &str, port: u16, args: &[&str]) -> LoggedServer {
    let log = dir.join(format!("{name}.jsonl"));
    LoggedServer::start(&python(), "scripts/reference/starvla_toy_server.py", port, log, args)
}

fn run(specs: &Path, run: &Path, policy: &str) -> Output {
    let (s, r) = (specs.to_str().unwrap(), run.to_str().unwrap());
    let steps = STEPS.to_string();
    pipeline(&["run", s, "--out", r, "--policy", policy, "--max-steps", &steps, "--jobs", "1"])
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

/// Per episode (in init-state order: `--jobs 1` runs them in turn), its steps' eef_pos (3),
/// gripper_qpos (2) and action (7).
fn steps(out: &Path) -> Vec<Vec<Vec<f64>>> {
    let rows = sql_rows(
        out,
        "SELECT e.init_state_id, s.eef_pos[1], s.eef_pos[2], s.eef_pos[3], s.gripper_qpos[1], s.gripper_qpos[2], \
         s.action[1], s.action[2], s.action[3], s.action[4], s.action[5], s.action[6], s.action[7] \
         FROM steps s JOIN episodes e ON s.episode_key = e.episode_key ORDER BY e.init_state_id, s.step",
        &[],
    );
    let mut by: BTreeMap<u32, Vec<Vec<f64>>> = BTreeMap::new();
    for r in &rows {
        by.entry(r[0].parse().unwrap()).or_default().push(r[1..].iter().map(|x| x.parse().unwrap()).collect());
    }
    by.into_values().collect()
}

/// The infer requests, grouped by connection (session), in order.
fn by_session(server: &LoggedServer) -> Vec<Vec<Value>> {
    let mut sessions: BTreeMap<u64, Vec<Value>> = BTreeMap::new();
    for e in server.events("infer") {
        sessions.entry(e["session"].as_u64().unwrap()).or_default().push(e);
    }
    sessions.into_values().collect()
}

fn gripper(open: f64) -> f64 {
    if open > 0.5 { -1.0 } else { 1.0 }
}

/// Checks the two 224x224 uint8 images of a request, upright: rotated 180° from LIBERO's
/// upside-down render, the agentview's table (brighter) is in the lower half.
fn check_images(e: &Value) {
    let images = e["images"].as_array().unwrap();
    assert_eq!(images.len(), 2, "{e}");
    for im in images {
        assert_eq!((&im["dtype"], &im["shape"]), (&"|u1".into(), &serde_json::json!([224, 224, 3])), "{e}");
        assert!(im["sum"].as_i64().unwrap() > 224 * 224 * 3 * 20, "a rendered, not a blank, image: {e}");
    }
    let agentview = &images[0];
    assert!(
        agentview["bottom_mean"].as_f64().unwrap() > agentview["top_mean"].as_f64().unwrap(),
        "agentview upright (rot180 applied): {agentview}"
    );
}

#[test]
fn head_generation_actions_run_as_served_in_whole_chunks() {
    // action_chunk_size 5, 7 rows per reply: queries at policy steps 0, 5, 10; rows 5 and 6 unused.
    let d = test_dir("starvla", "head");
    let server = start_server(&d, "head", 0, &["--generation", "head", "--chunk", "5", "--predict", "7"]);
    let specs = spatial_task0_specs(&d, "2");
    let out = d.join("run");
    let policy = format!("starvla:{}?unnorm=franka", server.url());
    ok(run(&specs, &out, &policy));
    let episodes = sql_rows(&out, "SELECT n_policy_steps, COALESCE(error, 'none') FROM episodes", &[]);
    assert_eq!(episodes, [[STEPS.to_string(), "none".into()], [STEPS.to_string(), "none".into()]]);
    let instruction = sql_rows(&out, "SELECT DISTINCT instruction FROM episodes", &[]);
    let instruction = instruction[0][0].as_str();

    let sessions = by_session(&server);
    let ours = steps(&out);
    assert_eq!((sessions.len(), ours.len()), (2, 2), "one connection per episode");
    let mut grips = (0, 0);
    for (requests, steps) in sessions.iter().zip(&ours) {
        assert_eq!(requests.len(), 3, "queries at policy steps 0, 5, 10");
        for e in requests {
            check_images(e);
            assert_eq!(e["lang"], instruction);
            assert!(e["state"].is_null(), "HEAD's LIBERO loop sends no state: {e}");
            assert_eq!(e["unnorm_key"], "franka");
            assert_eq!(e["options"], serde_json::json!({"do_sample": false, "use_ddim": true, "num_ddim_steps": 10}));
        }
        for p in 0..STEPS {
            let sent = floats(&requests[p / 5]["actions"][p % 5]);
            let stored = &steps[WAIT + p][5..12];
            for j in 0..6 {
                assert_eq!(stored[j] as f32, sent[j] as f32, "policy step {p}: action[{j}]");
            }
            assert_eq!(stored[6], gripper(sent[6]), "policy step {p}: gripper");
            if stored[6] < 0.0 { grips.0 += 1 } else { grips.1 += 1 }
        }
    }
    assert!(grips.0 > 0 && grips.1 > 0, "both gripper states: {grips:?}");

    // The manifest records the metadata; resuming against the same server is the same run.
    // CSV-quoted JSON: quotes doubled
    let identity = sql_rows(&out, "SELECT policy_identity FROM manifest", &[]).concat().join(",").replace("\"\"", "\"");
    for says in ["starvla_policy_server", "action_chunk_size", "\"generation\":\"head\"", "resize224:pil-bilinear"] {
        assert!(identity.contains(says), "{says}: {identity}");
    }
    let again = run(&specs, &out, &policy);
    assert!(again.status.success() && String::from_utf8_lossy(&again.stderr).contains("2 already finished"));

    // Another model on the same address: the run refuses to resume, before any episode.
    let port = server.port;
    drop(server);
    let other = start_server(&d, "other", port, &["--generation", "head", "--chunk", "5", "--tag", "other"]);
    let refused = run(&specs, &out, &policy);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && stderr.contains("policy_identity"), "{stderr}");
    assert!(other.events("infer").is_empty());
}

/// VLA-JEPA's `M1Inference.unnormalize_actions` for one row, without a mask.
fn unnormalize(a: &[f64], min: &[f64; 7], max: &[f64; 7]) -> Vec<f64> {
    (0..7)
        .map(|j| {
            let mut x = a[j].clamp(-1.0, 1.0);
            if j == 6 {
                x = if x < 0.5 { 0.0 } else { 1.0 };
            }
            0.5 * (x + 1.0) * (max[j] - min[j]) + min[j]
        })
        .collect()
}

#[test]
fn legacy_generation_actions_are_unnormalised_here_from_the_stats_file() {
    // {"env": "simpler_env"}: normalised actions, 7 executed per query (policy steps 0 and 7).
    let d = test_dir("starvla", "legacy");
    let server = start_server(&d, "legacy", 0, &["--generation", "legacy", "--predict", "8"]);
    let specs = spatial_task0_specs(&d, "2");
    let (min, max) = ([-0.9, -0.8, -0.7, -0.2, -0.3, -0.4, 0.0], [0.9, 0.8, 0.95, 0.2, 0.3, 0.35, 1.0]);
    let stats = d.join("dataset_statistics.json");
    let (zeros, ones) = ([0.0; 7], [1.0; 7]);
    let json = serde_json::json!({
        "franka": {"action": {"min": min, "max": max, "mean": zeros, "std": ones}, "state": {}},
        "other": {"action": {"min": zeros, "max": ones}},
    });
    std::fs::write(&stats, json.to_string()).unwrap();

    // Before any episode: no stats, an unknown key, two keys and none chosen.
    let out = d.join("refused");
    for (policy, says) in [
        (format!("starvla:{}", server.url()), "stats=<path>".to_string()),
        (
            format!("starvla:{}?stats={}&unnorm=libero", server.url(), stats.display()),
            "no unnorm key \"libero\"".into(),
        ),
        (format!("starvla:{}?stats={}", server.url(), stats.display()), "franka, other".into()),
    ] {
        let refused = run(&specs, &out, &policy);
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert!(!refused.status.success() && stderr.contains(&says), "{policy}: {stderr}");
        let episodes = std::fs::read_dir(out.join("episodes")).map(|d| d.count()).unwrap_or(0);
        assert_eq!(episodes, 0, "{policy}");
    }
    assert!(server.events("infer").is_empty());

    let out = d.join("run");
    ok(run(&specs, &out, &format!("starvla:{}?unnorm=franka&stats={}", server.url(), stats.display())));
    let sessions = by_session(&server);
    let ours = steps(&out);
    assert_eq!((sessions.len(), ours.len()), (2, 2));
    let mut clipped = 0;
    for (requests, steps) in sessions.iter().zip(&ours) {
        assert_eq!(requests.len(), 2, "queries at policy steps 0 and 7");
        for (q, e) in requests.iter().enumerate() {
            check_images(e);
            assert_eq!(e["unnorm_key"], "franka");
            // the raw 8-D state, (1, 8) float64, as it was after the env step before the query
            let s = &e["state"];
            assert_eq!((&s["dtype"], &s["shape"]), (&"<f8".into(), &serde_json::json!([1, 8])), "{e}");
            let state = floats(&s["values"]);
            let before = &steps[WAIT + 7 * q - 1];
            assert_eq!((&state[..3], &state[6..8]), (&before[..3], &before[3..5]), "query {q}");
        }
        for p in 0..STEPS {
            let sent = floats(&requests[p / 7]["actions"][p % 7]);
            clipped += sent[..6].iter().filter(|x| x.abs() > 1.0).count();
            let expected = unnormalize(&sent, &min, &max);
            let stored = &steps[WAIT + p][5..12];
            for j in 0..6 {
                assert_eq!(stored[j] as f32, expected[j] as f32, "policy step {p}: action[{j}]");
            }
            assert_eq!(stored[6], gripper(expected[6]), "policy step {p}: gripper");
            assert_eq!(stored[6], if sent[6] >= 0.5 { -1.0 } else { 1.0 }, "policy step {p}");
        }
    }
    assert!(clipped > 0, "some normalised actions were outside [-1, 1]");
    // CSV-quoted JSON: quotes doubled
    let identity = sql_rows(&out, "SELECT policy_identity FROM manifest", &[]).concat().join(",").replace("\"\"", "\"");
    for says in ["simpler_env", "\"generation\":\"legacy\"", "resize224:cv2-area", "\"key\":\"franka\""] {
        assert!(identity.contains(says), "{says}: {identity}");
    }
}

#[test]
fn an_error_frame_and_a_drop_are_error_rows_and_the_next_episode_reconnects() {
    // Chunk 5: 3 requests per full episode. Request 2 (episode 0, policy step 5) is an error
    // envelope; request 4 (episode 1, policy step 5) is dropped; episode 2 runs whole.
    let d = test_dir("starvla", "faults");
    let server = start_server(&d, "faults", 0, &["--chunk", "5", "--error-at", "2", "--drop-at", "4"]);
    let specs = spatial_task0_specs(&d, "3");
    let out = d.join("run");
    let t0 = Instant::now();
    ok(run(&specs, &out, &format!("starvla:{}", server.url())));
    assert!(t0.elapsed() < Duration::from_secs(120), "{:?}", t0.elapsed());
    let rows = sql_rows(
        &out,
        "SELECT init_state_id, n_policy_steps, COALESCE(error_kind, 'none'), \
         COALESCE(strpos(error, 'toy policy failure at request 2') > 0, false), \
         COALESCE(strpos(error, 'dropped') > 0, false) FROM episodes ORDER BY init_state_id",
        &[],
    );
    assert_eq!(
        rows,
        [
            ["0", "5", "policy", "true", "false"],
            ["1", "5", "policy", "false", "true"],
            ["2", "12", "none", "false", "false"]
        ]
    );
    // Three connections with requests (one per episode), besides the identity's.
    let sessions: Vec<u64> = by_session(&server).iter().map(|s| s[0]["session"].as_u64().unwrap()).collect();
    assert_eq!(sessions.len(), 3, "{sessions:?}");
    assert_eq!(server.events("drop").len(), 1);
}

#[test]
fn a_server_whose_metadata_changes_mid_run_fails_the_later_episodes() {
    // Connection 0 is the run's identity, 1 episode 0's; from connection 2 on the server says it
    // is another model.
    let d = test_dir("starvla", "swap");
    let server = start_server(&d, "swap", 0, &["--chunk", "5", "--swap-after", "2"]);
    let specs = spatial_task0_specs(&d, "2");
    let out = d.join("run");
    ok(run(&specs, &out, &format!("starvla:{}", server.url())));
    let rows = sql_rows(
        &out,
        "SELECT init_state_id, n_policy_steps, COALESCE(error_kind, 'none'), \
         COALESCE(strpos(error, 'not the model this run started with') > 0, false) FROM episodes ORDER BY init_state_id",
        &[],
    );
    assert_eq!(rows, [["0", "12", "none", "false"], ["1", "0", "policy", "true"]]);
    assert_eq!(server.events("infer").len(), 3, "episode 1 sent nothing");
}

#[test]
fn an_unreachable_server_fails_the_run_before_any_episode() {
    let d = test_dir("starvla", "unreachable");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let specs = spatial_task0_specs(&d, "1");
    let out = d.join("run");
    let t0 = Instant::now();
    let result = run(&specs, &out, &format!("starvla:ws://127.0.0.1:{port}"));
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(!result.status.success(), "{stderr}");
    assert!(stderr.contains(&format!("cannot connect to ws://127.0.0.1:{port}")), "{stderr}");
    assert!(t0.elapsed() < Duration::from_secs(30), "{:?}", t0.elapsed());
    let episodes = std::fs::read_dir(out.join("episodes")).map(|d| d.count()).unwrap_or(0);
    assert_eq!(episodes, 0);
}
