//! Naming a policy on the command line and recording its identity in the run manifest.

use crate::remote::openpi::{LIBERO_REPLAN_STEPS, OpenpiConfig, OpenpiPolicy};
use crate::{Expert, ExpertDrop, LiftPolicy, NanAtPolicy, Policy, PolicyError, RandomPolicy};
use std::fmt;
use std::str::FromStr;

/// A policy a run evaluates, as named on the command line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PolicySpec {
    /// Uniform random actions (baseline; must score ≈ 0).
    Random,
    /// Move up, gripper untouched (baseline; must score ≈ 0).
    Lift,
    /// The privileged scripted expert (positive control; reads the simulator state).
    Expert,
    /// Diagnostic: NaN action at policy step N (exercises error rows).
    NanAt(u32),
    /// Diagnostic: the expert forced to let go early in its first carry (real `dropped` failures).
    ExpertDrop,
    /// A TorchScript module with its `model.json` manifest (`torchscript:<file>[?batch=N]`;
    /// with `batch`, the rollout workers' queries share forwards of up to N episodes).
    TorchScript { file: std::path::PathBuf, batch: Option<usize> },
    /// OpenVLA in process from a Hugging Face checkpoint directory
    /// (`openvla:<dir>[?unnorm=<key>][&batch=N]`; with `batch`, the rollout workers' queries share
    /// forwards of up to N episodes).
    OpenVla { dir: std::path::PathBuf, unnorm_key: Option<String>, batch: Option<usize> },
    /// A policy served by openpi's websocket policy server (`openpi:ws://host:port[?replan=N]`).
    Openpi { url: String, replan_steps: usize },
}

impl PolicySpec {
    /// A fresh instance for one rollout worker.
    pub fn instantiate(&self) -> Result<Box<dyn Policy>, PolicyError> {
        Ok(match self {
            PolicySpec::Random => Box::new(RandomPolicy::new()),
            PolicySpec::Lift => Box::new(LiftPolicy),
            PolicySpec::Expert => Box::new(Expert::new()),
            PolicySpec::NanAt(n) => Box::new(NanAtPolicy { at: *n }),
            PolicySpec::ExpertDrop => Box::new(ExpertDrop::new()),
            PolicySpec::TorchScript { file, batch } => load_torchscript(file, *batch, &self.to_string())?,
            PolicySpec::OpenVla { dir, unnorm_key, batch } => {
                load_openvla(dir, unnorm_key.clone(), *batch, &self.to_string())?
            }
            PolicySpec::Openpi { url, replan_steps } => Box::new(OpenpiPolicy::connect(OpenpiConfig {
                replan_steps: *replan_steps,
                ..OpenpiConfig::new(url.clone())
            })?),
        })
    }

    /// Short name stored in every episode row.
    pub fn name(&self) -> String {
        self.to_string()
    }

    /// Baselines are expected to fail; results warn when one scores above 5%.
    pub fn is_baseline(&self) -> bool {
        matches!(self, PolicySpec::Random | PolicySpec::Lift)
    }

    /// The identity for the run manifest, asking the policy itself where only it knows (a remote
    /// server's metadata): a server that cannot be reached fails the run before any episode.
    pub fn resolve_identity(&self) -> Result<serde_json::Value, PolicyError> {
        match self {
            PolicySpec::Openpi { url, replan_steps } => Ok(OpenpiPolicy::connect(OpenpiConfig {
                replan_steps: *replan_steps,
                ..OpenpiConfig::new(url.clone())
            })?
            .identity()),
            #[cfg(feature = "torch")]
            PolicySpec::TorchScript { file, batch } => {
                Ok(crate::torchscript::TorchScriptModel::load(file)?.identity(*batch))
            }
            #[cfg(feature = "torch")]
            PolicySpec::OpenVla { dir, unnorm_key, batch } => {
                crate::openvla::OpenVlaPolicy::identity_of(dir, unnorm_key.as_deref(), *batch)
            }
            _ => Ok(self.identity()),
        }
    }

    /// Identity for the manifest: what a reader needs to know which policy produced the steps
    /// (checkpoint hash, unnorm key, chunking and image preprocessing for model policies).
    pub fn identity(&self) -> serde_json::Value {
        match self {
            PolicySpec::Random => serde_json::json!({
                "kind": "baseline", "name": "random", "distribution": "uniform [-1,1]^7",
                "rng": "ChaCha8 seeded per episode from the episode key", "chunking": 1,
            }),
            PolicySpec::Lift => serde_json::json!({
                "kind": "baseline", "name": "lift", "action": [0, 0, 0.05, 0, 0, 0, 0], "chunking": 1,
            }),
            PolicySpec::Expert => serde_json::json!({
                "kind": "scripted expert", "name": "expert", "privileged": true,
                "plan": "goal terms -> pick-and-place / open / close / turn-on skills, closed loop on the eef pose",
                "chunking": 1,
            }),
            PolicySpec::NanAt(n) => {
                serde_json::json!({"kind": "diagnostic", "name": "nan-at", "step": n})
            }
            PolicySpec::OpenVla { dir, unnorm_key, batch } => serde_json::json!({
                "kind": "openvla", "checkpoint": dir.display().to_string(), "unnorm_key": unnorm_key,
                "batch": batch,
                "checkpoint_sha256": "read at run start (resolve_identity)",
            }),
            PolicySpec::TorchScript { file, .. } => serde_json::json!({
                "kind": "torchscript", "file": file.display().to_string(),
                "sha256": "read at run start (resolve_identity)",
            }),
            PolicySpec::Openpi { url, replan_steps } => serde_json::json!({
                "kind": "remote", "name": "openpi", "url": url, "replan_steps": replan_steps,
                "server_metadata": "read at run start (resolve_identity)",
            }),
            PolicySpec::ExpertDrop => serde_json::json!({
                "kind": "diagnostic", "name": "expert-drop", "privileged": true,
                "forced": "the expert opens its gripper 5 steps into its first carry, then holds still",
                "chunking": 1,
            }),
        }
    }
}

impl fmt::Display for PolicySpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PolicySpec::Random => f.write_str("random"),
            PolicySpec::Lift => f.write_str("lift"),
            PolicySpec::Expert => f.write_str("expert"),
            PolicySpec::NanAt(n) => write!(f, "nan-at:{n}"),
            PolicySpec::ExpertDrop => f.write_str("expert-drop"),
            PolicySpec::OpenVla { dir, unnorm_key, batch } => {
                let options: Vec<String> =
                    [unnorm_key.as_ref().map(|k| format!("unnorm={k}")), batch.map(|b| format!("batch={b}"))]
                        .into_iter()
                        .flatten()
                        .collect();
                match options.is_empty() {
                    true => write!(f, "openvla:{}", dir.display()),
                    false => write!(f, "openvla:{}?{}", dir.display(), options.join("&")),
                }
            }
            PolicySpec::TorchScript { file, batch: None } => write!(f, "torchscript:{}", file.display()),
            PolicySpec::TorchScript { file, batch: Some(b) } => write!(f, "torchscript:{}?batch={b}", file.display()),
            PolicySpec::Openpi { url, replan_steps } if *replan_steps == LIBERO_REPLAN_STEPS => {
                write!(f, "openpi:{url}")
            }
            PolicySpec::Openpi { url, replan_steps } => write!(f, "openpi:{url}?replan={replan_steps}"),
        }
    }
}

impl FromStr for PolicySpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "random" => Ok(PolicySpec::Random),
            "lift" => Ok(PolicySpec::Lift),
            "expert" => Ok(PolicySpec::Expert),
            "expert-drop" => Ok(PolicySpec::ExpertDrop),
            _ if s.starts_with("openpi:") => parse_openpi(&s["openpi:".len()..]),
            _ if s.starts_with("openvla:") && s.len() > "openvla:".len() => parse_openvla(&s["openvla:".len()..]),
            _ if s.starts_with("torchscript:") && s.len() > "torchscript:".len() => {
                parse_torchscript(&s["torchscript:".len()..])
            }
            _ => match s.strip_prefix("nan-at:").map(str::parse) {
                Some(Ok(n)) => Ok(PolicySpec::NanAt(n)),
                _ => Err(format!(
                    "unknown policy {s:?}; known: random, lift, expert, openpi:ws://host:port[?replan=N], torchscript:<model.pt>[?batch=N], openvla:<checkpoint dir>[?unnorm=<key>][&batch=N]; diagnostics: nan-at:<policy step>, expert-drop"
                )),
            },
        }
    }
}

/// A worker's policy on the process-wide batcher of `spec` (its text, options included: one model
/// and one batcher per distinct spec), loading the model with the first worker.
#[cfg(feature = "torch")]
fn batched<M: crate::batching::BatchModel>(
    spec: &str,
    max_batch: usize,
    policy: &str,
    load: impl FnOnce() -> Result<M, PolicyError>,
) -> Result<Box<dyn Policy>, PolicyError> {
    use crate::batching::{BatchedPolicy, shared_batcher};
    // Wait briefly for the other workers' queries: they arrive within a physics step.
    let batcher = shared_batcher(spec, || Ok((load()?, max_batch, std::time::Duration::from_millis(20))))?;
    let replan = batcher.replan_steps();
    Ok(Box::new(BatchedPolicy::new(batcher, replan, policy)))
}

#[cfg(feature = "torch")]
fn load_torchscript(file: &std::path::Path, batch: Option<usize>, spec: &str) -> Result<Box<dyn Policy>, PolicyError> {
    use crate::torchscript::{TorchScriptModel, TorchScriptPolicy};
    match batch {
        None => Ok(Box::new(TorchScriptPolicy::load(file)?)),
        Some(n) => batched(spec, n, "torchscript", || TorchScriptModel::load(file)),
    }
}

#[cfg(feature = "torch")]
fn load_openvla(
    dir: &std::path::Path,
    unnorm_key: Option<String>,
    batch: Option<usize>,
    spec: &str,
) -> Result<Box<dyn Policy>, PolicyError> {
    use crate::openvla::{OpenVlaBatchModel, OpenVlaPolicy};
    match batch {
        None => Ok(Box::new(OpenVlaPolicy::load(dir, unnorm_key)?)),
        Some(n) => batched(spec, n, "openvla", || OpenVlaBatchModel::load(dir, unnorm_key)),
    }
}

#[cfg(not(feature = "torch"))]
fn load_openvla(
    _: &std::path::Path,
    _: Option<String>,
    _: Option<usize>,
    _: &str,
) -> Result<Box<dyn Policy>, PolicyError> {
    Err(PolicyError {
        policy: "openvla".into(),
        detail: "this build has no libtorch (built without the `torch` feature)".into(),
    })
}

#[cfg(not(feature = "torch"))]
fn load_torchscript(_: &std::path::Path, _: Option<usize>, _: &str) -> Result<Box<dyn Policy>, PolicyError> {
    Err(PolicyError {
        policy: "torchscript".into(),
        detail: "this build has no libtorch (built without the `torch` feature)".into(),
    })
}

/// `<dir>[?unnorm=<key>][&batch=N]` of `openvla:...` (options in any order).
fn parse_openvla(rest: &str) -> Result<PolicySpec, String> {
    let (dir, query) = rest.split_once('?').map_or((rest, None), |(d, q)| (d, Some(q)));
    let (mut unnorm_key, mut batch) = (None, None);
    for option in query.into_iter().flat_map(|q| q.split('&')) {
        match option.split_once('=') {
            Some(("unnorm", _)) if unnorm_key.is_some() => {
                return Err(format!("openvla:{rest}: unnorm is given twice"));
            }
            Some(("batch", _)) if batch.is_some() => return Err(format!("openvla:{rest}: batch is given twice")),
            Some(("unnorm", k)) if !k.is_empty() => unnorm_key = Some(k.to_string()),
            Some(("batch", n)) if n.parse::<usize>().is_ok_and(|n| n >= 1) => batch = n.parse().ok(),
            _ => {
                return Err(format!(
                    "openvla:{rest}: unknown option {option:?}; the options are ?unnorm=<dataset key> and \
                     &batch=N with N >= 1 (episodes per forward)"
                ));
            }
        }
    }
    Ok(PolicySpec::OpenVla { dir: dir.into(), unnorm_key, batch })
}

/// `<file>[?batch=N]` of `torchscript:...`.
fn parse_torchscript(rest: &str) -> Result<PolicySpec, String> {
    let (file, query) = rest.split_once('?').map_or((rest, None), |(f, q)| (f, Some(q)));
    let batch = match query {
        None => None,
        Some(q) => match q.strip_prefix("batch=").map(str::parse::<usize>) {
            Some(Ok(n)) if n >= 1 => Some(n),
            _ => {
                return Err(format!(
                    "torchscript:{rest}: the only option is ?batch=N with N >= 1 (episodes per forward)"
                ));
            }
        },
    };
    Ok(PolicySpec::TorchScript { file: file.into(), batch })
}

/// `ws://host:port[?replan=N]` of `openpi:...`.
fn parse_openpi(rest: &str) -> Result<PolicySpec, String> {
    let (url, query) = rest.split_once('?').map_or((rest, None), |(u, q)| (u, Some(q)));
    if !url.starts_with("ws://") {
        return Err(format!("openpi:{rest}: the server address must be a ws:// URL, e.g. openpi:ws://localhost:8000"));
    }
    let replan_steps = match query {
        None => LIBERO_REPLAN_STEPS,
        Some(q) => match q.strip_prefix("replan=").map(str::parse::<usize>) {
            Some(Ok(n)) if n >= 1 => n,
            _ => {
                return Err(format!(
                    "openpi:{rest}: the only option is ?replan=N with N >= 1 (actions executed per chunk)"
                ));
            }
        },
    };
    Ok(PolicySpec::Openpi { url: url.to_string(), replan_steps })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn openpi_specs_parse_and_print_back() {
        let p: PolicySpec = "openpi:ws://localhost:8000".parse().unwrap();
        assert_eq!(p, PolicySpec::Openpi { url: "ws://localhost:8000".into(), replan_steps: 5 });
        assert_eq!(p.to_string(), "openpi:ws://localhost:8000");
        let p: PolicySpec = "openpi:ws://h:1?replan=10".parse().unwrap();
        assert_eq!(p.to_string(), "openpi:ws://h:1?replan=10");
        assert!("openpi:http://h:1".parse::<PolicySpec>().unwrap_err().contains("ws://"));
        assert!("openpi:ws://h:1?replan=0".parse::<PolicySpec>().unwrap_err().contains("replan=N"));
        assert!("nope".parse::<PolicySpec>().unwrap_err().contains("openpi:ws://"));
    }

    #[test]
    fn openvla_specs_parse_in_any_option_order_and_print_back() {
        let dir = std::path::PathBuf::from("/ckpt/openvla-7b");
        let cases = [
            ("openvla:/ckpt/openvla-7b", None, None, "openvla:/ckpt/openvla-7b"),
            ("openvla:/ckpt/openvla-7b?unnorm=k", Some("k"), None, "openvla:/ckpt/openvla-7b?unnorm=k"),
            ("openvla:/ckpt/openvla-7b?batch=8", None, Some(8), "openvla:/ckpt/openvla-7b?batch=8"),
            (
                "openvla:/ckpt/openvla-7b?batch=8&unnorm=k",
                Some("k"),
                Some(8),
                "openvla:/ckpt/openvla-7b?unnorm=k&batch=8",
            ),
        ];
        for (text, unnorm, batch, printed) in cases {
            let p: PolicySpec = text.parse().unwrap();
            let expected = PolicySpec::OpenVla { dir: dir.clone(), unnorm_key: unnorm.map(str::to_string), batch };
            assert_eq!(p, expected, "{text}");
            assert_eq!(p.to_string(), printed);
            assert_eq!(printed.parse::<PolicySpec>().unwrap(), expected, "{printed} reads back");
        }
        for (bad, says) in [
            ("openvla:/c?batch=0", "batch=N"),
            ("openvla:/c?unnorm=", "unnorm=<dataset key>"),
            ("openvla:/c?unnorm=a&unnorm=b", "twice"),
            ("openvla:/c?batch=2&batch=4", "twice"),
            ("openvla:/c?replan=4", "unknown option"),
        ] {
            let e = bad.parse::<PolicySpec>().unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }
}
