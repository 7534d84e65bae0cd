//! [`OpenpiAlohaPolicy`]: a policy served by openpi's policy server (π0's `pi0_aloha_sim`, or
//! anything) evaluated on ALOHA-sim as openpi's `examples/aloha_sim` evaluates it.
//!
//! The example (`examples/aloha_sim/env.py`, `main.py`; Physical-Intelligence/openpi) sends one
//! observation dict per request,
//!
//! | key | value |
//! |---|---|
//! | `"state"` | `obs["agent_pos"]`: per arm 6 joint positions and the normalized gripper, float64 (14,) |
//! | `"images"` | `{"cam_high": ...}`: the 480 × 640 `top` frame after `image_tools.resize_with_pad(224, 224)` (Pillow bilinear to 224 × 168, 28 black rows above and below), `convert_to_uint8`, then HWC → CHW: uint8 (3, 224, 224) |
//!
//! and no prompt: the server's config injects one (`default_prompt="Transfer cube"` for
//! `pi0_aloha_sim`). The reply's `"actions"` is an (N, 14) chunk (N = `action_horizon`, 50 for
//! `pi0_aloha_sim`; the server's `AlohaOutputs` already turned them back into the env's joint
//! targets); the client's `ActionChunkBroker(action_horizon=10)` executes the first 10 and asks
//! again. [`ALOHA_REPLAN_STEPS`] is that 10, `?replan=N` changes it, and both lengths go into the
//! identity. The connection, timeouts and reconnects are [`OpenpiServer`]'s, shared with LIBERO's
//! client.

use super::msgpack_numpy::NdArray;
use super::openpi::{OpenpiConfig, OpenpiServer, error};
use crate::aloha::{ALOHA_ACTION_DIM, AlohaAction, AlohaObservation, AlohaPolicy};
use crate::chunking::ActionChunker;
use crate::preprocess::image::resize_with_pad;
use crate::preprocess::{Filter, RgbImage};
use crate::{CameraImage, PolicyError};
use rmpv::Value;

/// `ActionChunkBroker(action_horizon=10)` of openpi's `examples/aloha_sim/main.py`: actions
/// executed per predicted chunk.
pub const ALOHA_REPLAN_STEPS: usize = 10;
/// Request keys of openpi's ALOHA-sim example (read by `AlohaInputs` in
/// `src/openpi/policies/aloha_policy.py`).
pub const KEY_STATE: &str = "state";
pub const KEY_IMAGES: &str = "images";
pub const KEY_CAM_HIGH: &str = "cam_high";
/// `cam_high`'s side after `resize_with_pad`.
pub const CAM_HIGH_SIZE: u32 = 224;

/// `"images"]["cam_high"]` from the `top` frame (upright RGB, as gym-aloha's `obs["pixels"]["top"]`):
/// `resize_with_pad` to 224 × 224 (Pillow bilinear, black bars), then channels first.
/// Returns the (3, 224, 224) bytes.
pub fn cam_high(top: &CameraImage) -> Result<Vec<u8>, PolicyError> {
    let img = RgbImage::new(top.width, top.height, top.rgb.clone())
        .map_err(|e| error(format!("the top camera's image: {e}")))?;
    let hwc = resize_with_pad(&img, CAM_HIGH_SIZE, CAM_HIGH_SIZE, Filter::Bilinear).rgb;
    let plane = (CAM_HIGH_SIZE * CAM_HIGH_SIZE) as usize;
    let mut chw = vec![0u8; 3 * plane];
    for (i, px) in hwc.chunks_exact(3).enumerate() {
        for (c, v) in px.iter().enumerate() {
            chw[c * plane + i] = *v;
        }
    }
    Ok(chw)
}

/// The observation dict of openpi's ALOHA-sim example: `{"state": (14,) f64, "images":
/// {"cam_high": (3, 224, 224) u8}}`, with `cam_high` already made by [`cam_high`].
pub fn aloha_request(agent_pos: &[f64; ALOHA_ACTION_DIM], cam_high_chw: Vec<u8>) -> Value {
    let size = CAM_HIGH_SIZE as usize;
    let images =
        Value::Map(vec![(Value::from(KEY_CAM_HIGH), NdArray::from_u8(&[3, size, size], cam_high_chw).to_value())]);
    Value::Map(vec![
        (Value::from(KEY_STATE), NdArray::from_f64(&[ALOHA_ACTION_DIM], agent_pos).to_value()),
        (Value::from(KEY_IMAGES), images),
    ])
}

/// A policy served by openpi's websocket policy server, on ALOHA-sim. One instance per rollout
/// worker, one connection ([`OpenpiServer`]).
#[derive(Debug)]
pub struct OpenpiAlohaPolicy {
    server: OpenpiServer,
    chunker: ActionChunker<AlohaAction>,
}

impl OpenpiAlohaPolicy {
    /// Connects and reads the server's metadata (within `config.connect_timeout`);
    /// `config.replan_steps` is the example's [`ALOHA_REPLAN_STEPS`] unless chosen otherwise.
    pub fn connect(config: OpenpiConfig) -> Result<Self, PolicyError> {
        let chunker = ActionChunker::new(config.replan_steps);
        Ok(OpenpiAlohaPolicy { server: OpenpiServer::connect(config)?, chunker })
    }

    /// Server queries since the last reset.
    pub fn queries(&self) -> u64 {
        self.chunker.queries()
    }

    /// Identity for the run manifest: the server's metadata, the request layout, both chunk lengths.
    pub fn identity(&self) -> serde_json::Value {
        self.server.identity(
            "openpi websocket + msgpack-numpy: server metadata first, one observation dict per request, reply {\"actions\": (N, 14)}",
            serde_json::json!({
                "benchmark": "aloha_sim",
                "keys": [KEY_STATE, format!("{KEY_IMAGES}/{KEY_CAM_HIGH}")],
                "state": "float64 (14,): agent_pos, per arm 6 joint positions and the normalized gripper",
                "prompt": "none sent (openpi's aloha_sim example; the server's default_prompt applies)",
                "images": {
                    "cameras": ["top"],
                    "render": "480x640, look mujoco-3.3.7 (the scene's own visual settings)",
                    "preprocessing": "resize_with_pad 224 (pil-bilinear, black bars), uint8, CHW (3, 224, 224)",
                },
            }),
        )
    }
}

impl AlohaPolicy for OpenpiAlohaPolicy {
    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        self.chunker.set_ensemble(Some(ensemble));
        Ok(())
    }

    fn queries_model(&self) -> bool {
        self.chunker.needs_query()
    }

    fn reset(&mut self, _episode_seed: u64) {
        self.chunker.reset();
    }

    fn act(&mut self, obs: &AlohaObservation) -> Result<AlohaAction, PolicyError> {
        if self.chunker.needs_query() {
            let top = obs.top.as_ref().ok_or_else(|| error("the env rendered no top camera for the request".into()))?;
            let request = aloha_request(&obs.agent_pos, cam_high(top)?);
            let chunk = self.server.query::<ALOHA_ACTION_DIM>(&request)?;
            self.chunker.push_chunk(chunk).map_err(error)?;
        }
        Ok(self.chunker.next_action().expect("a chunk of at least replan_steps >= 1 actions was queued"))
    }

    /// Renders only when a request is due: the queued actions of a chunk need none.
    fn wants_top_camera(&self) -> bool {
        self.chunker.needs_query()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::remote::msgpack_numpy;

    #[test]
    fn cam_high_is_the_padded_frame_channels_first() {
        // a 480 x 640 frame: red 10, green the row / 2, blue 200
        let (w, h) = (640u32, 480u32);
        let rgb = (0..w * h).flat_map(|i| [10u8, ((i / w) / 2) as u8, 200]).collect();
        let chw = cam_high(&CameraImage { width: w, height: h, rgb }).unwrap();
        assert_eq!(chw.len(), 3 * 224 * 224);
        let at = |c: usize, y: usize, x: usize| chw[c * 224 * 224 + y * 224 + x];
        // 640 x 480 fits as 224 x 168: 28 black rows above and below
        for x in [0, 100, 223] {
            assert_eq!((at(0, 27, x), at(2, 27, x), at(0, 196, x)), (0, 0, 0));
            assert_eq!((at(0, 28, x), at(2, 28, x), at(0, 195, x), at(2, 195, x)), (10, 200, 10, 200));
        }
        // the green ramp runs down the picture, not across it
        assert!(at(1, 190, 5) > at(1, 40, 5) + 150);
        assert_eq!(at(1, 100, 0), at(1, 100, 223));
    }

    #[test]
    fn the_request_has_the_aloha_example_keys_and_types() {
        let pos: [f64; 14] = std::array::from_fn(|i| i as f64 / 10.0);
        let req = aloha_request(&pos, vec![3; 3 * 224 * 224]);
        let json_keys: Vec<&str> = req.as_map().unwrap().iter().map(|(k, _)| k.as_str().unwrap()).collect();
        assert_eq!(json_keys, [KEY_STATE, KEY_IMAGES]);
        let map = req.as_map().unwrap();
        let state = NdArray::from_value(msgpack_numpy::get(map, b"state").unwrap()).unwrap().unwrap();
        assert_eq!((state.dtype.as_str(), state.shape.as_slice()), ("<f8", &[14][..]));
        assert_eq!(state.to_f64().unwrap(), pos);
        let images = msgpack_numpy::get(map, b"images").unwrap().as_map().unwrap();
        let cam = NdArray::from_value(msgpack_numpy::get(images, b"cam_high").unwrap()).unwrap().unwrap();
        assert_eq!((cam.dtype.as_str(), cam.shape.as_slice()), ("|u1", &[3, 224, 224][..]));
    }
}
