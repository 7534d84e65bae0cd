//! [`OpenpiPolicy`]: a π0/π0.5 (or anything) served by openpi's policy server, evaluated as
//! openpi's LIBERO example evaluates it.
//!
//! The loop is `examples/libero/main.py` (Physical-Intelligence/openpi): when its action plan is
//! empty it sends one observation dict
//!
//! | key | value |
//! |---|---|
//! | `"observation/image"` | agentview, `obs["agentview_image"][::-1, ::-1]` (180°), `resize_with_pad` 256 → 224, uint8 (224, 224, 3) |
//! | `"observation/wrist_image"` | `robot0_eye_in_hand`, the same preprocessing |
//! | `"observation/state"` | `concat(eef_pos (3), quat2axisangle(eef_quat) (3), gripper_qpos (2))`: float64 (8,) |
//! | `"prompt"` | the task's language instruction, a str |
//!
//! reads `reply["actions"]`, an (N, 7) array (N = the model's `action_horizon`, 10 for
//! `pi05_libero`), asserts N ≥ `replan_steps`, and executes the first `replan_steps` (default 5)
//! before asking again. The predicted length N and the executed `replan_steps` are separate
//! choices; both go into the identity (see [`OpenpiPolicy::identity`]).
//!
//! Images are an optional input of the request ([`libero_request`], [`OpenpiPolicy::act_with_images`]),
//! already preprocessed by the caller (rotation and `resize_with_pad` are the image
//! preprocessing's business, not the transport's). Through [`Policy::act`] the client sends
//! proprio and prompt only, which a toy server accepts and a π0 server rejects (its
//! `LiberoInputs` reads both image keys): a server-side error, hence an error row, not a silent
//! wrong run.

use super::client::{OpenpiConnection, RemoteError};
use super::msgpack_numpy::{self, NdArray};
use crate::chunking::ActionChunker;
use crate::{Action, Observation, Policy, PolicyError};
use rmpv::Value;
use std::time::Duration;

/// `Args.replan_steps` of openpi's `examples/libero/main.py`: actions executed per chunk.
pub const LIBERO_REPLAN_STEPS: usize = 5;
/// Request keys of openpi's LIBERO example (`examples/libero/main.py`, read by `LiberoInputs` in
/// `src/openpi/policies/libero_policy.py`).
pub const KEY_IMAGE: &str = "observation/image";
pub const KEY_WRIST_IMAGE: &str = "observation/wrist_image";
pub const KEY_STATE: &str = "observation/state";
pub const KEY_PROMPT: &str = "prompt";
/// The reply key holding the action chunk.
pub const KEY_ACTIONS: &str = "actions";

const NAME: &str = "openpi";

/// How to reach the server and how to run its chunks.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenpiConfig {
    /// `ws://host:port` (or `host:port`).
    pub url: String,
    /// Actions executed from each predicted chunk before the server is asked again.
    pub replan_steps: usize,
    /// TCP connect + websocket handshake + the metadata message.
    pub connect_timeout: Duration,
    /// One request: sending the observation and receiving the actions. A first π0 call can
    /// include compilation; the default leaves room for it.
    pub request_timeout: Duration,
    /// Sent as `Authorization: Api-Key <key>` (openpi's client does the same); never recorded.
    pub api_key: Option<String>,
}

impl OpenpiConfig {
    /// openpi's LIBERO defaults: replan every 5 steps; 30 s to connect, 60 s per request.
    pub fn new(url: impl Into<String>) -> Self {
        OpenpiConfig {
            url: url.into(),
            replan_steps: LIBERO_REPLAN_STEPS,
            connect_timeout: Duration::from_secs(30),
            request_timeout: Duration::from_secs(60),
            api_key: None,
        }
    }
}

/// An image as the model's preprocessing left it: row-major (H, W, 3) RGB bytes, upright (the
/// 180° rotation already applied), e.g. 224×224 after `resize_with_pad`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RgbImage {
    pub height: u32,
    pub width: u32,
    pub rgb: Vec<u8>,
}

/// The two images openpi's LIBERO example sends.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OpenpiImages {
    /// `"observation/image"`: agentview.
    pub image: RgbImage,
    /// `"observation/wrist_image"`: robot0_eye_in_hand.
    pub wrist_image: RgbImage,
}

/// robosuite's `quat2axisangle` (the copy in openpi's `examples/libero/main.py`), for our
/// (w, x, y, z) quaternion: [`crate::preprocess::quat2axisangle`] after reordering; no sign
/// canonicalisation (a negative w gives an angle above π, as there).
pub fn quat2axisangle(quat_wxyz: [f64; 4]) -> [f64; 3] {
    crate::preprocess::quat2axisangle(crate::preprocess::proprio::wxyz_to_xyzw(quat_wxyz))
}

/// `"observation/state"`: eef position (3), the hand body's orientation as axis-angle (3), the
/// two gripper finger joints (2), float64 as robosuite's observations are. The orientation is
/// [`Observation::hand_quat`], robosuite's `robot0_eef_quat` (MuJoCo's `xquat` of the hand, used
/// as given, as openpi's example uses it).
pub fn libero_state(obs: &Observation) -> [f64; 8] {
    crate::preprocess::libero_state(
        obs.eef_pos,
        crate::preprocess::proprio::wxyz_to_xyzw(obs.hand_quat),
        obs.gripper_qpos,
        crate::preprocess::QuatSign::AsGiven,
    )
}

/// The request's images from the rendered cameras: openpi's LIBERO preprocessing
/// ([`crate::preprocess::ImagePipeline::OPENPI`]: rot180, `resize_with_pad` 224, Pillow bilinear).
pub fn openpi_images(cams: &crate::CameraImages) -> Result<OpenpiImages, PolicyError> {
    let prep = |c: &crate::CameraImage| -> Result<RgbImage, PolicyError> {
        let img = crate::preprocess::RgbImage::new(c.width, c.height, c.rgb.clone())
            .and_then(|i| crate::preprocess::ImagePipeline::OPENPI.apply(&i))
            .map_err(|e| error(format!("image preprocessing: {e}")))?;
        Ok(RgbImage { height: img.height, width: img.width, rgb: img.rgb })
    };
    Ok(OpenpiImages { image: prep(&cams.agentview)?, wrist_image: prep(&cams.wrist)? })
}

/// Camera renders openpi's LIBERO example takes (`LIBERO_ENV_RESOLUTION`).
pub const LIBERO_RENDER_SIZE: u32 = 256;

fn image_value(img: &RgbImage) -> Value {
    NdArray::from_u8(&[img.height as usize, img.width as usize, 3], img.rgb.clone()).to_value()
}

/// The observation dict of openpi's LIBERO example: state and prompt, and the two images when
/// given (uint8 (H, W, 3)).
pub fn libero_request(obs: &Observation, prompt: &str, images: Option<&OpenpiImages>) -> Value {
    let mut map = Vec::with_capacity(4);
    if let Some(im) = images {
        map.push((Value::from(KEY_IMAGE), image_value(&im.image)));
        map.push((Value::from(KEY_WRIST_IMAGE), image_value(&im.wrist_image)));
    }
    map.push((Value::from(KEY_STATE), NdArray::from_f64(&[8], &libero_state(obs)).to_value()));
    map.push((Value::from(KEY_PROMPT), Value::from(prompt)));
    Value::Map(map)
}

/// The action chunk of a reply: `reply["actions"]`, a float (N, D) array with N ≥ 1, D the
/// benchmark's action size (7 for LIBERO, 14 for ALOHA-sim).
pub fn actions_of<const D: usize>(reply: &Value) -> Result<Vec<[f32; D]>, String> {
    let map = reply.as_map().ok_or("the reply is not a map")?;
    let keys = || map.iter().map(|(k, _)| msgpack_numpy::to_json(k).to_string()).collect::<Vec<_>>().join(", ");
    let v = msgpack_numpy::get(map, KEY_ACTIONS.as_bytes())
        .ok_or_else(|| format!("the reply has no \"actions\" (keys: {})", keys()))?;
    let a = NdArray::from_value(v).map_err(|e| e.0)?.ok_or("\"actions\" is not an ndarray")?;
    if !a.dtype.starts_with(['<', '>', '=']) || !a.dtype[1..].starts_with('f') {
        return Err(format!("\"actions\" has dtype {:?}, expected float", a.dtype));
    }
    match a.shape[..] {
        [n, d] if n >= 1 && d == D => {}
        _ => return Err(format!("\"actions\" has shape {:?}, expected (N, {D}) with N >= 1", a.shape)),
    }
    let values = a.to_f64().map_err(|e| e.0)?;
    Ok(values.chunks_exact(D).map(|c| std::array::from_fn(|j| c[j] as f32)).collect())
}

/// The connection side of an openpi client, whatever the benchmark: one connection (reopened
/// after a failure at the next query, when the server sends the same metadata again) and the
/// metadata of the first one. The request layout and the chunking are the policies' business
/// ([`OpenpiPolicy`] for LIBERO, [`super::openpi_aloha::OpenpiAlohaPolicy`] for ALOHA-sim).
#[derive(Debug)]
pub struct OpenpiServer {
    config: OpenpiConfig,
    conn: Option<OpenpiConnection>,
    /// The metadata of the first connection, as JSON (for the identity, and to check reconnects).
    metadata: serde_json::Value,
}

impl OpenpiServer {
    /// Connects and reads the server's metadata (within `config.connect_timeout`).
    pub fn connect(config: OpenpiConfig) -> Result<Self, PolicyError> {
        if config.replan_steps == 0 {
            return Err(error("replan_steps must be at least 1".into()));
        }
        let conn = open(&config)?;
        let metadata = msgpack_numpy::to_json(conn.metadata());
        Ok(OpenpiServer { conn: Some(conn), metadata, config })
    }

    pub fn config(&self) -> &OpenpiConfig {
        &self.config
    }

    /// The server's metadata message (sent before anything else on the connection), as JSON.
    pub fn metadata(&self) -> &serde_json::Value {
        &self.metadata
    }

    /// Sends one observation dict and returns the action chunk (N, D); (re)connects first if
    /// needed. A chunk shorter than `replan_steps` is an error, as openpi's clients assert (the
    /// LIBERO example) or fail indexing it (`ActionChunkBroker`).
    pub fn query<const D: usize>(&mut self, request: &Value) -> Result<Vec<[f32; D]>, PolicyError> {
        if !self.conn.as_ref().is_some_and(OpenpiConnection::is_open) {
            self.conn = None;
            let conn = open(&self.config)?;
            let metadata = msgpack_numpy::to_json(conn.metadata());
            if metadata != self.metadata {
                return Err(error(format!(
                    "reconnected to {}, but the server's metadata changed (was {}, now {metadata}): not the policy this run started with",
                    self.config.url, self.metadata
                )));
            }
            self.conn = Some(conn);
        }
        let conn = self.conn.as_mut().expect("connected above");
        let reply = conn.infer(request).map_err(remote_error)?;
        let chunk =
            actions_of::<D>(&reply).map_err(|e| error(format!("malformed reply from {}: {e}", self.config.url)))?;
        if chunk.len() < self.config.replan_steps {
            return Err(error(format!(
                "the server predicted {} actions, fewer than replan_steps = {} (openpi's example asserts the same)",
                chunk.len(),
                self.config.replan_steps
            )));
        }
        Ok(chunk)
    }

    /// The identity's common part: the server, its metadata, the chunking and the timeouts.
    pub fn identity(&self, protocol: &str, request: serde_json::Value) -> serde_json::Value {
        let predicted = self.metadata.get("action_horizon").cloned().unwrap_or(serde_json::Value::Null);
        serde_json::json!({
            "kind": "remote",
            "name": NAME,
            "url": self.config.url,
            "protocol": protocol,
            "server_metadata": self.metadata,
            "request": request,
            "chunking": { "predicted": predicted, "executed": self.config.replan_steps },
            "replan_steps": self.config.replan_steps,
            "timeouts_s": {
                "connect": self.config.connect_timeout.as_secs_f64(),
                "request": self.config.request_timeout.as_secs_f64(),
            },
            "determinism": "as the server's: a sampling policy draws its noise server-side",
        })
    }
}

/// A policy served by openpi's websocket policy server. One instance, one connection (each
/// rollout worker makes its own); the connection persists across episodes, as in openpi's
/// example, and is reopened after a failure at the next query ([`OpenpiServer`]).
#[derive(Debug)]
pub struct OpenpiPolicy {
    server: OpenpiServer,
    prompt: String,
    /// The queued actions of the last chunk (executes `replan_steps` of each).
    chunker: ActionChunker,
}

impl OpenpiPolicy {
    /// Connects and reads the server's metadata (within `config.connect_timeout`).
    pub fn connect(config: OpenpiConfig) -> Result<Self, PolicyError> {
        let chunker = ActionChunker::new(config.replan_steps);
        Ok(OpenpiPolicy { server: OpenpiServer::connect(config)?, prompt: String::new(), chunker })
    }

    pub fn config(&self) -> &OpenpiConfig {
        self.server.config()
    }

    /// The server's metadata message (sent before anything else on the connection), as JSON.
    pub fn metadata(&self) -> &serde_json::Value {
        self.server.metadata()
    }

    /// Length of the last chunk the server predicted (None before the first query).
    pub fn last_predicted(&self) -> Option<usize> {
        self.chunker.last_predicted()
    }

    /// Server queries since the last [`Policy::reset`].
    pub fn queries(&self) -> u64 {
        self.chunker.queries()
    }

    /// Whether the next `act` sends a request (so images are needed); false while actions of the
    /// last chunk are still queued.
    pub fn needs_query(&self) -> bool {
        self.chunker.needs_query()
    }

    /// Identity for the run manifest. `chunking.predicted` is the server's `action_horizon` when
    /// its metadata states one (openpi's `pi05_libero` metadata does not; then null: the length
    /// is only known from the replies, see [`Self::last_predicted`]).
    pub fn identity(&self) -> serde_json::Value {
        self.server.identity(
            "openpi websocket + msgpack-numpy: server metadata first, one observation dict per request, reply {\"actions\": (N, 7)}",
            serde_json::json!({
                "keys": [KEY_IMAGE, KEY_WRIST_IMAGE, KEY_STATE, KEY_PROMPT],
                "state": "float64 (8,): eef_pos (3), quat2axisangle(robot0_eef_quat = hand body xquat, as given) (3), gripper_qpos (2)",
                "prompt": "the task's language instruction",
                "images": {
                    "cameras": ["agentview", "robot0_eye_in_hand"],
                    "render": format!("{LIBERO_RENDER_SIZE}x{LIBERO_RENDER_SIZE}, look mujoco-3.2.3"),
                    "preprocessing": crate::preprocess::ImagePipeline::OPENPI.describe(),
                },
            }),
        )
    }

    /// The next action, sending `images` (already preprocessed) with the request when one is due.
    pub fn act_with_images(&mut self, obs: &Observation, images: Option<&OpenpiImages>) -> Result<Action, PolicyError> {
        if self.chunker.needs_query() {
            let request = libero_request(obs, &self.prompt, images);
            let chunk = self.server.query::<7>(&request)?;
            self.chunker.push_chunk(chunk).map_err(error)?;
        }
        Ok(self.chunker.next_action().expect("a chunk of at least replan_steps >= 1 actions was queued"))
    }
}

impl Policy for OpenpiPolicy {
    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        self.chunker.set_ensemble(Some(ensemble));
        Ok(())
    }

    fn queries_model(&self) -> bool {
        self.chunker.needs_query()
    }

    fn reset(&mut self, instruction: &str, _episode_seed: u64) {
        self.prompt = instruction.to_string();
        self.chunker.reset();
    }

    /// Renders only when a request is due: the queued actions of a chunk need none.
    fn camera_size(&self) -> Option<u32> {
        self.needs_query().then_some(LIBERO_RENDER_SIZE)
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        let images = match (&obs.images, self.needs_query()) {
            (Some(cams), true) => Some(openpi_images(cams)?),
            _ => None,
        };
        self.act_with_images(obs, images.as_ref())
    }
}

fn open(config: &OpenpiConfig) -> Result<OpenpiConnection, PolicyError> {
    OpenpiConnection::connect(&config.url, config.api_key.as_deref(), config.connect_timeout, config.request_timeout)
        .map_err(remote_error)
}

pub(super) fn error(detail: String) -> PolicyError {
    PolicyError { policy: NAME.into(), detail }
}

fn remote_error(e: RemoteError) -> PolicyError {
    error(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quat2axisangle_matches_robosuite() {
        // identity (w = 1) and the den == 0 branch
        assert_eq!(quat2axisangle([1.0, 0.0, 0.0, 0.0]), [0.0; 3]);
        // 90° about z: (w, z) = (cos 45°, sin 45°)
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let aa = quat2axisangle([h, 0.0, 0.0, h]);
        assert!((aa[2] - std::f64::consts::FRAC_PI_2).abs() < 1e-12 && aa[0] == 0.0 && aa[1] == 0.0);
        // no canonicalisation: -q gives the angle 2π - θ about -axis, as robosuite does
        let aa = quat2axisangle([-h, 0.0, 0.0, -h]);
        assert!((aa[2] + 3.0 * std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // LIBERO's typical downward gripper, (w, x, y, z) = (0, 1, 0, 0): π about x
        assert_eq!(quat2axisangle([0.0, 1.0, 0.0, 0.0]), [std::f64::consts::PI, 0.0, 0.0]);
    }

    #[test]
    fn the_request_has_the_libero_example_keys_and_types() {
        let obs = Observation {
            eef_pos: [0.1, 0.2, 0.3],
            hand_quat: [0.0, 1.0, 0.0, 0.0],
            gripper_qpos: [0.04, -0.04],
            ..Default::default()
        };
        let images = OpenpiImages {
            image: RgbImage { height: 2, width: 2, rgb: vec![7; 12] },
            wrist_image: RgbImage { height: 2, width: 2, rgb: vec![9; 12] },
        };
        let req = libero_request(&obs, "pick up the bowl", Some(&images));
        let map = req.as_map().unwrap();
        let keys: Vec<&str> = map.iter().map(|(k, _)| k.as_str().unwrap()).collect();
        assert_eq!(keys, [KEY_IMAGE, KEY_WRIST_IMAGE, KEY_STATE, KEY_PROMPT]);
        let state = NdArray::from_value(msgpack_numpy::get(map, b"observation/state").unwrap()).unwrap().unwrap();
        assert_eq!((state.dtype.as_str(), state.shape.as_slice()), ("<f8", &[8][..]));
        assert_eq!(state.to_f64().unwrap(), [0.1, 0.2, 0.3, std::f64::consts::PI, 0.0, 0.0, 0.04, -0.04]);
        let img = NdArray::from_value(msgpack_numpy::get(map, b"observation/image").unwrap()).unwrap().unwrap();
        assert_eq!((img.dtype.as_str(), img.shape.as_slice()), ("|u1", &[2, 2, 3][..]));
        assert_eq!(msgpack_numpy::get(map, b"prompt").unwrap().as_str(), Some("pick up the bowl"));
        let no_images = libero_request(&obs, "x", None);
        assert_eq!(no_images.as_map().unwrap().len(), 2);
    }

    #[test]
    fn actions_are_read_from_a_float_n_by_7_array_only() {
        let reply = |a: NdArray| Value::Map(vec![(Value::from("actions"), a.to_value())]);
        let vals: Vec<f32> = (0..14).map(|i| i as f32).collect();
        let chunk = actions_of::<7>(&reply(NdArray::from_f32(&[2, 7], &vals))).unwrap();
        assert_eq!(chunk, [[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0]]);
        let f64s: Vec<f64> = (0..7).map(|i| i as f64 / 2.0).collect();
        assert_eq!(actions_of::<7>(&reply(NdArray::from_f64(&[1, 7], &f64s))).unwrap()[0][6], 3.0);
        assert!(actions_of::<7>(&reply(NdArray::from_f32(&[14], &vals))).unwrap_err().contains("shape"));
        assert!(actions_of::<7>(&reply(NdArray::from_f32(&[0, 7], &[]))).unwrap_err().contains("shape"));
        assert!(actions_of::<7>(&reply(NdArray::from_u8(&[1, 7], vec![0; 7]))).unwrap_err().contains("dtype"));
        let other = Value::Map(vec![(Value::from("action"), Value::from(1))]);
        assert!(actions_of::<7>(&other).unwrap_err().contains("no \"actions\""));
    }
}
