//! [`StarVlaPolicy`]: a model served by starVLA's websocket policy server (VLA-JEPA, and starVLA's
//! Qwen-GR00T/-OFT/-PI/-FAST frameworks), evaluated as starVLA's own LIBERO client feeds it.
//!
//! **Transport** (`deployment/model_server/tools/websocket_policy_{server,client}.py`): openpi's
//! (websockets, no compression, the msgpack-numpy codec with bin keys, [`super::msgpack_numpy`]),
//! and on connect the server sends one **metadata** map first. Each request is one map; each reply
//! an envelope `{"status": "ok"|"error", "ok", "type": "inference_result", "request_id", "data" |
//! "error": {"message"}}`. A policy error is such a frame and the connection stays open (an error
//! row, the next query may go on); only a crash of the handler sends a traceback as text and
//! closes with 1011, as openpi's server does.
//!
//! **Two generations**, told apart by the metadata ([`Generation::of`]):
//!
//! | | [`Generation::Head`] (starVLA 0ed0aad2) | [`Generation::Legacy`] (ginwind/VLA-JEPA ec8c70f6) |
//! |---|---|---|
//! | metadata | `action_chunk_size`, `available_unnorm_keys`, `default_unnorm_key`, ... | `{"env": "simpler_env"}` (no `action_chunk_size`) |
//! | request | flat `{"examples": [{"image": [agentview, wrist], "lang", "state"?}], "unnorm_key", "do_sample": false, "use_ddim": true, "num_ddim_steps": 10}` | `{"type": "infer", "payload": {"batch_images": [[agentview, wrist]], "instructions": [lang], "state"?: [(1, 8)], "unnorm_key", "do_sample", "use_ddim", "num_ddim_steps"}}` |
//! | reply `data` | `{"actions": (B, T, D)}`, unnormalised by the server | `{"normalized_actions": (B, T, 7), ...}`, unnormalised here ([`ActionStats::unnormalize`]) from the checkpoint's `dataset_statistics.json` |
//! | images | rot180, Pillow bilinear to 224 ([`ImagePipeline::STARVLA`]) | rot180, cv2 `INTER_AREA` to 224 ([`ImagePipeline::VLA_JEPA`]) |
//! | chunk executed | `action_chunk_size` of the metadata, all of it | 7 (`future_action_window_size + 1` of VLA-JEPA's config) |
//! | state | not sent (HEAD's LIBERO loop sends none) | sent (`with_state=true` in VLA-JEPA's `eval_libero.sh`) |
//!
//! The state, when sent, is float64 (1, 8): eef position, robosuite `quat2axisangle` of
//! `robot0_eef_quat`, finger joints, unnormalised (as both loops build it). The executed action is
//! the chunk's row with its gripper mapped as `_binarize_gripper_open`: `open_gripper > 0.5` → -1
//! (open), else +1. A new query is sent every `chunk` policy steps (`step % chunk == 0`), and the
//! reply must hold at least `chunk` actions (the reference indexes `actions[step % chunk]`).
//!
//! HEAD's client-side `AdaptiveEnsembler` is built but never applied in its LIBERO `step`, so
//! nothing is ensembled by default; `ensemble=adaptive:3:0.1` applies it (`crate::ensembling`),
//! to the actions as the model gave them, the gripper mapped after, as starVLA's ensembler does.

use super::client::{RemoteError, WsConnection};
use super::msgpack_numpy::{self, NdArray};
use crate::chunking::ActionChunker;
use crate::preprocess::ImagePipeline;
use crate::{Action, Observation, Policy, PolicyError};
use rmpv::Value;
use std::path::{Path, PathBuf};
use std::time::Duration;

const NAME: &str = "starvla";
/// `LIBERO_ENV_RESOLUTION` of both LIBERO loops: the renders, resized to 224 by the client.
pub const LIBERO_RENDER_SIZE: u32 = 256;
/// The legacy generation's chunk: `future_action_window_size + 1` of VLA-JEPA's LIBERO config.
pub const LEGACY_CHUNK: usize = 7;
/// `num_ddim_steps` both LIBERO clients send (their `ModelClient`/`M1Inference` default).
pub const NUM_DDIM_STEPS: u32 = 10;

/// Which payload generation the server speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Generation {
    /// starVLA HEAD: `{"examples": [...]}` in, unnormalised `actions` out.
    Head,
    /// VLA-JEPA's (older starVLA): `batch_images`/`instructions` in, `normalized_actions` out.
    Legacy,
}

impl Generation {
    /// HEAD's `PolicyServerWrapper.metadata` always holds `action_chunk_size`; the older server's
    /// metadata is `{"env": "simpler_env"}`.
    pub fn of(metadata: &serde_json::Value) -> Generation {
        if metadata.get("action_chunk_size").is_some() { Generation::Head } else { Generation::Legacy }
    }

    pub fn name(self) -> &'static str {
        match self {
            Generation::Head => "head",
            Generation::Legacy => "legacy",
        }
    }

    pub fn images(self) -> ImagePipeline {
        match self {
            Generation::Head => ImagePipeline::STARVLA,
            Generation::Legacy => ImagePipeline::VLA_JEPA,
        }
    }
}

/// How to reach the server and what to tell it.
#[derive(Debug, Clone, PartialEq)]
pub struct StarVlaConfig {
    /// `ws://host:port`.
    pub url: String,
    /// The dataset key of the action statistics (`unnorm_key`), sent with every request; for the
    /// legacy generation also the key read from `stats`.
    pub unnorm_key: Option<String>,
    /// The checkpoint's `dataset_statistics.json` (legacy generation only: it unnormalises here).
    pub stats: Option<PathBuf>,
    /// Actions executed per query; default: the metadata's `action_chunk_size` (HEAD), 7 (legacy).
    pub chunk: Option<usize>,
    /// Send the 8-D state; default: no (HEAD), yes (legacy).
    pub state: Option<bool>,
    /// TCP connect + websocket handshake + the metadata message.
    pub connect_timeout: Duration,
    /// One request and its reply.
    pub request_timeout: Duration,
}

impl StarVlaConfig {
    /// 30 s to connect, 60 s per request (as the other remote clients here).
    pub fn new(url: impl Into<String>) -> Self {
        StarVlaConfig {
            url: url.into(),
            unnorm_key: None,
            stats: None,
            chunk: None,
            state: None,
            connect_timeout: Duration::from_secs(30),
            request_timeout: Duration::from_secs(60),
        }
    }
}

/// `dataset_statistics.json[unnorm_key]["action"]`: the bounds the legacy generation's client
/// unnormalises with, and the optional `mask` (false: the dimension is left as the model gave it).
#[derive(Debug, Clone, PartialEq)]
pub struct ActionStats {
    pub key: String,
    pub min: Vec<f64>,
    pub max: Vec<f64>,
    pub mask: Option<Vec<bool>>,
}

impl ActionStats {
    /// Reads the statistics of `key` (or of the only key, when `key` is None and there is one, as
    /// `M1Inference._check_unnorm_key`); an absent key names the keys present.
    pub fn from_json(stats: &serde_json::Value, key: Option<&str>, source: &str) -> Result<Self, String> {
        let map = stats.as_object().ok_or_else(|| format!("{source} is not a JSON object"))?;
        let keys = || map.keys().cloned().collect::<Vec<_>>().join(", ");
        let key = match key {
            Some(k) if map.contains_key(k) => k.to_string(),
            Some(k) => return Err(format!("{source} has no unnorm key {k:?}; its keys: {}", keys())),
            None if map.len() == 1 => map.keys().next().expect("one key").clone(),
            None => return Err(format!("{source} holds several datasets: choose one with unnorm=<key>: {}", keys())),
        };
        let action = map[&key].get("action").ok_or_else(|| format!("{source}: {key:?} has no \"action\""))?;
        let floats = |name: &str| -> Result<Vec<f64>, String> {
            action
                .get(name)
                .and_then(|v| v.as_array())
                .and_then(|a| a.iter().map(serde_json::Value::as_f64).collect::<Option<Vec<f64>>>())
                .ok_or_else(|| format!("{source}: {key}.action.{name} is not a list of numbers"))
        };
        let (min, max) = (floats("min")?, floats("max")?);
        let mask = match action.get("mask") {
            None | Some(serde_json::Value::Null) => None,
            Some(m) => Some(
                m.as_array()
                    .and_then(|a| a.iter().map(serde_json::Value::as_bool).collect::<Option<Vec<bool>>>())
                    .ok_or_else(|| format!("{source}: {key}.action.mask is not a list of booleans"))?,
            ),
        };
        if min.len() != 7 || max.len() != 7 || mask.as_ref().is_some_and(|m| m.len() != 7) {
            return Err(format!("{source}: {key}.action min/max/mask must have 7 entries (LIBERO's action)"));
        }
        Ok(ActionStats { key, min, max, mask })
    }

    /// Reads `path` ([`Self::from_json`]).
    pub fn load(path: &Path, key: Option<&str>) -> Result<Self, String> {
        let source = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| format!("cannot read {source}: {e}"))?;
        let json = serde_json::from_str(&text).map_err(|e| format!("{source} is not JSON: {e}"))?;
        Self::from_json(&json, key, &source)
    }

    /// `M1Inference.unnormalize_actions` for one action: clip to [-1, 1], the gripper (index 6) to
    /// 0 below 0.5 else 1, then `0.5·(a+1)·(max−min)+min` where the mask is true (everywhere when
    /// there is none), the value as is elsewhere.
    pub fn unnormalize(&self, normalized: &[f64; 7]) -> [f64; 7] {
        std::array::from_fn(|j| {
            let mut a = normalized[j].clamp(-1.0, 1.0);
            if j == 6 {
                a = if a < 0.5 { 0.0 } else { 1.0 };
            }
            if self.mask.as_ref().is_none_or(|m| m[j]) {
                0.5 * (a + 1.0) * (self.max[j] - self.min[j]) + self.min[j]
            } else {
                a
            }
        })
    }
}

/// `_binarize_gripper_open` of both LIBERO loops: `open_gripper > 0.5` → -1 (open), else +1.
pub fn libero_gripper(open_gripper: f64) -> f32 {
    if open_gripper > 0.5 { -1.0 } else { 1.0 }
}

/// The executed action: the first six as the server (or our unnormalisation) gave them, the
/// gripper mapped by [`libero_gripper`].
pub fn libero_action(row: &[f64; 7]) -> Action {
    std::array::from_fn(|j| if j == 6 { libero_gripper(row[6]) } else { row[j] as f32 })
}

/// The two images both loops send, rotated and resized by the generation's pipeline.
pub fn request_images(cams: &crate::CameraImages, pipeline: &ImagePipeline) -> Result<[Value; 2], String> {
    let prep = |c: &crate::CameraImage| -> Result<Value, String> {
        let img = crate::preprocess::RgbImage::new(c.width, c.height, c.rgb.clone())
            .and_then(|i| pipeline.apply(&i))
            .map_err(|e| format!("image preprocessing: {e}"))?;
        Ok(NdArray::from_u8(&[img.height as usize, img.width as usize, 3], img.rgb).to_value())
    };
    Ok([prep(&cams.agentview)?, prep(&cams.wrist)?])
}

/// The request of `generation` for one observation (images already preprocessed).
pub fn request(
    generation: Generation,
    images: [Value; 2],
    lang: &str,
    state: Option<[f64; 8]>,
    unnorm_key: Option<&str>,
) -> Value {
    let state = state.map(|s| NdArray::from_f64(&[1, 8], &s).to_value());
    let unnorm = unnorm_key.map_or(Value::Nil, Value::from);
    let options = [
        (Value::from("unnorm_key"), unnorm),
        (Value::from("do_sample"), Value::Boolean(false)),
        (Value::from("use_ddim"), Value::Boolean(true)),
        (Value::from("num_ddim_steps"), Value::from(NUM_DDIM_STEPS)),
    ];
    match generation {
        Generation::Head => {
            let mut example =
                vec![(Value::from("image"), Value::Array(images.to_vec())), (Value::from("lang"), Value::from(lang))];
            example.extend(state.map(|s| (Value::from("state"), s)));
            let mut map = vec![(Value::from("examples"), Value::Array(vec![Value::Map(example)]))];
            map.extend(options);
            Value::Map(map)
        }
        Generation::Legacy => {
            let mut payload = vec![
                (Value::from("batch_images"), Value::Array(vec![Value::Array(images.to_vec())])),
                (Value::from("instructions"), Value::Array(vec![Value::from(lang)])),
            ];
            payload.extend(options);
            payload.extend(state.map(|s| (Value::from("state"), Value::Array(vec![s]))));
            Value::Map(vec![(Value::from("type"), Value::from("infer")), (Value::from("payload"), Value::Map(payload))])
        }
    }
}

/// The reply envelope's `data`, or the server's error message (`Err(Ok(message))`) when it
/// answered `status: "error"`; a malformed envelope is `Err(Err(detail))`.
pub fn reply_data(reply: &Value) -> Result<&[(Value, Value)], Result<String, String>> {
    let map = reply.as_map().ok_or(Err("the reply is not a map".to_string()))?;
    let status = msgpack_numpy::get(map, b"status").and_then(Value::as_str);
    match status {
        Some("ok") => msgpack_numpy::get(map, b"data")
            .and_then(Value::as_map)
            .map(Vec::as_slice)
            .ok_or(Err("status ok but no \"data\" map".to_string())),
        Some("error") => {
            let error = msgpack_numpy::get(map, b"error");
            let message = error
                .and_then(Value::as_map)
                .and_then(|m| msgpack_numpy::get(m, b"message"))
                .and_then(Value::as_str)
                .map_or_else(
                    || error.map_or("(no error message)".to_string(), |e| msgpack_numpy::to_json(e).to_string()),
                    str::to_string,
                );
            Err(Ok(message))
        }
        _ => Err(Err(format!("no \"status\" of ok or error in the reply envelope: {}", msgpack_numpy::to_json(reply)))),
    }
}

/// The first example's action rows from a reply's `data`: `actions` (HEAD) or
/// `normalized_actions` (legacy), a float (B ≥ 1, T ≥ 1, 7) array.
pub fn action_rows(generation: Generation, data: &[(Value, Value)]) -> Result<Vec<[f64; 7]>, String> {
    let (key, other) = match generation {
        Generation::Head => ("actions", "normalized_actions"),
        Generation::Legacy => ("normalized_actions", "actions"),
    };
    let Some(v) = msgpack_numpy::get(data, key.as_bytes()) else {
        let keys: Vec<String> = data.iter().map(|(k, _)| msgpack_numpy::to_json(k).to_string()).collect();
        let hint = if msgpack_numpy::get(data, other.as_bytes()).is_some() {
            format!(" but {other:?}: the server speaks the other generation than its metadata says")
        } else {
            String::new()
        };
        return Err(format!("the reply data has no {key:?}{hint} (keys: {})", keys.join(", ")));
    };
    let a = NdArray::from_value(v).map_err(|e| e.0)?.ok_or_else(|| format!("{key:?} is not an ndarray"))?;
    if !a.dtype[1..].starts_with('f') {
        return Err(format!("{key:?} has dtype {:?}, expected float", a.dtype));
    }
    let t = match a.shape[..] {
        [b, t, 7] if b >= 1 && t >= 1 => t,
        _ => return Err(format!("{key:?} has shape {:?}, expected (B, T, 7)", a.shape)),
    };
    let values = a.to_f64().map_err(|e| e.0)?;
    Ok(values[..t * 7].chunks_exact(7).map(|c| std::array::from_fn(|j| c[j])).collect())
}

/// What the metadata and the options resolve to; checked before any episode.
#[derive(Debug, Clone, PartialEq)]
pub struct Resolved {
    pub generation: Generation,
    pub chunk: usize,
    pub send_state: bool,
    /// Legacy: the statistics we unnormalise with.
    pub stats: Option<ActionStats>,
}

impl Resolved {
    pub fn new(config: &StarVlaConfig, metadata: &serde_json::Value) -> Result<Self, String> {
        let url = &config.url;
        let generation = Generation::of(metadata);
        let (chunk, stats) = match generation {
            Generation::Head => {
                if config.stats.is_some() {
                    return Err(format!(
                        "the server at {url} unnormalises its actions itself (starVLA HEAD: its metadata has action_chunk_size): stats= is for the older generation only"
                    ));
                }
                let keys = metadata.get("available_unnorm_keys").and_then(|k| k.as_array());
                if let (Some(k), Some(keys)) = (&config.unnorm_key, keys)
                    && !keys.iter().any(|x| x.as_str() == Some(k))
                {
                    return Err(format!(
                        "the server at {url} has no unnorm key {k:?}; available_unnorm_keys: {}",
                        serde_json::Value::Array(keys.clone())
                    ));
                }
                let served = metadata["action_chunk_size"].as_u64().filter(|&n| n >= 1).ok_or_else(|| {
                    format!(
                        "the server at {url} sends action_chunk_size = {}, expected an integer >= 1",
                        metadata["action_chunk_size"]
                    )
                })?;
                (config.chunk.unwrap_or(served as usize), None)
            }
            Generation::Legacy => {
                let path = config.stats.as_ref().ok_or_else(|| {
                    format!("the server at {url} sends normalised actions (its metadata {metadata} has no action_chunk_size: VLA-JEPA's older starVLA server); name the checkpoint's dataset_statistics.json with stats=<path> to unnormalise them")
                })?;
                let stats = ActionStats::load(path, config.unnorm_key.as_deref())?;
                (config.chunk.unwrap_or(LEGACY_CHUNK), Some(stats))
            }
        };
        let send_state = config.state.unwrap_or(generation == Generation::Legacy);
        Ok(Resolved { generation, chunk, send_state, stats })
    }
}

/// A model served by starVLA's policy server. One instance, one connection, opened by
/// [`Self::connect`] (the rollout makes one per episode); a failed connection is not reopened:
/// the episode is an error row and the next episode connects afresh.
#[derive(Debug)]
pub struct StarVlaPolicy {
    config: StarVlaConfig,
    ws: WsConnection,
    metadata: serde_json::Value,
    resolved: Resolved,
    instruction: String,
    chunker: ActionChunker,
}

impl StarVlaPolicy {
    /// Connects, reads the metadata and resolves the generation, chunk, state and statistics, all
    /// before any episode.
    pub fn connect(config: StarVlaConfig) -> Result<Self, PolicyError> {
        if config.chunk == Some(0) {
            return Err(error("chunk must be at least 1".into()));
        }
        let (mut ws, deadline) =
            WsConnection::connect(&config.url, None, config.connect_timeout, config.request_timeout)
                .map_err(remote_error)?;
        let metadata =
            ws.receive(deadline, config.connect_timeout, "reading the server's metadata").map_err(remote_error)?;
        let metadata = msgpack_numpy::to_json(&metadata);
        super::client::same_server("metadata", &config.url, &metadata).map_err(error)?;
        let resolved = Resolved::new(&config, &metadata).map_err(error)?;
        Ok(StarVlaPolicy {
            ws,
            metadata,
            chunker: ActionChunker::new(resolved.chunk),
            resolved,
            instruction: String::new(),
            config,
        })
    }

    pub fn metadata(&self) -> &serde_json::Value {
        &self.metadata
    }

    pub fn resolved(&self) -> &Resolved {
        &self.resolved
    }

    /// Identity for the run manifest: the server's metadata, the generation, what is sent and how
    /// the actions are made executable.
    pub fn identity(&self) -> serde_json::Value {
        let r = &self.resolved;
        let images = r.generation.images();
        let actions = match &r.stats {
            None => "data.actions[0] (T, 7), unnormalised by the server".to_string(),
            Some(_) => "data.normalized_actions[0] (T, 7) unnormalised here as M1Inference.unnormalize_actions: clip(-1, 1), gripper < 0.5 -> 0 else 1, 0.5*(a+1)*(max-min)+min where mask (everywhere without one)".to_string(),
        };
        serde_json::json!({
            "kind": "remote",
            "name": NAME,
            "url": self.config.url,
            "protocol": "starVLA websocket policy server: msgpack-numpy, metadata first, one request -> one envelope {status, ok, type, request_id, data | error}",
            "generation": r.generation.name(),
            "server_metadata": self.metadata,
            "unnorm_key": self.config.unnorm_key,
            "stats": r.stats.as_ref().map(|s| serde_json::json!({
                "file": self.config.stats.as_ref().map(|p| p.display().to_string()),
                "key": s.key, "min": s.min, "max": s.max, "mask": s.mask,
            })),
            "request": {
                "images": {
                    "cameras": ["agentview", "robot0_eye_in_hand"],
                    "render": format!("{LIBERO_RENDER_SIZE}x{LIBERO_RENDER_SIZE}, look mujoco-3.2.3"),
                    "preprocessing": images.describe(),
                },
                "state": r.send_state.then_some("float64 (1, 8): eef_pos, quat2axisangle(robot0_eef_quat, as given), gripper_qpos"),
                "do_sample": false, "use_ddim": true, "num_ddim_steps": NUM_DDIM_STEPS,
            },
            "actions": actions,
            "gripper": "open_gripper > 0.5 -> -1 (open), else +1",
            "chunking": {"executed": r.chunk, "query_every": r.chunk},
            "timeouts_s": {
                "connect": self.config.connect_timeout.as_secs_f64(),
                "request": self.config.request_timeout.as_secs_f64(),
            },
            "determinism": "as the server's (do_sample false)",
        })
    }

    fn query(&mut self, obs: &Observation) -> Result<Vec<Action>, PolicyError> {
        let r = &self.resolved;
        let cams = obs
            .images
            .as_ref()
            .ok_or_else(|| error("no camera images for this step (the rollout rendered none)".into()))?;
        let images = request_images(cams, &r.generation.images()).map_err(error)?;
        let state = r.send_state.then(|| super::openpi::libero_state(obs));
        let msg = request(r.generation, images, &self.instruction, state, self.config.unnorm_key.as_deref());
        let reply =
            self.ws.request(&msg, "sending the observation", "waiting for the actions").map_err(remote_error)?;
        let url = &self.config.url;
        let data = match reply_data(&reply) {
            Ok(data) => data,
            Err(Ok(message)) => return Err(remote_error(RemoteError::Server { url: url.clone(), message })),
            Err(Err(detail)) => return Err(error(format!("malformed reply from {url}: {detail}"))),
        };
        let rows = action_rows(r.generation, data).map_err(|e| error(format!("malformed reply from {url}: {e}")))?;
        if rows.len() < r.chunk {
            return Err(error(format!(
                "the server predicted {} actions, fewer than the {} executed per query (the reference client indexes actions[step % chunk])",
                rows.len(),
                r.chunk
            )));
        }
        let unnormalised = rows.iter().map(|row| r.stats.as_ref().map_or(*row, |s| s.unnormalize(row)));
        Ok(match self.chunker.ensemble() {
            None => unnormalised.map(|row| libero_action(&row)).collect(),
            // Ensembled as the model gave them (the gripper's open_gripper in [0, 1]), mapped after.
            Some(_) => unnormalised.map(|row| row.map(|x| x as f32)).collect(),
        })
    }
}

impl Policy for StarVlaPolicy {
    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        self.chunker.set_ensemble(Some(ensemble));
        Ok(())
    }

    fn queries_model(&self) -> bool {
        self.chunker.needs_query()
    }

    fn reset(&mut self, instruction: &str, _episode_seed: u64) {
        self.instruction = instruction.to_string();
        self.chunker.reset();
    }

    /// Renders only when a query is due.
    fn camera_size(&self) -> Option<u32> {
        self.chunker.needs_query().then_some(LIBERO_RENDER_SIZE)
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        if self.chunker.needs_query() {
            let chunk = self.query(obs)?;
            self.chunker.push_chunk(chunk).map_err(error)?;
        }
        let mut action = self.chunker.next_action().expect("a chunk of at least `chunk` >= 1 actions was queued");
        if self.chunker.ensemble().is_some() {
            action[6] = libero_gripper(f64::from(action[6]));
        }
        Ok(action)
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

    fn stats(mask: Option<Vec<bool>>) -> ActionStats {
        ActionStats {
            key: "franka".into(),
            min: vec![-1.0, -2.0, 0.0, -0.5, -0.5, -0.5, 0.0],
            max: vec![1.0, 2.0, 4.0, 0.5, 0.5, 0.5, 1.0],
            mask,
        }
    }

    #[test]
    fn legacy_unnormalisation_is_m1_inferences() {
        let s = stats(None);
        let a = s.unnormalize(&[0.0, 0.5, -1.0, 2.0, -3.0, 0.25, 0.49]);
        // 0.5*(a+1)*(max-min)+min, clipped first; the gripper to 0 then unnormalised to min
        assert_eq!(&a[..6], &[0.0, 1.0, 0.0, 0.5, -0.5, 0.125]);
        assert_eq!(a[6], 0.5, "gripper 0.49 -> 0 -> 0.5*(0+1)*(1-0)+0");
        assert_eq!(s.unnormalize(&[0.0; 7].map(|_| 0.5))[6], 1.0, "0.5 -> 1 -> 1.0");
        // with a mask false on the gripper: the 0/1 is kept
        let s = stats(Some(vec![true, true, true, true, true, true, false]));
        assert_eq!(s.unnormalize(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.7])[6], 1.0);
        assert_eq!(s.unnormalize(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.7])[6], 0.0);
    }

    #[test]
    fn the_gripper_opens_above_one_half() {
        assert_eq!(libero_gripper(0.51), -1.0);
        assert_eq!(libero_gripper(0.5), 1.0);
        assert_eq!(libero_gripper(0.0), 1.0);
        assert_eq!(libero_gripper(1.0), -1.0);
        let a = libero_action(&[0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 1.0]);
        assert_eq!(a, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, -1.0]);
        // legacy end to end: normalised gripper 0.9 -> 1 -> unnormalised 1.0 -> open (-1)
        assert_eq!(libero_action(&stats(None).unnormalize(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.9]))[6], -1.0);
        assert_eq!(libero_action(&stats(None).unnormalize(&[0.0; 7]))[6], 1.0, "0 -> 0 -> 0.5, not > 0.5: close");
    }

    #[test]
    fn stats_keys_are_chosen_or_listed() {
        let action = serde_json::json!({"min": [0, 0, 0, 0, 0, 0, 0], "max": [1, 1, 1, 1, 1, 1, 1]});
        let one = serde_json::json!({"franka": {"action": action}});
        assert_eq!(ActionStats::from_json(&one, None, "s.json").unwrap().key, "franka");
        let two = serde_json::json!({"a": {"action": action}, "b": {"action": action}});
        assert!(ActionStats::from_json(&two, None, "s.json").unwrap_err().contains("a, b"));
        let e = ActionStats::from_json(&two, Some("c"), "s.json").unwrap_err();
        assert!(e.contains("no unnorm key \"c\"") && e.contains("a, b"), "{e}");
        assert_eq!(ActionStats::from_json(&two, Some("b"), "s.json").unwrap().max[0], 1.0);
        let short = serde_json::json!({"k": {"action": {"min": [0], "max": [1]}}});
        assert!(ActionStats::from_json(&short, None, "s.json").unwrap_err().contains("7 entries"));
    }

    #[test]
    fn generations_are_told_apart_by_the_metadata() {
        let head = serde_json::json!({"env": "starvla_policy_server", "action_chunk_size": 8, "available_unnorm_keys": ["franka"]});
        let legacy = serde_json::json!({"env": "simpler_env"});
        assert_eq!(Generation::of(&head), Generation::Head);
        assert_eq!(Generation::of(&legacy), Generation::Legacy);
        let config = StarVlaConfig::new("ws://h:1");
        let r = Resolved::new(&config, &head).unwrap();
        assert_eq!((r.chunk, r.send_state, r.stats.is_none()), (8, false, true));
        let r = Resolved::new(&StarVlaConfig { chunk: Some(4), state: Some(true), ..config.clone() }, &head).unwrap();
        assert_eq!((r.chunk, r.send_state), (4, true));
        let e = Resolved::new(&StarVlaConfig { unnorm_key: Some("x".into()), ..config.clone() }, &head).unwrap_err();
        assert!(e.contains("no unnorm key \"x\"") && e.contains("franka"), "{e}");
        let e = Resolved::new(&StarVlaConfig { stats: Some("s.json".into()), ..config.clone() }, &head).unwrap_err();
        assert!(e.contains("stats= is for the older generation"), "{e}");
        assert!(Resolved::new(&config, &legacy).unwrap_err().contains("stats=<path>"));
    }

    #[test]
    fn requests_and_replies_of_both_generations() {
        let img = || NdArray::from_u8(&[1, 1, 3], vec![1, 2, 3]).to_value();
        let head = request(Generation::Head, [img(), img()], "go", None, Some("franka"));
        let m = head.as_map().unwrap();
        let keys: Vec<&str> = m.iter().map(|(k, _)| k.as_str().unwrap()).collect();
        assert_eq!(keys, ["examples", "unnorm_key", "do_sample", "use_ddim", "num_ddim_steps"]);
        let legacy = request(Generation::Legacy, [img(), img()], "go", Some([0.0; 8]), None);
        let m = legacy.as_map().unwrap();
        assert_eq!(msgpack_numpy::get(m, b"type").unwrap().as_str(), Some("infer"));
        let p = msgpack_numpy::get(m, b"payload").unwrap().as_map().unwrap();
        assert!(msgpack_numpy::get(p, b"unnorm_key").unwrap().is_nil());
        let Value::Array(states) = msgpack_numpy::get(p, b"state").unwrap() else { panic!() };
        assert_eq!(NdArray::from_value(&states[0]).unwrap().unwrap().shape, [1, 8]);

        let env = |status: &str, body: (&str, Value)| {
            Value::Map(vec![(Value::from("status"), Value::from(status)), (Value::from(body.0), body.1)])
        };
        let vals: Vec<f32> = (0..14).map(|i| i as f32 / 10.0).collect();
        let data = Value::Map(vec![(Value::from("actions"), NdArray::from_f32(&[1, 2, 7], &vals).to_value())]);
        let ok = env("ok", ("data", data));
        let rows = action_rows(Generation::Head, reply_data(&ok).unwrap()).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1][0], 0.7f32 as f64);
        let e = action_rows(Generation::Legacy, reply_data(&ok).unwrap()).unwrap_err();
        assert!(e.contains("other generation"), "{e}");
        let err = env("error", ("error", Value::Map(vec![(Value::from("message"), Value::from("boom"))])));
        assert_eq!(reply_data(&err).unwrap_err(), Ok("boom".to_string()));
        assert!(reply_data(&Value::Map(vec![])).unwrap_err().is_err());
    }
}
