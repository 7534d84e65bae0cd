//! Policies served over the network: a client of openpi's websocket policy server, so that a
//! π0/π0.5 served by openpi (`scripts/serve_policy.py`) is evaluated unchanged, and a client of
//! vla-eval's model-server protocol, which serves OFT, π0/π0.5, lerobot, GR00T, X-VLA, starVLA...
//!
//! - [`msgpack_numpy`]: the wire format, MessagePack with NumPy arrays as bin-keyed maps;
//! - [`client`]: one blocking websocket connection with deadlines ([`WsConnection`]), and
//!   openpi's use of it ([`OpenpiConnection`]): the server's metadata first, then one
//!   observation dict per request;
//! - [`openpi`]: [`OpenpiPolicy`], the [`crate::Policy`] of openpi's LIBERO example (request
//!   keys, state layout, action chunks executed `replan_steps` at a time);
//! - [`openpi_aloha`]: [`OpenpiAlohaPolicy`], the [`crate::aloha::AlohaPolicy`] of openpi's
//!   ALOHA-sim example (`state` and `images/cam_high` padded to 224 channels first, chunks of 50
//!   executed 10 at a time), on the same connection code ([`openpi::OpenpiServer`]);
//! - [`vla_eval`]: [`VlaEvalPolicy`], vla-eval's protocol (HELLO with the server's observation
//!   params, episode start/end, string-keyed arrays, PNG images, ERROR frames) and what its LIBERO
//!   benchmark sends and executes (one observation per step; the server keeps the chunk);
//! - [`starvla`]: [`StarVlaPolicy`], starVLA's policy server (VLA-JEPA's route): metadata first,
//!   a request/reply envelope with errors as frames, both payload generations (HEAD's
//!   server-side unnormalisation; VLA-JEPA's normalised actions unnormalised here from the
//!   checkpoint's `dataset_statistics.json`), action chunks executed whole.
//!
//! The rollout calls [`crate::Policy::act`] synchronously from rayon workers, one policy instance
//! per worker, so the client is blocking and owns one connection. A timeout, a dropped
//! connection, a malformed reply or the server's error text is a [`crate::PolicyError`] (the
//! rollout turns it into an error row), never a hang or a panic.
//!
//! ```no_run
//! use libero_policies::remote::{OpenpiConfig, OpenpiPolicy};
//! use libero_policies::{Observation, Policy};
//! let mut policy = OpenpiPolicy::connect(OpenpiConfig::new("ws://localhost:8000")).unwrap();
//! println!("{}", policy.identity()); // server metadata, replan_steps, ...
//! policy.reset("put the bowl on the plate", 0);
//! let action = policy.act(&Observation::default()).unwrap();
//! ```
//!
//! Dependencies, the smallest dependable set for this:
//! - `tungstenite` (0.28, its `handshake` feature only: no TLS, no `url`): the
//!   reference sync websocket implementation under tokio-tungstenite. It runs over any
//!   `Read + Write`, so it runs over our own `TcpStream` with per-call deadlines, and needs no
//!   async runtime in a crate that has none. 0.28 rather than 0.30: it reuses `sha1` 0.10, `rand`
//!   0.9, `http` and `httparse` already in the lock file and adds two small crates
//!   (`data-encoding`, `utf-8`); 0.30 would add the whole `digest` 0.11 stack for the same
//!   client. openpi's servers speak plain `ws://` on a trusted network; TLS is left out.
//! - `rmpv` (1.3, on `rmp`): schema-free MessagePack values. The format needs bin and str kept
//!   apart (array keys are bin, the dict's keys str) and arbitrary server maps (metadata, extra
//!   reply keys such as `server_timing`); a `Value` tree does that directly, where `rmp-serde`
//!   would need serde shims for bin-vs-str keys. Its decoder caps preallocation by declared
//!   lengths, so a malformed reply cannot make it allocate gigabytes.
//! - `png` (0.18, already in the workspace for the media output): vla-eval's image codec sends
//!   camera images PNG-encoded.

pub mod client;
pub mod msgpack_numpy;
pub mod openpi;
pub mod openpi_aloha;
pub mod starvla;
pub mod vla_eval;

pub use client::{OpenpiConnection, RemoteError, WsConnection};
pub use msgpack_numpy::NdArray;
pub use openpi::{OpenpiConfig, OpenpiImages, OpenpiPolicy, OpenpiServer, RgbImage};
pub use openpi_aloha::OpenpiAlohaPolicy;
pub use starvla::{Generation, StarVlaConfig, StarVlaPolicy};
pub use vla_eval::{ObservationParams, VlaEvalConfig, VlaEvalPolicy};
