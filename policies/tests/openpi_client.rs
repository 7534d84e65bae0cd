//! The openpi client against a real openpi-protocol server: `scripts/reference/openpi_toy_server.py`,
//! written with the PyPI `openpi-client` package's msgpack-numpy codec and `websockets`, with a
//! deterministic toy policy on the other side (its formula is `expected_chunk` below).
//!
//! Needs the venv of `scripts/setup/remote_policy_venv.sh`: `$LIBERO_REMOTE_VENV`, else
//! `<repo>/.remote-venv` (made by ./setup.sh --tests). Fails, never skips, when neither exists.

use libero_policies::remote::openpi::{LIBERO_REPLAN_STEPS, libero_request};
use libero_policies::remote::{OpenpiConfig, OpenpiConnection, OpenpiImages, OpenpiPolicy, RgbImage};
use libero_policies::{Action, Observation, Policy};
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

fn python() -> PathBuf {
    let venv = std::env::var_os("LIBERO_REMOTE_VENV").map(PathBuf::from).unwrap_or_else(|| repo().join(".remote-venv"));
    let py = venv.join("bin/python");
    assert!(
        py.exists(),
        "no remote-policy venv at {} ({} missing): run ./setup.sh --tests, or `bash scripts/setup/remote_policy_venv.sh DIR` and set LIBERO_REMOTE_VENV=DIR",
        venv.display(),
        py.display()
    );
    py
}

/// The toy server on a free port, killed on drop.
struct ToyServer {
    child: Child,
    url: String,
}

impl ToyServer {
    fn start(args: &[&str]) -> ToyServer {
        let mut child = Command::new(python())
            .arg(repo().join("scripts/reference/openpi_toy_server.py"))
            .args(["--port", "0"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start the toy server");
        let stdout = child.stdout.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(stdout).read_line(&mut line);
            let _ = tx.send(line);
        });
        let line = match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(line) => line,
            Err(_) => {
                let _ = child.kill();
                panic!("the toy server did not start within 60 s");
            }
        };
        let port: u16 = match line.trim().strip_prefix("listening on ").and_then(|p| p.parse().ok()) {
            Some(p) => p,
            None => {
                let _ = child.kill();
                panic!("the toy server said {line:?}, not `listening on <port>`");
            }
        };
        ToyServer { child, url: format!("ws://127.0.0.1:{port}") }
    }

    fn config(&self) -> OpenpiConfig {
        OpenpiConfig {
            connect_timeout: Duration::from_secs(10),
            request_timeout: Duration::from_secs(10),
            ..OpenpiConfig::new(&self.url)
        }
    }
}

impl Drop for ToyServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An observation that changes with `t`.
fn obs(t: u32) -> Observation {
    let s = t as f64;
    Observation {
        policy_step: t,
        eef_pos: [0.1 + 0.01 * s, -0.2, 1.0 - 0.001 * s],
        // a unit quaternion, (w, x, y, z), turning with t
        eef_quat: [(0.3 + 0.01 * s).cos(), (0.3 + 0.01 * s).sin(), 0.0, 0.0],
        gripper_qpos: [0.039 - 0.001 * s, -0.039 + 0.001 * s],
        ..Default::default()
    }
}

fn images() -> OpenpiImages {
    let img = |seed: u8| RgbImage {
        height: 224,
        width: 224,
        rgb: (0..224 * 224 * 3).map(|i| (i as u8).wrapping_mul(seed)).collect(),
    };
    OpenpiImages { image: img(3), wrist_image: img(7) }
}

/// The toy policy's formula (openpi_toy_server.py `toy_actions`), in the same f64 order, cast
/// to f32 as the server's `.astype(np.float32)`.
fn expected_chunk(o: &Observation, prompt: &str, images: Option<&OpenpiImages>, chunk: usize) -> Vec<Action> {
    let state = libero_policies::remote::openpi::libero_state(o);
    let image_term = images.map_or(0.0, |im| {
        let wrist_last = im.wrist_image.rgb[im.wrist_image.rgb.len() - 1];
        (im.image.rgb[0] as i64 + wrist_last as i64) as f64 / 1000.0
    });
    (0..chunk)
        .map(|i| {
            std::array::from_fn(|j| {
                let base = state[j] + 0.5 * state[7] + 0.001 * prompt.len() as f64 + image_term;
                (base + 0.01 * (i as f64 + 1.0)) as f32
            })
        })
        .collect()
}

const PROMPT: &str = "pick up the black bowl between the plate and the ramekin and place it on the plate";

#[test]
fn the_metadata_is_read_first_and_recorded_in_the_identity() {
    let server = ToyServer::start(&[]);
    let policy = OpenpiPolicy::connect(server.config()).unwrap();
    assert_eq!(
        policy.metadata(),
        &serde_json::json!({
            "name": "toy", "action_horizon": 10, "action_dim": 7,
            "scale": {"dtype": "<f4", "shape": [2], "values": [0.5, 0.01f32 as f64]},
        })
    );
    let id = policy.identity();
    assert_eq!(id["server_metadata"], *policy.metadata());
    assert_eq!(id["chunking"], serde_json::json!({"predicted": 10, "executed": LIBERO_REPLAN_STEPS}));
    assert_eq!(id["url"], server.url.as_str());
    assert_eq!(
        id["request"]["keys"],
        serde_json::json!(["observation/image", "observation/wrist_image", "observation/state", "prompt"])
    );
}

#[test]
fn the_actions_are_the_toy_function_of_what_we_sent() {
    let server = ToyServer::start(&[]);
    let cfg = server.config();
    let mut conn = OpenpiConnection::connect(&cfg.url, None, cfg.connect_timeout, cfg.request_timeout).unwrap();
    let im = images();
    for (t, with_images) in [(0, false), (7, true)] {
        let o = obs(t);
        let reply = conn.infer(&libero_request(&o, PROMPT, with_images.then_some(&im))).unwrap();
        let chunk = libero_policies::remote::openpi::actions_of::<7>(&reply).unwrap();
        assert_eq!(chunk, expected_chunk(&o, PROMPT, with_images.then_some(&im), 10));
        // the server saw our keys and our prompt as str, and decoded our arrays (it checks their
        // dtypes and shapes and would have failed otherwise)
        let echo = libero_policies::remote::msgpack_numpy::to_json(&reply)["echo"].clone();
        let keys: &[&str] = if with_images {
            &["observation/image", "observation/state", "observation/wrist_image", "prompt"]
        } else {
            &["observation/state", "prompt"]
        };
        assert_eq!(echo, serde_json::json!({"prompt": PROMPT, "keys": keys}));
    }
    // through the Policy: the first action of the chunk
    let mut policy = OpenpiPolicy::connect(server.config()).unwrap();
    policy.reset(PROMPT, 0);
    assert_eq!(policy.act_with_images(&obs(3), Some(&im)).unwrap(), expected_chunk(&obs(3), PROMPT, Some(&im), 10)[0]);
    policy.reset("x", 0);
    assert_eq!(policy.act(&obs(4)).unwrap(), expected_chunk(&obs(4), "x", None, 10)[0]);
}

#[test]
fn replan_steps_executes_the_first_k_actions_of_each_chunk_and_asks_again() {
    let server = ToyServer::start(&["--chunk", "10"]);
    let mut policy = OpenpiPolicy::connect(OpenpiConfig { replan_steps: 3, ..server.config() }).unwrap();
    for episode in 0..2 {
        policy.reset(PROMPT, episode);
        for t in 0..8u32 {
            // the chunk comes from the observation of the step that asked: t - t % 3
            let asked = t - t % 3;
            let want = expected_chunk(&obs(asked), PROMPT, None, 10)[(t % 3) as usize];
            assert_eq!(policy.act(&obs(t)).unwrap(), want, "episode {episode}, step {t}");
            assert_eq!(policy.queries(), (t / 3 + 1) as u64);
        }
        assert_eq!(policy.last_predicted(), Some(10));
    }
    // a chunk shorter than replan_steps fails as openpi's example asserts
    let short = ToyServer::start(&["--chunk", "2"]);
    let mut policy = OpenpiPolicy::connect(short.config()).unwrap();
    policy.reset(PROMPT, 0);
    let e = policy.act(&obs(0)).unwrap_err().to_string();
    assert!(e.contains("predicted 2 actions, fewer than replan_steps = 5"), "{e}");
}

#[test]
fn a_late_reply_is_an_error_within_the_timeout_and_the_next_episode_reconnects() {
    let server = ToyServer::start(&["--delay-at", "2", "--delay-s", "5"]);
    let timeout = Duration::from_millis(500);
    let mut policy =
        OpenpiPolicy::connect(OpenpiConfig { replan_steps: 1, request_timeout: timeout, ..server.config() }).unwrap();
    policy.reset(PROMPT, 0);
    policy.act(&obs(0)).unwrap();
    let t0 = Instant::now();
    let e = policy.act(&obs(1)).unwrap_err().to_string();
    let elapsed = t0.elapsed();
    eprintln!("timeout error after {elapsed:?}: {e}");
    assert!(e.contains("no reply") && e.contains("within 500ms"), "{e}");
    assert!(elapsed >= timeout && elapsed < timeout + Duration::from_secs(1), "{elapsed:?}");
    // the next episode reconnects; the late reply of request 2 is never taken for request 3's
    policy.reset(PROMPT, 1);
    assert_eq!(policy.act(&obs(9)).unwrap(), expected_chunk(&obs(9), PROMPT, None, 10)[0]);
}

#[test]
fn a_dropped_connection_is_an_error_and_the_next_episode_reconnects() {
    let server = ToyServer::start(&["--drop-at", "2"]);
    let mut policy = OpenpiPolicy::connect(OpenpiConfig { replan_steps: 1, ..server.config() }).unwrap();
    policy.reset(PROMPT, 0);
    policy.act(&obs(0)).unwrap();
    let t0 = Instant::now();
    let e = policy.act(&obs(1)).unwrap_err().to_string();
    eprintln!("drop error after {:?}: {e}", t0.elapsed());
    assert!(e.contains("dropped"), "{e}");
    assert!(t0.elapsed() < Duration::from_secs(5));
    policy.reset(PROMPT, 1);
    assert_eq!(policy.act(&obs(2)).unwrap(), expected_chunk(&obs(2), PROMPT, None, 10)[0]);
    // a dead server: every query fails at once (connection refused), no hang
    drop(server);
    policy.reset(PROMPT, 2);
    let e = policy.act(&obs(3)).unwrap_err().to_string();
    assert!(e.contains("dropped") || e.contains("cannot connect"), "{e}");
    policy.reset(PROMPT, 3);
    let e = policy.act(&obs(3)).unwrap_err().to_string();
    assert!(e.contains("cannot connect"), "{e}");
}

#[test]
fn a_server_side_error_is_an_error_with_its_traceback() {
    let server = ToyServer::start(&["--error-at", "1"]);
    let mut policy = OpenpiPolicy::connect(server.config()).unwrap();
    policy.reset(PROMPT, 0);
    let e = policy.act(&obs(0)).unwrap_err().to_string();
    assert!(e.starts_with("policy openpi: the policy server at ws://127.0.0.1:"), "{e}");
    assert!(e.contains("RuntimeError: toy policy failure at request 1"), "{e}");
}

#[test]
fn malformed_replies_are_errors() {
    for (kind, says) in
        [("garbage", "not MessagePack"), ("no-actions", "no \"actions\""), ("wrong-shape", "shape [10, 6]")]
    {
        let server = ToyServer::start(&["--bad-reply-at", "1", "--bad-reply", kind]);
        let mut policy = OpenpiPolicy::connect(server.config()).unwrap();
        policy.reset(PROMPT, 0);
        let e = policy.act(&obs(0)).unwrap_err().to_string();
        assert!(e.contains("malformed reply") && e.contains(says), "{kind}: {e}");
    }
}

#[test]
fn a_server_that_never_answers_the_handshake_times_out_and_a_closed_port_is_refused() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("ws://{}", listener.local_addr().unwrap());
    let timeout = Duration::from_millis(400);
    let t0 = Instant::now();
    let e = OpenpiPolicy::connect(OpenpiConfig { connect_timeout: timeout, ..OpenpiConfig::new(&url) })
        .unwrap_err()
        .to_string();
    let elapsed = t0.elapsed();
    eprintln!("handshake timeout after {elapsed:?}: {e}");
    assert!(e.contains("websocket handshake") && e.contains("within 400ms"), "{e}");
    assert!(elapsed >= timeout && elapsed < timeout + Duration::from_secs(1), "{elapsed:?}");
    drop(listener);
    let e = OpenpiPolicy::connect(OpenpiConfig::new(&url)).unwrap_err().to_string();
    assert!(e.contains("cannot connect"), "{e}");
    let e = OpenpiPolicy::connect(OpenpiConfig::new("wss://example.org:443")).unwrap_err().to_string();
    assert!(e.contains("only ws://"), "{e}");
}
