//! A model served by vla-eval's own model server, evaluated through the whole pipeline on real
//! LIBERO episodes: `pipeline run --policy vla-eval:ws://...` against
//! `scripts/reference/vla_eval_dummy_server.py`, a dummy model on the PyPI package's
//! `PredictModelServer` + `serve_async` (its protocol, its msgpack/ndarray/PNG codec). The server
//! logs what its own decoder made of every observation and every action it sent; the test checks
//! that against the HELLO's observation params and the stored steps.

use libero_e2e::{LoggedServer, ok, pipeline, repo_root, spatial_task0_specs, sql_rows, test_dir};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

/// OpenVLA-OFT's `get_observation_params` (vla_eval/model_servers/oft.py, two images and proprio).
const OFT_PARAMS: &str = r#"{"env_seed": 0, "quat_no_antipodal": true, "send_wrist_image": true, "send_state": true}"#;
/// Wait steps before the first policy step (the protocol's, `--wait-steps` default).
const WAIT: usize = 10;

fn python() -> PathBuf {
    let venv = std::env::var_os("LIBERO_VLA_EVAL_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join(".vla-eval-venv"));
    let py = venv.join("bin/python");
    assert!(py.exists(), "no vla-eval venv at {}: run ./setup.sh --tests", venv.display());
    py
}

/// vla-eval's own model server with the dummy model: `params` its observation params (JSON),
/// `faults` the dummy's fault options.
fn start_server(dir: &Path, name: &str, port: u16, params: &str, faults: &[&str]) -> LoggedServer {
    let log = dir.join(format!("{name}.jsonl"));
    let args: Vec<&str> = ["--params", params].into_iter().chain(faults.iter().copied()).collect();
    LoggedServer::start(&python(), "scripts/reference/vla_eval_dummy_server.py", port, log, &args)
}

fn run(specs: &Path, run: &Path, url: &str) -> Output {
    let policy = format!("vla-eval:{url}");
    let (s, r) = (specs.to_str().unwrap(), run.to_str().unwrap());
    pipeline(&["run", s, "--out", r, "--policy", &policy, "--max-steps", "12", "--jobs", "1"])
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

fn parse(row: &[String]) -> Vec<f64> {
    row.iter().map(|x| x.parse().unwrap()).collect()
}

#[test]
fn a_vla_eval_served_model_gets_what_its_hello_asks_for_and_its_actions_are_stored() {
    let d = test_dir("vla-eval", "ok");
    let server = start_server(&d, "oft", 0, OFT_PARAMS, &[]);
    let specs = spatial_task0_specs(&d, "2");
    let out = d.join("run");
    ok(run(&specs, &out, &server.url()));
    let episodes = sql_rows(
        &out,
        "SELECT episode_key, n_policy_steps, COALESCE(error, 'none') FROM episodes ORDER BY episode_key",
        &[],
    );
    assert_eq!(episodes.len(), 2);
    assert!(episodes.iter().all(|e| e[1] == "12" && e[2] == "none"), "{episodes:?}");
    let instruction = sql_rows(&out, "SELECT DISTINCT instruction FROM episodes", &[]);
    let instruction = instruction[0][0].as_str();

    // What vla-eval's own decoder saw: per its HELLO, two PNG-coded 256x256 uint8 images, the
    // instruction, float64 states and float32 controller states on every step.
    let observations = server.events("observation");
    assert_eq!(observations.len(), 24);
    for o in &observations {
        assert_eq!(o["keys"], serde_json::json!(["controller_states", "images", "states", "task_description"]), "{o}");
        assert_eq!(o["image_formats"], serde_json::json!(["png", "png"]));
        for camera in ["agentview", "wrist"] {
            assert_eq!(o["images"][camera], serde_json::json!({"dtype": "|u1", "shape": [256, 256, 3]}), "{o}");
            assert!(
                o["image_sums"][camera].as_i64().unwrap() > 256 * 256 * 3 * 20,
                "a rendered, not a blank, image: {o}"
            );
        }
        assert_eq!(o["task_description"], instruction);
        assert_eq!((&o["states"]["dtype"], &o["states"]["shape"]), (&"<f8".into(), &serde_json::json!([8])));
        assert_eq!(o["controller_states"]["dtype"], "<f4");
    }
    let starts = server.events("episode_start");
    assert_eq!(starts.len(), 2);
    assert!(starts.iter().all(|s| s["payload"]["task"]["name"] == instruction), "{starts:?}");
    let ends: Vec<Value> = server.events("episode_end").iter().map(|e| e["payload"].clone()).collect();
    assert_eq!(ends, [serde_json::json!({"steps": 12}), serde_json::json!({"steps": 12})]);

    // Our steps, per episode: the state the server got at policy step p is the one after env step
    // WAIT + p - 1; the action stored at policy step p is the one the server sent, its gripper
    // binarised as vla-eval's LIBERO benchmark does.
    let rows = sql_rows(
        &out,
        "SELECT episode_key, eef_pos[1], eef_pos[2], eef_pos[3], gripper_qpos[1], gripper_qpos[2], \
         action[1], action[2], action[3], action[4], action[5], action[6], action[7] FROM steps ORDER BY episode_key, step",
        &[],
    );
    let mut ours: BTreeMap<String, Vec<Vec<f64>>> = BTreeMap::new();
    for r in &rows {
        ours.entry(r[0].clone()).or_default().push(parse(&r[1..]));
    }
    let actions = server.events("action");
    assert_eq!(actions.len(), 24);
    let mut signs = (0, 0);
    for (o, a) in observations.iter().zip(&actions) {
        assert_eq!(o["episode"], a["episode"]);
        let step = o["step"].as_u64().unwrap() as usize;
        let state = floats(&o["states"]["values"]);
        // the episode whose state after the previous env step is the one sent
        let (key, steps) = ours
            .iter()
            .find(|(_, s)| s[WAIT + step - 1][..3] == state[..3])
            .unwrap_or_else(|| panic!("no episode had eef_pos {:?} after env step {}", &state[..3], WAIT + step - 1));
        let before = &steps[WAIT + step - 1];
        assert_eq!(&state[6..8], &before[3..5], "{key} policy step {step}: gripper_qpos");
        let sent = floats(&a["actions"]);
        let stored = &steps[WAIT + step][5..12];
        for j in 0..6 {
            assert_eq!(stored[j] as f32, sent[j] as f32, "{key} policy step {step}: action[{j}]");
        }
        assert_eq!(stored[6], if sent[6] < 0.0 { -1.0 } else { 1.0 }, "{key} policy step {step}: gripper");
        if sent[6] < 0.0 { signs.1 += 1 } else { signs.0 += 1 }
    }
    assert!(signs.0 > 0 && signs.1 > 0, "both gripper signs exercised: {signs:?}");

    // The manifest records the server's HELLO; resuming against the same server is the same run.
    let identity = sql_rows(&out, "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    assert!(identity.contains("DummyModelServer") && identity.contains("quat_no_antipodal"), "{identity}");
    let again = run(&specs, &out, &server.url());
    assert!(again.status.success() && String::from_utf8_lossy(&again.stderr).contains("2 already finished"));

    // Another model server on the same address: the run refuses to resume, before any episode.
    let port = server.port;
    drop(server);
    let other = start_server(&d, "other", port, r#"{"send_wrist_image": true}"#, &[]);
    let refused = run(&specs, &out, &other.url());
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && stderr.contains("policy_identity"), "{stderr}");
    assert!(other.events("observation").is_empty());
}

#[test]
fn an_unreachable_server_fails_the_run_before_any_episode() {
    let d = test_dir("vla-eval", "unreachable");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let specs = spatial_task0_specs(&d, "1");
    let out = d.join("run");
    let t0 = Instant::now();
    let result = run(&specs, &out, &format!("ws://127.0.0.1:{port}"));
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(!result.status.success(), "{stderr}");
    assert!(stderr.contains(&format!("cannot connect to ws://127.0.0.1:{port}")), "{stderr}");
    assert!(t0.elapsed() < Duration::from_secs(30), "{:?}", t0.elapsed());
    let episodes = std::fs::read_dir(out.join("episodes")).map(|d| d.count()).unwrap_or(0);
    assert_eq!(episodes, 0);
}

#[test]
fn a_dropped_connection_and_a_model_error_are_error_rows_and_the_next_episode_reconnects() {
    // No observation params: agentview only, no state. Observation 6 (episode 0, policy step 5)
    // is dropped; observation 21 (episode 2, policy step 2) makes the model raise.
    let d = test_dir("vla-eval", "faults");
    let server = start_server(&d, "faults", 0, "{}", &["--drop-at", "6", "--error-at", "21"]);
    let specs = spatial_task0_specs(&d, "3");
    let out = d.join("run");
    let t0 = Instant::now();
    ok(run(&specs, &out, &server.url()));
    assert!(t0.elapsed() < Duration::from_secs(120), "{:?}", t0.elapsed());
    let rows = sql_rows(
        &out,
        "SELECT init_state_id, n_policy_steps, COALESCE(error_kind, 'none') FROM episodes ORDER BY init_state_id",
        &[],
    );
    assert_eq!(rows, [["0", "5", "policy"], ["1", "12", "none"], ["2", "2", "policy"]]);
    // The error texts: the drop as a dropped connection, the model's failure as the server's ERROR.
    let says = sql_rows(
        &out,
        "SELECT init_state_id, strpos(error, 'dropped') > 0, \
         strpos(error, 'observation_failed: RuntimeError: dummy model failure at observation 21') > 0 \
         FROM episodes WHERE error IS NOT NULL ORDER BY init_state_id",
        &[],
    );
    assert_eq!(says, [["0", "true", "false"], ["2", "false", "true"]]);
    let observations = server.events("observation");
    assert_eq!(observations.len(), 6 + 12 + 3);
    for o in &observations {
        assert_eq!(o["keys"], serde_json::json!(["images", "task_description"]), "{o}");
        assert_eq!(o["images"].as_object().unwrap().keys().collect::<Vec<_>>(), ["agentview"]);
    }
    // The episode after the drop ran on a new connection (a new server session).
    assert_ne!(observations[0]["session"], observations[6]["session"]);
}

#[test]
fn a_server_that_changes_its_hello_mid_run_fails_the_later_episodes() {
    // HELLO 1 is the run's identity (read at its start), HELLO 2 episode 0's connection; from
    // HELLO 3 on the server says it is another model.
    let d = test_dir("vla-eval", "swap");
    let server = start_server(&d, "swap", 0, "{}", &["--swap-after", "2"]);
    let specs = spatial_task0_specs(&d, "2");
    let out = d.join("run");
    ok(run(&specs, &out, &server.url()));
    let rows = sql_rows(
        &out,
        "SELECT init_state_id, n_policy_steps, COALESCE(error_kind, 'none'), \
         COALESCE(strpos(error, 'not the model this run started with') > 0, false) FROM episodes ORDER BY init_state_id",
        &[],
    );
    assert_eq!(rows, [["0", "12", "none", "false"], ["1", "0", "policy", "true"]]);
    assert_eq!(server.events("observation").len(), 12, "episode 1 sent nothing");
}
