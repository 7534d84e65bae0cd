//! [`VlaEvalPolicy`]: a model served by vla-eval's model server (PyPI `vla-eval` 0.8.0: OFT,
//! openpi π0/π0.5, lerobot, GR00T, X-VLA, starVLA, ... behind one protocol), evaluated as
//! vla-eval's own LIBERO benchmark client feeds it.
//!
//! **Protocol** (`vla_eval/protocol/messages.py`, `model_servers/serve.py`, `connection.py`):
//! every frame is one binary msgpack map `{"type", "payload", "seq", "timestamp"}` (all four
//! required), `type` one of `hello`, `episode_start`, `observation`, `action`, `episode_end`,
//! `error`. The client speaks first: HELLO `{harness_version, protocol_version: 1, benchmark}`; the
//! server answers HELLO `{harness_version, protocol_version, model_server, capabilities,
//! observation_params?, action_spec?, observation_spec?}`. Per episode: EPISODE_START
//! `{"task": {...}}` (no reply), then per env step one OBSERVATION answered by one ACTION (the
//! server echoes the observation's `seq`), then EPISODE_END (no reply). A model failure is an
//! ERROR frame `{"error": "observation_failed: ..."}` and the connection stays open. Action
//! chunking is the server's (`PredictModelServer` pops one action of its chunk per observation).
//!
//! **Codec** (`protocol/numpy_codec.py`, `image_codec.py`): arrays are maps with **string** keys
//! `{"__ndarray__": True, "data", "dtype", "shape"}` (not openpi's bin keys); HWC uint8 arrays
//! with 1/3/4 channels go as `{"__image__": True, "format": "png", "data": <PNG>, "shape"}` (PNG
//! is the default and nothing in the package changes it).
//!
//! **What is sent** (`benchmarks/libero/benchmark.py`, `LIBEROBenchmark.make_obs`), honouring the
//! server's `observation_params` ([`ObservationParams`]):
//!
//! | key | value |
//! |---|---|
//! | `images.agentview` | the 256² render rotated 180° (`img[::-1, ::-1]`, no resize), PNG |
//! | `images.wrist` | `robot0_eye_in_hand` the same way, when `send_wrist_image` |
//! | `task_description` | the task's language instruction |
//! | `states` | when `send_state`: float64 (8,): eef pos, axis-angle of `robot0_eef_quat` (float32-rounded; antipodal-normalised unless `quat_no_antipodal`), finger joints |
//! | `controller_states` | when `send_state`: float32 (8,): the controller's eef pose (grip site), axis-angle (normalised), finger joints |
//!
//! **What is executed** (`LIBEROBenchmark.step`): the reply's `actions` (or `action`), exactly
//! 7 numbers; the gripper binarised (`< 0` → -1, else +1); that is the action returned (and
//! stored).

use super::client::{RemoteError, WsConnection};
use super::msgpack_numpy::{self, NdArray};
use crate::{Action, Observation, Policy, PolicyError};
use rmpv::Value;
use std::time::{Duration, Instant};

const NAME: &str = "vla-eval";
/// `PROTOCOL_VERSION` of `vla_eval/protocol/messages.py`.
pub const PROTOCOL_VERSION: i64 = 1;
/// `LIBERO_ENV_RESOLUTION` of vla-eval's LIBERO benchmark: the camera renders, sent unresized.
pub const LIBERO_RENDER_SIZE: u32 = 256;
/// The benchmark named in our HELLO (vla-eval's orchestrator sends its config's import string).
pub const BENCHMARK: &str = "vla_eval.benchmarks.libero.benchmark:LIBEROBenchmark";

/// How to reach the server.
#[derive(Debug, Clone, PartialEq)]
pub struct VlaEvalConfig {
    /// `ws://host:port`.
    pub url: String,
    /// TCP connect + websocket handshake + the HELLO exchange.
    pub connect_timeout: Duration,
    /// One observation and its action.
    pub request_timeout: Duration,
}

impl VlaEvalConfig {
    /// 30 s to connect (vla-eval's `Connection` default timeout), 60 s per request (as openpi's
    /// client here: a first call may compile).
    pub fn new(url: impl Into<String>) -> Self {
        VlaEvalConfig {
            url: url.into(),
            connect_timeout: Duration::from_secs(30),
            request_timeout: Duration::from_secs(60),
        }
    }
}

/// The server's `observation_params` (HELLO), as `LIBEROBenchmark.__init__` takes them.
///
/// vla-eval merges them into the benchmark's constructor arguments, the eval config winning, and
/// drops (with a warning) keys the constructor does not take. Here: `send_wrist_image`,
/// `send_state`, `quat_no_antipodal` are honoured; `absolute_action: true` is refused (this
/// pipeline drives the delta controller only); `suite`, `seed`, `env_seed`, `num_steps_wait`,
/// `max_steps` are fixed by our run (spec table, `--wait-steps`, `--max-steps`): the eval config
/// wins, as in vla-eval; other keys are not LIBERO's and are ignored, as vla-eval ignores them.
/// All of them stay in the identity (the whole HELLO is recorded).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ObservationParams {
    pub send_wrist_image: bool,
    pub send_state: bool,
    pub quat_no_antipodal: bool,
}

impl ObservationParams {
    /// From the HELLO reply's payload (as JSON); an absent or empty `observation_params` gives the
    /// benchmark's defaults (agentview only, no state).
    pub fn from_hello(hello: &serde_json::Value) -> Result<Self, String> {
        let mut p = ObservationParams::default();
        let params = match hello.get("observation_params") {
            None | Some(serde_json::Value::Null) => return Ok(p),
            Some(serde_json::Value::Object(m)) => m,
            Some(other) => return Err(format!("observation_params is not a map: {other}")),
        };
        for (key, value) in params {
            let flag =
                || value.as_bool().ok_or_else(|| format!("observation_params.{key} = {value}, expected true or false"));
            match key.as_str() {
                "send_wrist_image" => p.send_wrist_image = flag()?,
                "send_state" => p.send_state = flag()?,
                "quat_no_antipodal" => p.quat_no_antipodal = flag()?,
                "absolute_action" if flag()? => {
                    return Err("the server asks for absolute_action = true (world-frame eef targets); this pipeline drives LIBERO's delta controller only".into());
                }
                _ => {}
            }
        }
        Ok(p)
    }
}

/// vla-eval's `rotation.quat_to_axisangle` for an (x, y, z, w) quaternion, operation for
/// operation: `q = -q` when `w < 0`, `w` clipped to [-1, 1], zeros when `sqrt(1 - w²) < 1e-8`, else
/// `q[:3] / sqrt(1 - w²) * 2·acos(w)` (the package then rounds to float32).
pub fn quat_to_axisangle(quat_xyzw: [f64; 4]) -> [f64; 3] {
    let q = if quat_xyzw[3] < 0.0 { quat_xyzw.map(|v| -v) } else { quat_xyzw };
    let w = q[3].clamp(-1.0, 1.0);
    let sin_half = (1.0 - w * w).sqrt();
    if sin_half < 1e-8 {
        return [0.0; 3];
    }
    let angle = 2.0 * w.acos();
    [q[0] / sin_half * angle, q[1] / sin_half * angle, q[2] / sin_half * angle]
}

fn f32_round(v: [f64; 3]) -> [f64; 3] {
    v.map(|x| x as f32 as f64)
}

/// `states` of `LIBEROBenchmark._proprio_state`: eef position, the axis-angle of
/// `robot0_eef_quat` ([`Observation::hand_quat`]) rounded to float32 as the package's conversions
/// return it, the finger joints; float64.
pub fn libero_states(obs: &Observation, quat_no_antipodal: bool) -> [f64; 8] {
    let q = crate::preprocess::proprio::wxyz_to_xyzw(obs.hand_quat);
    let aa = f32_round(if quat_no_antipodal { crate::preprocess::quat2axisangle(q) } else { quat_to_axisangle(q) });
    let (p, g) = (obs.eef_pos, obs.gripper_qpos);
    [p[0], p[1], p[2], aa[0], aa[1], aa[2], g[0], g[1]]
}

/// `controller_states`: the OSC controller's eef position and orientation (robosuite's grip site,
/// [`Observation::eef_pos`], [`Observation::eef_quat`]) as normalised axis-angle, the finger
/// joints; float32. robosuite's controller holds the pose of its last update, which may lag the
/// observation by a physics substep (not measured); we send the pose after the step.
pub fn controller_states(obs: &Observation) -> [f32; 8] {
    let aa = quat_to_axisangle(crate::preprocess::proprio::wxyz_to_xyzw(obs.eef_quat));
    let (p, g) = (obs.eef_pos, obs.gripper_qpos);
    [p[0], p[1], p[2], aa[0], aa[1], aa[2], g[0], g[1]].map(|v| v as f32)
}

/// An array in vla-eval's codec: string keys.
pub fn ndarray_value(a: &NdArray) -> Value {
    Value::Map(vec![
        (Value::from("__ndarray__"), Value::Boolean(true)),
        (Value::from("data"), Value::Binary(a.data.clone())),
        (Value::from("dtype"), Value::from(a.dtype.as_str())),
        (Value::from("shape"), Value::Array(a.shape.iter().map(|&d| Value::from(d)).collect())),
    ])
}

/// A camera image as vla-eval's LIBERO client sends it: rotated 180° (`img[::-1, ::-1]`, which
/// is the pixel order reversed) and PNG-encoded in the image codec's map.
pub fn image_value(cam: &crate::CameraImage) -> Result<Value, String> {
    let (w, h) = (cam.width as usize, cam.height as usize);
    if cam.rgb.len() != w * h * 3 || w == 0 || h == 0 {
        return Err(format!("camera image {}x{} has {} bytes", cam.width, cam.height, cam.rgb.len()));
    }
    let rotated: Vec<u8> = cam.rgb.chunks_exact(3).rev().flatten().copied().collect();
    let mut png_bytes = Vec::with_capacity(rotated.len() / 2);
    let mut encoder = png::Encoder::new(&mut png_bytes, cam.width, cam.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    // Lossless either way; the fast deflate keeps two 256² images per step cheap.
    encoder.set_compression(png::Compression::Fast);
    let mut writer = encoder.write_header().map_err(|e| format!("PNG: {e}"))?;
    writer.write_image_data(&rotated).map_err(|e| format!("PNG: {e}"))?;
    writer.finish().map_err(|e| format!("PNG: {e}"))?;
    Ok(Value::Map(vec![
        (Value::from("__image__"), Value::Boolean(true)),
        (Value::from("format"), Value::from("png")),
        (Value::from("data"), Value::Binary(png_bytes)),
        (Value::from("shape"), Value::Array(vec![Value::from(h), Value::from(w), Value::from(3)])),
    ]))
}

/// The OBSERVATION payload of `LIBEROBenchmark.make_obs`.
pub fn observation_payload(obs: &Observation, instruction: &str, params: ObservationParams) -> Result<Value, String> {
    let cams = obs.images.as_ref().ok_or("no camera images for this step (the rollout rendered none)")?;
    let mut images = vec![(Value::from("agentview"), image_value(&cams.agentview)?)];
    if params.send_wrist_image {
        images.push((Value::from("wrist"), image_value(&cams.wrist)?));
    }
    let mut map =
        vec![(Value::from("images"), Value::Map(images)), (Value::from("task_description"), Value::from(instruction))];
    if params.send_state {
        let s = libero_states(obs, params.quat_no_antipodal);
        map.push((Value::from("states"), ndarray_value(&NdArray::from_f64(&[8], &s))));
        map.push((Value::from("controller_states"), ndarray_value(&NdArray::from_f32(&[8], &controller_states(obs)))));
    }
    Ok(Value::Map(map))
}

/// The action of an ACTION payload as `LIBEROBenchmark.step` executes it: `actions` (else
/// `action`), exactly 7 numbers (a (7,) array or a list), gripper binarised `< 0` → -1, else +1.
pub fn action_of(payload: &Value) -> Result<Action, String> {
    let map = payload.as_map().ok_or("the action payload is not a map")?;
    let v = msgpack_numpy::get(map, b"actions").or_else(|| msgpack_numpy::get(map, b"action")).ok_or_else(|| {
        let keys: Vec<String> = map.iter().map(|(k, _)| msgpack_numpy::to_json(k).to_string()).collect();
        format!("the action has no \"actions\" (keys: {})", keys.join(", "))
    })?;
    let values: Vec<f64> = match NdArray::from_value(v).map_err(|e| e.0)? {
        Some(a) if a.shape.len() == 1 => a.to_f64().map_err(|e| e.0)?,
        Some(a) => return Err(format!("\"actions\" has shape {:?}, expected (7,)", a.shape)),
        None => match v {
            Value::Array(items) => items
                .iter()
                .map(|x| x.as_f64().or_else(|| x.as_i64().map(|i| i as f64)))
                .collect::<Option<Vec<f64>>>()
                .ok_or_else(|| format!("\"actions\" is a list of non-numbers: {v}"))?,
            other => return Err(format!("\"actions\" is neither an array nor a list: {other}")),
        },
    };
    if values.len() != 7 {
        return Err(format!("\"actions\" has {} values, expected 7", values.len()));
    }
    let gripper = if values[6] < 0.0 { -1.0 } else { 1.0 };
    Ok(std::array::from_fn(|j| if j == 6 { gripper } else { values[j] as f32 }))
}

/// One frame: `{"type", "payload", "seq", "timestamp"}`.
pub fn frame(kind: &str, payload: Value, seq: u64) -> Value {
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
    Value::Map(vec![
        (Value::from("type"), Value::from(kind)),
        (Value::from("payload"), payload),
        (Value::from("seq"), Value::from(seq)),
        (Value::from("timestamp"), Value::F64(now)),
    ])
}

/// A received frame's type, payload and seq; the four keys are required, as `unpack_message`
/// requires them.
pub fn parse_frame(v: &Value) -> Result<(String, Value, i64), String> {
    let map = v.as_map().ok_or("the message is not a map")?;
    let field = |k: &str| msgpack_numpy::get(map, k.as_bytes()).ok_or_else(|| format!("the message has no {k:?}"));
    let kind = field("type")?.as_str().ok_or("the message type is not a string")?.to_string();
    if !["hello", "observation", "action", "episode_start", "episode_end", "error"].contains(&kind.as_str()) {
        return Err(format!("unknown message type {kind:?}"));
    }
    let payload = field("payload")?.clone();
    let seq = field("seq")?.as_i64().ok_or("the message seq is not an integer")?;
    field("timestamp")?;
    Ok((kind, payload, seq))
}

/// A connection after the HELLO exchange: the server's HELLO payload, our frame counter.
#[derive(Debug)]
pub struct VlaEvalConnection {
    ws: WsConnection,
    hello: Value,
    seq: u64,
}

impl VlaEvalConnection {
    /// Connects and exchanges HELLOs within `config.connect_timeout`.
    pub fn connect(config: &VlaEvalConfig) -> Result<Self, RemoteError> {
        let (ws, deadline) = WsConnection::connect(&config.url, None, config.connect_timeout, config.request_timeout)?;
        let mut conn = VlaEvalConnection { ws, hello: Value::Nil, seq: 0 };
        let hello = Value::Map(vec![
            (Value::from("harness_version"), Value::from(concat!("libero-pipeline ", env!("CARGO_PKG_VERSION")))),
            (Value::from("protocol_version"), Value::from(PROTOCOL_VERSION)),
            (Value::from("benchmark"), Value::from(BENCHMARK)),
        ]);
        let seq = conn.next_seq();
        conn.ws.send(&frame("hello", hello, seq), deadline, config.connect_timeout, "sending HELLO")?;
        let reply = conn.ws.receive(deadline, config.connect_timeout, "waiting for the server's HELLO")?;
        conn.hello = match conn.parse(&reply, "waiting for the server's HELLO")? {
            (kind, payload, _) if kind == "hello" && payload.is_map() => payload,
            (kind, payload, _) => {
                return Err(conn.ws.malformed_reply(
                    "waiting for the server's HELLO",
                    format!("expected a HELLO with a map payload, got {kind} {payload}"),
                ));
            }
        };
        Ok(conn)
    }

    /// The server's HELLO payload.
    pub fn hello(&self) -> &Value {
        &self.hello
    }

    pub fn is_open(&self) -> bool {
        self.ws.is_open()
    }

    fn next_seq(&mut self) -> u64 {
        self.seq += 1;
        self.seq
    }

    fn parse(&mut self, v: &Value, during: &'static str) -> Result<(String, Value, i64), RemoteError> {
        parse_frame(v).map_err(|e| self.ws.malformed_reply(during, e))
    }

    /// Sends a frame that has no reply (EPISODE_START, EPISODE_END).
    pub fn notify(&mut self, kind: &str, payload: Value, during: &'static str) -> Result<(), RemoteError> {
        let seq = self.next_seq();
        let timeout = self.ws.request_timeout();
        self.ws.send(&frame(kind, payload, seq), Instant::now() + timeout, timeout, during)
    }

    /// One OBSERVATION and its ACTION payload. An ERROR frame is the server's error (the
    /// connection stays open, as the server keeps it); an ACTION for another `seq` is refused.
    pub fn act(&mut self, observation: Value) -> Result<Value, RemoteError> {
        let seq = self.next_seq();
        let reply = self.ws.request(
            &frame("observation", observation, seq),
            "sending the observation",
            "waiting for the action",
        )?;
        match self.parse(&reply, "waiting for the action")? {
            (kind, payload, _) if kind == "error" => {
                let message = payload
                    .as_map()
                    .and_then(|m| msgpack_numpy::get(m, b"error"))
                    .and_then(Value::as_str)
                    .map_or_else(|| msgpack_numpy::to_json(&payload).to_string(), str::to_string);
                Err(RemoteError::Server { url: self.ws.url().to_string(), message })
            }
            (kind, payload, s) if kind == "action" && s == seq as i64 => Ok(payload),
            (kind, _, s) => Err(self.ws.malformed_reply(
                "waiting for the action",
                format!("expected the ACTION for observation seq {seq}, got {kind} with seq {s}"),
            )),
        }
    }
}

/// A model served by vla-eval's model server. One instance, one connection (each rollout worker
/// makes its own); the connection persists across episodes, as vla-eval's orchestrator keeps it,
/// and after a failure the next episode reconnects (the server must send the same HELLO again).
#[derive(Debug)]
pub struct VlaEvalPolicy {
    config: VlaEvalConfig,
    conn: Option<VlaEvalConnection>,
    /// The HELLO payload of the first connection, as JSON (the identity; checked on reconnect).
    hello: serde_json::Value,
    params: ObservationParams,
    instruction: String,
    /// EPISODE_START was sent on the current connection for the current episode.
    started: bool,
    steps: u64,
}

impl VlaEvalPolicy {
    /// Connects, exchanges HELLOs and reads the server's observation params (refusing ones it
    /// cannot honour), all before any episode.
    pub fn connect(config: VlaEvalConfig) -> Result<Self, PolicyError> {
        let conn = VlaEvalConnection::connect(&config).map_err(remote_error)?;
        let hello = msgpack_numpy::to_json(conn.hello());
        super::client::same_server("HELLO", &config.url, &hello).map_err(error)?;
        let params =
            ObservationParams::from_hello(&hello).map_err(|e| error(format!("the server at {}: {e}", config.url)))?;
        Ok(VlaEvalPolicy {
            config,
            conn: Some(conn),
            hello,
            params,
            instruction: String::new(),
            started: false,
            steps: 0,
        })
    }

    /// The server's HELLO payload, as JSON.
    pub fn hello(&self) -> &serde_json::Value {
        &self.hello
    }

    pub fn params(&self) -> ObservationParams {
        self.params
    }

    /// Identity for the run manifest: the server's whole HELLO (its vla-eval version, model server
    /// class, observation params and specs) and what this client sends for it.
    pub fn identity(&self) -> serde_json::Value {
        let p = self.params;
        let quat = if p.quat_no_antipodal {
            "robosuite quat2axisangle (no antipodal normalisation, quat_no_antipodal)"
        } else {
            "vla-eval rotation.quat_to_axisangle (antipodal-normalised, w >= 0)"
        };
        serde_json::json!({
            "kind": "remote",
            "name": NAME,
            "url": self.config.url,
            "protocol": format!("vla-eval model-server protocol {PROTOCOL_VERSION}: msgpack {{type, payload, seq, timestamp}}; HELLO exchange, EPISODE_START/END, one OBSERVATION -> one ACTION (7,) per step; action chunks are the server's"),
            "server_hello": self.hello,
            "observation_params_applied": {
                "send_wrist_image": p.send_wrist_image, "send_state": p.send_state, "quat_no_antipodal": p.quat_no_antipodal,
            },
            "observation_params_not_applied": "suite, seed, env_seed, num_steps_wait, max_steps: the run's (spec table, --wait-steps, --max-steps); keys LIBEROBenchmark does not take: ignored, as vla-eval drops them",
            "request": {
                "images": {
                    "agentview": format!("{LIBERO_RENDER_SIZE}x{LIBERO_RENDER_SIZE} render, rot180, uint8 HWC, PNG"),
                    "wrist": p.send_wrist_image.then(|| format!("{LIBERO_RENDER_SIZE}x{LIBERO_RENDER_SIZE} render, rot180, uint8 HWC, PNG")),
                    "render": "look mujoco-3.2.3",
                },
                "task_description": "the task's language instruction",
                "states": p.send_state.then(|| format!("float64 (8,): eef_pos, {quat} of robot0_eef_quat rounded to float32, gripper_qpos")),
                "controller_states": p.send_state.then_some("float32 (8,): grip-site pos, normalised axis-angle of the grip-site orientation, gripper_qpos (the pose after the step; robosuite's controller may hold it from a substep earlier)"),
            },
            "episode_start": {"task": {"name": "the instruction"}},
            "action": "payload actions (7,), gripper binarised (< 0 -> -1, else +1) as LIBEROBenchmark.step",
            "timeouts_s": {
                "connect": self.config.connect_timeout.as_secs_f64(),
                "request": self.config.request_timeout.as_secs_f64(),
            },
            "determinism": "as the server's",
        })
    }

    fn connection(&mut self) -> Result<&mut VlaEvalConnection, PolicyError> {
        if !self.conn.as_ref().is_some_and(VlaEvalConnection::is_open) {
            self.conn = None;
            self.started = false;
            let conn = VlaEvalConnection::connect(&self.config).map_err(remote_error)?;
            let hello = msgpack_numpy::to_json(conn.hello());
            if hello != self.hello {
                return Err(error(format!(
                    "reconnected to {}, but the server's HELLO changed (was {}, now {hello}): not the model this run started with",
                    self.config.url, self.hello
                )));
            }
            self.conn = Some(conn);
        }
        Ok(self.conn.as_mut().expect("connected above"))
    }
}

impl Policy for VlaEvalPolicy {
    fn reset(&mut self, instruction: &str, _episode_seed: u64) {
        self.instruction = instruction.to_string();
        self.started = false;
        self.steps = 0;
    }

    /// Every step sends an observation (the server keeps the chunk).
    fn camera_size(&self) -> Option<u32> {
        Some(LIBERO_RENDER_SIZE)
    }

    fn wants_wrist_camera(&self) -> bool {
        self.params.send_wrist_image
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        let observation = observation_payload(obs, &self.instruction, self.params).map_err(error)?;
        let start = !self.started;
        let instruction = self.instruction.clone();
        let conn = self.connection()?;
        if start {
            let task = Value::Map(vec![(Value::from("name"), Value::from(instruction))]);
            conn.notify("episode_start", Value::Map(vec![(Value::from("task"), task)]), "sending EPISODE_START")
                .map_err(remote_error)?;
        }
        self.started = true;
        let conn = self.conn.as_mut().expect("connected above");
        let payload = conn.act(observation).map_err(remote_error)?;
        let action =
            action_of(&payload).map_err(|e| error(format!("malformed action from {}: {e}", self.config.url)))?;
        self.steps += 1;
        Ok(action)
    }

    /// EPISODE_END with the steps taken (the policy is not told the outcome); skipped when the
    /// episode never started or the connection is gone.
    fn end_episode(&mut self) {
        if self.started
            && let Some(conn) = self.conn.as_mut().filter(|c| c.is_open())
        {
            let payload = Value::Map(vec![(Value::from("steps"), Value::from(self.steps))]);
            let _ = conn.notify("episode_end", payload, "sending EPISODE_END");
        }
        self.started = false;
    }
}

fn error(detail: String) -> PolicyError {
    PolicyError { policy: NAME.into(), detail }
}

fn remote_error(e: RemoteError) -> PolicyError {
    error(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn observation_params_are_honoured_or_refused() {
        let hello = |p: serde_json::Value| serde_json::json!({"model_server": "X", "observation_params": p});
        assert_eq!(ObservationParams::from_hello(&serde_json::json!({})).unwrap(), ObservationParams::default());
        // OFT's: env_seed is the run's, the rest honoured
        let oft =
            serde_json::json!({"env_seed": 0, "quat_no_antipodal": true, "send_wrist_image": true, "send_state": true});
        let p = ObservationParams::from_hello(&hello(oft)).unwrap();
        assert_eq!(p, ObservationParams { send_wrist_image: true, send_state: true, quat_no_antipodal: true });
        let p = ObservationParams::from_hello(&hello(serde_json::json!({"send_state": true, "success_mode": "x"})))
            .unwrap();
        assert!(p.send_state && !p.send_wrist_image);
        assert!(
            ObservationParams::from_hello(&hello(serde_json::json!({"absolute_action": true})))
                .unwrap_err()
                .contains("absolute_action")
        );
        assert!(ObservationParams::from_hello(&hello(serde_json::json!({"absolute_action": false}))).is_ok());
        assert!(
            ObservationParams::from_hello(&hello(serde_json::json!({"send_state": 1})))
                .unwrap_err()
                .contains("true or false")
        );
        assert!(ObservationParams::from_hello(&hello(serde_json::json!([1]))).is_err());
    }

    #[test]
    fn another_hello_at_the_same_address_is_refused() {
        let a = serde_json::json!({"model_server": "A", "harness_version": "0.8.0"});
        let b = serde_json::json!({"model_server": "B", "harness_version": "0.8.0"});
        let same_server = super::super::client::same_server;
        assert!(same_server("HELLO", "ws://test-only:1", &a).is_ok());
        assert!(same_server("HELLO", "ws://test-only:1", &a).is_ok());
        let e = same_server("HELLO", "ws://test-only:1", &b).unwrap_err();
        assert!(e.contains("another HELLO") && e.contains("not the model this run started with"), "{e}");
        assert!(same_server("HELLO", "ws://test-only:2", &b).is_ok());
        assert!(same_server("metadata", "ws://test-only:1", &b).is_ok(), "kept apart per protocol");
    }

    #[test]
    fn axis_angle_conventions() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        // w < 0: vla-eval's normalises to the short way round, robosuite's does not
        let q = [-h, 0.0, 0.0, -h];
        let aa = quat_to_axisangle(q);
        assert!((aa[0] - std::f64::consts::FRAC_PI_2).abs() < 1e-12 && aa[1] == 0.0);
        assert!((crate::preprocess::quat2axisangle(q)[0] + 3.0 * std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(quat_to_axisangle([0.0, 0.0, 0.0, -1.0]), [0.0; 3]);
        let obs = Observation {
            eef_pos: [0.1, 0.2, 0.3],
            hand_quat: [-h, -h, 0.0, 0.0], // (w, x, y, z)
            gripper_qpos: [0.04, -0.04],
            ..Default::default()
        };
        let s = libero_states(&obs, false);
        assert_eq!(s[3], std::f64::consts::FRAC_PI_2 as f32 as f64);
        let s = libero_states(&obs, true);
        assert_eq!(s[3], (-3.0 * std::f64::consts::FRAC_PI_2) as f32 as f64);
        assert_eq!((s[0], s[7]), (0.1, -0.04));
    }

    #[test]
    fn actions_are_seven_numbers_with_the_gripper_binarised() {
        let arr = |a: NdArray| Value::Map(vec![(Value::from("actions"), ndarray_value(&a))]);
        let a = action_of(&arr(NdArray::from_f32(&[7], &[0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.2]))).unwrap();
        assert_eq!(a, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 1.0]);
        let a = action_of(&arr(NdArray::from_f64(&[7], &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.01]))).unwrap();
        assert_eq!(a[6], -1.0);
        assert_eq!(action_of(&arr(NdArray::from_f64(&[7], &[0.0; 7]))).unwrap()[6], 1.0);
        let list = Value::Map(vec![(
            Value::from("action"),
            Value::Array((0..7).map(|i| Value::from(i as f64 / 10.0)).collect()),
        )]);
        assert_eq!(action_of(&list).unwrap()[1], 0.1);
        assert!(action_of(&arr(NdArray::from_f32(&[1, 7], &[0.0; 7]))).unwrap_err().contains("shape"));
        assert!(action_of(&arr(NdArray::from_f32(&[6], &[0.0; 6]))).unwrap_err().contains("6 values"));
        assert!(action_of(&Value::Map(vec![])).unwrap_err().contains("no \"actions\""));
    }

    #[test]
    fn frames_and_images_use_the_package_codec() {
        let f = frame("observation", Value::Map(vec![]), 3);
        let (kind, payload, seq) = parse_frame(&msgpack_numpy::unpack(&msgpack_numpy::pack(&f)).unwrap()).unwrap();
        assert_eq!((kind.as_str(), payload.as_map().unwrap().len(), seq), ("observation", 0, 3));
        assert!(parse_frame(&Value::Map(vec![(Value::from("type"), Value::from("action"))])).is_err());
        // a 2x1 image: rotated 180° is the pixel order reversed; PNG decodes to it
        let cam = crate::CameraImage { width: 1, height: 2, rgb: vec![1, 2, 3, 4, 5, 6] };
        let v = image_value(&cam).unwrap();
        let m = v.as_map().unwrap();
        assert_eq!(msgpack_numpy::get(m, b"format").unwrap().as_str(), Some("png"));
        assert!(matches!(m[0].0, Value::String(_)), "string keys, as vla-eval's codec");
        let Value::Binary(data) = msgpack_numpy::get(m, b"data").unwrap() else { panic!() };
        let mut reader = png::Decoder::new(std::io::Cursor::new(data.clone())).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height, &buf[..info.buffer_size()]), (1, 2, &[4, 5, 6, 1, 2, 3][..]));
    }
}
