//! One blocking websocket connection to an openpi policy server, with deadlines.
//!
//! The protocol (`packages/openpi-client/src/openpi_client/websocket_client_policy.py` and
//! `src/openpi/serving/websocket_policy_server.py` in Physical-Intelligence/openpi):
//!
//! 1. the client opens a websocket (no compression; `Authorization: Api-Key <key>` when a key is
//!    given); the server answers the handshake and at once sends its **metadata**, one binary
//!    message: a msgpack-numpy map (`policy.metadata`, `{}` when the policy has none);
//! 2. per request the client sends one binary message, the observation dict, and reads one reply:
//!    a binary msgpack-numpy map (`{"actions": ndarray, "server_timing": {...}, ...}`), or, when
//!    the policy raised, a **text** message with the server's traceback, after which the server
//!    closes with code 1011 (internal error).
//!
//! Every read and write runs under a deadline (the connect timeout for the TCP connect, the
//! handshake and the metadata; the request timeout for one request and its reply), enforced on
//! the socket itself, so a silent server costs at most the timeout, never a hang. After any
//! failure the connection is closed and not used again: a late reply must never be taken for the
//! answer to the next request. [`OpenpiConnection`] is the transport only; the LIBERO loop
//! (request layout, action chunks) is [`super::OpenpiPolicy`].

use super::msgpack_numpy::{self, DecodeError};
use rmpv::Value;
use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};
use tungstenite::client::IntoClientRequest;
use tungstenite::protocol::WebSocket;
use tungstenite::{HandshakeError, Message};

/// Why a connection or a request failed.
#[derive(Debug, thiserror::Error)]
pub enum RemoteError {
    #[error("bad server address {url:?}: {detail}")]
    Address { url: String, detail: String },
    #[error("cannot connect to {url}: {detail}")]
    Connect { url: String, detail: String },
    #[error("no reply from {url} within {timeout:?} ({during})")]
    Timeout { url: String, timeout: Duration, during: &'static str },
    #[error("connection to {url} dropped ({during}): {detail}")]
    Dropped { url: String, during: &'static str, detail: String },
    #[error("the policy server at {url} failed:\n{message}")]
    Server { url: String, message: String },
    #[error("malformed reply from {url} ({during}): {detail}")]
    Malformed { url: String, during: &'static str, detail: String },
}

/// A `TcpStream` whose every read and write gives up at a deadline: before each call the socket
/// timeout is set to the time left, and a timed-out call is reported as `TimedOut` (Linux says
/// `WouldBlock`, which tungstenite would take for a non-blocking socket and retry later).
#[derive(Debug)]
struct DeadlineStream {
    tcp: TcpStream,
    deadline: Instant,
}

impl DeadlineStream {
    fn left(&self) -> io::Result<Duration> {
        let left = self.deadline.saturating_duration_since(Instant::now());
        if left.is_zero() { Err(io::Error::new(io::ErrorKind::TimedOut, "deadline passed")) } else { Ok(left) }
    }

    fn timed_out(e: io::Error) -> io::Error {
        match e.kind() {
            io::ErrorKind::WouldBlock => io::Error::new(io::ErrorKind::TimedOut, "deadline passed"),
            _ => e,
        }
    }
}

impl Read for DeadlineStream {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.tcp.set_read_timeout(Some(self.left()?))?;
        self.tcp.read(buf).map_err(Self::timed_out)
    }
}

impl Write for DeadlineStream {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.tcp.set_write_timeout(Some(self.left()?))?;
        self.tcp.write(buf).map_err(Self::timed_out)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.tcp.flush()
    }
}

/// A connected openpi policy server: the websocket and the metadata it sent first.
#[derive(Debug)]
pub struct OpenpiConnection {
    ws: WsConnection,
    metadata: Value,
}

impl OpenpiConnection {
    /// Connects to `url` (`ws://host:port[/path]`; `host:port` alone is taken as `ws://`, as
    /// openpi's client does), does the websocket handshake and reads the metadata message, all
    /// within `connect_timeout`. `wss://` is refused: this build has no TLS.
    pub fn connect(
        url: &str,
        api_key: Option<&str>,
        connect_timeout: Duration,
        request_timeout: Duration,
    ) -> Result<Self, RemoteError> {
        let (mut ws, deadline) = WsConnection::connect(url, api_key, connect_timeout, request_timeout)?;
        let metadata = ws.receive(deadline, connect_timeout, "reading the server's metadata")?;
        Ok(OpenpiConnection { ws, metadata })
    }

    /// The server's metadata message, as decoded.
    pub fn metadata(&self) -> &Value {
        &self.metadata
    }

    pub fn url(&self) -> &str {
        self.ws.url()
    }

    /// False after any failure: the connection is closed and must be replaced.
    pub fn is_open(&self) -> bool {
        self.ws.is_open()
    }

    /// One request: sends `obs` (a map) and returns the reply map, within the request timeout.
    pub fn infer(&mut self, obs: &Value) -> Result<Value, RemoteError> {
        self.ws.request(obs, "sending the observation", "waiting for the actions")
    }
}

/// One websocket to a policy server whose messages are msgpack maps (openpi's, vla-eval's), with
/// deadlines on every read and write and closed for good after any failure. The protocol on top
/// (who speaks first, what a request is) is the caller's.
#[derive(Debug)]
pub struct WsConnection {
    url: String,
    ws: Option<WebSocket<DeadlineStream>>,
    request_timeout: Duration,
}

impl WsConnection {
    /// Connects to `url` (`ws://host:port[/path]`, or `host:port`) and does the websocket
    /// handshake within `connect_timeout`; returns the connection and the connect deadline, for
    /// the protocol's own greeting. `wss://` is refused: this build has no TLS.
    pub fn connect(
        url: &str,
        api_key: Option<&str>,
        connect_timeout: Duration,
        request_timeout: Duration,
    ) -> Result<(Self, Instant), RemoteError> {
        let url = if url.contains("://") { url.to_string() } else { format!("ws://{url}") };
        let address = |detail: String| RemoteError::Address { url: url.clone(), detail };
        let connect = |detail: String| RemoteError::Connect { url: url.clone(), detail };
        let mut request = url.as_str().into_client_request().map_err(|e| address(e.to_string()))?;
        if request.uri().scheme_str() != Some("ws") {
            return Err(address("only ws:// is supported (no TLS in this build)".into()));
        }
        let host = request.uri().host().ok_or_else(|| address("no host".into()))?.to_string();
        let port = request.uri().port_u16().unwrap_or(80);
        if let Some(key) = api_key {
            let value =
                format!("Api-Key {key}").parse().map_err(|_| address("API key is not a valid header value".into()))?;
            request.headers_mut().insert("Authorization", value);
        }
        let deadline = Instant::now() + connect_timeout;
        let addrs: Vec<_> = (host.trim_matches(['[', ']']), port)
            .to_socket_addrs()
            .map_err(|e| connect(format!("cannot resolve {host}: {e}")))?
            .collect();
        let mut last = format!("{host} resolves to no address");
        let mut tcp = None;
        for addr in addrs {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(RemoteError::Timeout { url, timeout: connect_timeout, during: "TCP connect" });
            }
            match TcpStream::connect_timeout(&addr, left) {
                Ok(s) => {
                    tcp = Some(s);
                    break;
                }
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {
                    return Err(RemoteError::Timeout { url, timeout: connect_timeout, during: "TCP connect" });
                }
                Err(e) => last = format!("{addr}: {e}"),
            }
        }
        let tcp = tcp.ok_or_else(|| connect(last))?;
        // Requests are small and latency-bound: send each frame at once.
        tcp.set_nodelay(true).map_err(|e| connect(e.to_string()))?;
        let stream = DeadlineStream { tcp, deadline };
        let ws = match tungstenite::client::client_with_config(request, stream, None) {
            Ok((ws, _response)) => ws,
            Err(HandshakeError::Failure(e)) => {
                return Err(match e {
                    tungstenite::Error::Io(io) if io.kind() == io::ErrorKind::TimedOut => {
                        RemoteError::Timeout { url, timeout: connect_timeout, during: "websocket handshake" }
                    }
                    e => connect(format!("websocket handshake: {e}")),
                });
            }
            Err(HandshakeError::Interrupted(_)) => {
                return Err(RemoteError::Timeout { url, timeout: connect_timeout, during: "websocket handshake" });
            }
        };
        Ok((WsConnection { url, ws: Some(ws), request_timeout }, deadline))
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    /// False after any failure: the connection is closed and must be replaced.
    pub fn is_open(&self) -> bool {
        self.ws.is_some()
    }

    /// The per-request timeout this connection was opened with.
    pub fn request_timeout(&self) -> Duration {
        self.request_timeout
    }

    /// One request: sends `msg` (a map) and returns the reply map, within the request timeout.
    pub fn request(&mut self, msg: &Value, sending: &'static str, waiting: &'static str) -> Result<Value, RemoteError> {
        let deadline = Instant::now() + self.request_timeout;
        self.send(msg, deadline, self.request_timeout, sending)?;
        self.receive(deadline, self.request_timeout, waiting)
    }

    /// Sends `msg` as one binary message, by `deadline`.
    pub fn send(
        &mut self,
        msg: &Value,
        deadline: Instant,
        timeout: Duration,
        during: &'static str,
    ) -> Result<(), RemoteError> {
        let Some(ws) = self.ws.as_mut() else {
            return Err(self.dropped(during, "the connection was closed after an earlier failure".into()));
        };
        ws.get_mut().deadline = deadline;
        match ws.send(Message::Binary(msgpack_numpy::pack(msg).into())) {
            Ok(()) => Ok(()),
            Err(e) => Err(self.fail(e, timeout, during)),
        }
    }

    /// Reads the next data message by `deadline`: binary → a decoded map; text → the server's
    /// error.
    pub fn receive(
        &mut self,
        deadline: Instant,
        timeout: Duration,
        during: &'static str,
    ) -> Result<Value, RemoteError> {
        loop {
            let Some(ws) = self.ws.as_mut() else {
                return Err(self.dropped(during, "the connection was closed after an earlier failure".into()));
            };
            ws.get_mut().deadline = deadline;
            match ws.read() {
                Ok(Message::Binary(bytes)) => {
                    return match msgpack_numpy::unpack(&bytes) {
                        Ok(v) if v.is_map() => Ok(v),
                        Ok(v) => Err(self.malformed(during, DecodeError(format!("expected a map, got {v}")))),
                        Err(e) => Err(self.malformed(during, e)),
                    };
                }
                Ok(Message::Text(text)) => {
                    self.close();
                    return Err(RemoteError::Server {
                        url: self.url.clone(),
                        message: text.as_str().trim_end().to_string(),
                    });
                }
                Ok(Message::Close(frame)) => {
                    let why = frame
                        .map_or("no close frame".to_string(), |f| format!("code {}, {:?}", f.code, f.reason.as_str()));
                    return Err(self.dropped(during, format!("the server closed the connection ({why})")));
                }
                Ok(_) => continue, // ping/pong: tungstenite answers pings itself
                Err(e) => return Err(self.fail(e, timeout, during)),
            }
        }
    }

    fn fail(&mut self, e: tungstenite::Error, timeout: Duration, during: &'static str) -> RemoteError {
        match e {
            tungstenite::Error::Io(io) if io.kind() == io::ErrorKind::TimedOut => {
                self.close();
                RemoteError::Timeout { url: self.url.clone(), timeout, during }
            }
            e => self.dropped(during, e.to_string()),
        }
    }

    fn dropped(&mut self, during: &'static str, detail: String) -> RemoteError {
        self.close();
        RemoteError::Dropped { url: self.url.clone(), during, detail }
    }

    /// Closes the connection and reports `detail` as a malformed reply (a protocol violation the
    /// caller found in a well-formed map).
    pub fn malformed_reply(&mut self, during: &'static str, detail: String) -> RemoteError {
        self.malformed(during, DecodeError(detail))
    }

    fn malformed(&mut self, during: &'static str, e: DecodeError) -> RemoteError {
        self.close();
        RemoteError::Malformed { url: self.url.clone(), during, detail: e.0 }
    }

    /// Closes the connection without waiting: a close frame if the socket takes it at once, then
    /// the socket is dropped (a server that stopped reading costs nothing).
    pub fn close(&mut self) {
        if let Some(mut ws) = self.ws.take() {
            ws.get_mut().deadline = Instant::now() + Duration::from_millis(50);
            let _ = ws.close(None);
            let _ = ws.flush();
        }
    }
}

impl Drop for WsConnection {
    fn drop(&mut self) {
        self.close();
    }
}

/// Checks that the server at `url` greets with what it sent first in this process (`what`: the
/// protocol's greeting, "HELLO" or "metadata"; kept apart per protocol). The rollout makes a
/// policy (a connection) per episode, and the run's identity is the greeting read at its start: a
/// server swapped for another at the same address mid-run must fail its episodes, not mix two
/// models in one run.
pub fn same_server(what: &str, url: &str, greeting: &serde_json::Value) -> Result<(), String> {
    type Seen = Vec<(String, String, serde_json::Value)>;
    static FIRST: std::sync::Mutex<Seen> = std::sync::Mutex::new(Vec::new());
    let mut first = FIRST.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    match first.iter().find(|(w, u, _)| w == what && u == url) {
        Some((_, _, g)) if g != greeting => Err(format!(
            "the server at {url} now sends another {what} than at the run's start (was {g}, now {greeting}): not the model this run started with"
        )),
        Some(_) => Ok(()),
        None => {
            first.push((what.to_string(), url.to_string(), greeting.clone()));
            Ok(())
        }
    }
}
