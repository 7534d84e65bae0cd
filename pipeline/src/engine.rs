//! Which query engine runs a command: this process (`local`, the default) or an Apache Ballista
//! cluster (`ballista://host:port`, [`crate::distributed`]).

use anyhow::Result;
use std::fmt;
use std::str::FromStr;

#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub enum Engine {
    /// DataFusion in this process; episodes on this machine's cores.
    #[default]
    Local,
    /// A Ballista scheduler started with `pipeline scheduler`.
    Ballista { host: String, port: u16 },
}

impl FromStr for Engine {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "local" {
            return Ok(Engine::Local);
        }
        let Some(address) = s.strip_prefix("ballista://") else {
            return Err(format!(
                "unknown engine {s:?}: use `local` or `ballista://HOST:PORT` (a `pipeline scheduler`)"
            ));
        };
        let address = address.trim_end_matches('/');
        let (host, port) = address.rsplit_once(':').ok_or_else(|| {
            format!("engine {s:?} has no port: use ballista://HOST:PORT (the scheduler's port, 50050 by default)")
        })?;
        let port = port.parse().map_err(|_| format!("engine {s:?}: {port:?} is not a port number"))?;
        if host.is_empty() {
            return Err(format!("engine {s:?} has no host: use ballista://HOST:PORT"));
        }
        Ok(Engine::Ballista { host: host.to_string(), port })
    }
}

impl fmt::Display for Engine {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Engine::Local => write!(f, "local"),
            Engine::Ballista { host, port } => write!(f, "ballista://{host}:{port}"),
        }
    }
}

impl Engine {
    /// Whether a scheduler on this host runs on this machine (so a local run folder is shared).
    pub fn is_loopback(&self) -> bool {
        match self {
            Engine::Local => true,
            Engine::Ballista { host, .. } => matches!(host.as_str(), "localhost" | "127.0.0.1" | "::1" | "[::1]"),
        }
    }

    /// Stop here, before anything starts, when the engine cannot be used: a build without the
    /// `distributed` feature, or a scheduler that does not answer.
    pub async fn check(&self) -> Result<()> {
        match self {
            Engine::Local => Ok(()),
            #[cfg(feature = "distributed")]
            Engine::Ballista { host, port } => crate::distributed::client::check_scheduler(host, *port).await,
            #[cfg(not(feature = "distributed"))]
            Engine::Ballista { .. } => anyhow::bail!(
                "--engine {self}: this pipeline was built without the `distributed` feature; rebuild with `cargo build --release` (the default features)"
            ),
        }
    }
}

/// The `--engine` option of the commands that run queries.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct EngineArg {
    /// Query engine: local (this process) or ballista://HOST:PORT (a `pipeline scheduler` with
    /// `pipeline executor`s; the run location must be one every node reaches).
    #[arg(long, default_value = "local")]
    pub engine: Engine,
}

#[cfg(test)]
mod tests {
    use super::Engine;

    #[test]
    fn engines_parse_and_name_what_is_wrong() {
        assert_eq!("local".parse::<Engine>(), Ok(Engine::Local));
        assert_eq!(
            "ballista://sched:50050".parse::<Engine>(),
            Ok(Engine::Ballista { host: "sched".into(), port: 50050 })
        );
        assert!("ballista://sched".parse::<Engine>().unwrap_err().contains("no port"));
        assert!("ballista://sched:x".parse::<Engine>().unwrap_err().contains("not a port"));
        assert!("spark://a:1".parse::<Engine>().unwrap_err().contains("unknown engine"));
        assert!(Engine::Ballista { host: "127.0.0.1".into(), port: 1 }.is_loopback());
        assert!(!Engine::Ballista { host: "sched".into(), port: 1 }.is_loopback());
    }
}
