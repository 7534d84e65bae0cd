//! Naming a policy on the command line and recording its identity in the run manifest.

use crate::ensembling::{ENSEMBLE_HELP, Ensemble};
use crate::placement::{Attention, ModelDevice, Quantization, devices_text, parse_devices};
use crate::remote::openpi::{LIBERO_REPLAN_STEPS, OpenpiConfig, OpenpiPolicy};
use crate::remote::openpi_aloha::{ALOHA_REPLAN_STEPS, OpenpiAlohaPolicy};
use crate::remote::starvla::{StarVlaConfig, StarVlaPolicy};
use crate::remote::vla_eval::{VlaEvalConfig, VlaEvalPolicy};
use crate::{Expert, ExpertDrop, LiftPolicy, NanAtPolicy, Policy, PolicyError, RandomPolicy};
use libero_schema::Benchmark;
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
    /// A TorchScript module with its `model.json` manifest
    /// (`torchscript:<file>[?batch=N[&wait_ms=W]][&devices=D]`; with `batch`, the rollout workers'
    /// queries share forwards of up to N episodes; `devices`: the one device it runs on, e.g.
    /// `devices=cpu` to run it on the CPU on purpose, see `models::cpu_fallback`).
    TorchScript {
        file: std::path::PathBuf,
        batch: Option<Batching>,
        device: Option<ModelDevice>,
        ensemble: Option<Ensemble>,
    },
    /// OpenVLA in process from a Hugging Face checkpoint directory
    /// (`openvla:<dir>[?unnorm=<key>][&batch=N[&wait_ms=W]][&devices=D,D...][&quant=int8|int4]`;
    /// with `batch`, the rollout workers' queries share forwards of up to N episodes; several
    /// devices need `batch`).
    OpenVla(CheckpointOptions),
    /// OpenVLA-OFT in process from its released LIBERO checkpoint directory (the HF files,
    /// `action_head--*.pt`, `proprio_projector--*.pt`, `dataset_statistics.json`; the same options
    /// as `openvla:`): two cameras and the state, an 8-action chunk per query, executed whole.
    Oft(CheckpointOptions),
    /// A policy served by openpi's websocket policy server (`openpi:ws://host:port[?replan=N]`);
    /// without `replan`, the executed part of each chunk is the benchmark's example's (5 on LIBERO,
    /// 10 on ALOHA-sim; [`PolicySpec::openpi_replan_steps`]).
    Openpi { url: String, replan_steps: Option<usize>, ensemble: Option<Ensemble> },
    /// A model served by vla-eval's model server (`vla-eval:ws://host:port`): the server's
    /// observation params from its HELLO decide what is sent; it keeps the action chunks.
    VlaEval { url: String },
    /// A model served by starVLA's policy server (VLA-JEPA's route;
    /// `starvla:ws://host:port[?unnorm=<key>][&stats=<dataset_statistics.json>][&chunk=N][&state=0|1]`):
    /// the generation comes from the server's metadata.
    StarVla(StarVlaOptions),
    /// A Python policy in a host process the pipeline starts (`lerobot:<checkpoint dir>` or
    /// `python:<module>:<factory>`, options after `?`: see [`PythonOptions`]).
    Python(PythonOptions),
}

/// The options of `lerobot:<dir>` and `python:<module>:<factory>`
/// (`?python=<interpreter>&batch=N&wait_ms=W&devices=D,...&timeout_s=S&load_timeout_s=S`, and the
/// policy's own: `steps=N`, `tokenizer=<dir>` for lerobot; any `key=value` for `python:`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PythonOptions {
    pub target: crate::python_host::PythonTarget,
    pub interpreter: Option<std::path::PathBuf>,
    /// The forwards' sharing; None: every episode in progress, up to [`PythonOptions::DEFAULT_BATCH`].
    pub batch: Option<Batching>,
    /// One host per device; empty: one host on its default device (CUDA where its torch sees one).
    pub devices: Vec<ModelDevice>,
    pub call_timeout_s: Option<u64>,
    pub load_timeout_s: Option<u64>,
    /// Passed to the policy (`--option key=value`), in the order given.
    pub policy_options: Vec<(String, String)>,
    /// `ensemble=`: how the chunks the host returns are combined.
    pub ensemble: Option<Ensemble>,
}

impl PythonOptions {
    /// A host answers every episode in progress in one call unless `batch` says otherwise.
    pub const DEFAULT_BATCH: usize = 64;
    /// What the host's own `lerobot:` adapter takes; `python:` passes any other key through.
    const LEROBOT_OPTIONS: [&'static str; 2] = ["steps", "tokenizer"];
    const HOST_OPTIONS: [&'static str; 7] =
        ["python", "batch", "wait_ms", "devices", "timeout_s", "load_timeout_s", "benchmark"];

    pub fn host_config(&self, benchmark: Benchmark) -> crate::python_host::PythonHostConfig {
        use crate::python_host::PythonHostConfig as C;
        C {
            target: self.target.clone(),
            interpreter: self.interpreter.clone(),
            benchmark: benchmark.to_string(),
            options: self.policy_options.clone(),
            call_timeout: std::time::Duration::from_secs(self.call_timeout_s.unwrap_or(C::DEFAULT_CALL_TIMEOUT_S)),
            load_timeout: std::time::Duration::from_secs(self.load_timeout_s.unwrap_or(C::DEFAULT_LOAD_TIMEOUT_S)),
            whole_chunks: self.ensemble.is_some(),
        }
    }

    pub fn batching(&self) -> Batching {
        self.batch.unwrap_or(Batching { max_episodes: Self::DEFAULT_BATCH, wait_ms: Batching::DEFAULT_WAIT_MS })
    }

    fn replica_devices(&self) -> Vec<Option<ModelDevice>> {
        match self.devices.is_empty() {
            true => vec![None],
            false => self.devices.iter().copied().map(Some).collect(),
        }
    }

    fn options(&self) -> Vec<String> {
        let mut o: Vec<String> = self.interpreter.iter().map(|p| format!("python={}", p.display())).collect();
        o.extend(self.batch.iter().flat_map(Batching::options));
        if !self.devices.is_empty() {
            o.push(format!("devices={}", devices_text(&self.devices)));
        }
        o.extend(self.call_timeout_s.map(|s| format!("timeout_s={s}")));
        o.extend(self.load_timeout_s.map(|s| format!("load_timeout_s={s}")));
        o.extend(self.policy_options.iter().map(|(k, v)| format!("{k}={v}")));
        o
    }

    fn parse(kind: &str, rest: &str) -> Result<PythonOptions, String> {
        use crate::python_host::PythonTarget;
        let (target, query) = rest.split_once('?').map_or((rest, None), |(t, q)| (t, Some(q)));
        let target = match kind {
            "lerobot" if !target.is_empty() => PythonTarget::Lerobot(target.into()),
            "python" => match target.rsplit_once(':') {
                Some((module, factory)) if !module.is_empty() && !factory.is_empty() => {
                    PythonTarget::Module { module: module.into(), factory: factory.into() }
                }
                _ => return Err(format!("python:{rest}: expected python:<module>:<factory>[?key=value&...]")),
            },
            _ => return Err(format!("{kind}:{rest}: expected lerobot:<checkpoint dir>[?options]")),
        };
        let mut host = std::collections::BTreeMap::new();
        let mut policy_options: Vec<(String, String)> = Vec::new();
        let known = || {
            let mut k: Vec<&str> = Self::HOST_OPTIONS[..6].to_vec();
            if kind == "lerobot" {
                k.extend(Self::LEROBOT_OPTIONS);
            }
            k.join(", ")
        };
        for option in query.into_iter().flat_map(|q| q.split('&')) {
            let Some((name, value)) = option.split_once('=') else {
                return Err(format!("{kind}:{rest}: option {option:?} is not key=value; the options are {}", known()));
            };
            let twice = || format!("{kind}:{rest}: {name} is given twice");
            if name == "benchmark" {
                return Err(format!("{kind}:{rest}: the benchmark comes from the specs, not from an option"));
            } else if Self::HOST_OPTIONS.contains(&name) {
                if host.insert(name, value).is_some() {
                    return Err(twice());
                }
            } else if kind == "python" || Self::LEROBOT_OPTIONS.contains(&name) {
                if policy_options.iter().any(|(k, _)| k == name) {
                    return Err(twice());
                }
                policy_options.push((name.into(), value.into()));
            } else {
                return Err(format!("{kind}:{rest}: unknown option {option:?}; the options are {}", known()));
            }
        }
        if let Some((_, steps)) = policy_options.iter().find(|(k, _)| k == "steps")
            && kind == "lerobot"
            && !matches!(steps.parse::<usize>(), Ok(n) if n >= 1)
        {
            return Err(format!("{kind}:{rest}: expected steps=N with N >= 1 (actions executed of each chunk)"));
        }
        let seconds = |name: &str| -> Result<Option<u64>, String> {
            host.get(name)
                .map(|v: &&str| match v.parse::<u64>() {
                    Ok(s) if s >= 1 => Ok(s),
                    _ => Err(format!("{kind}:{rest}: expected {name}=S with S >= 1 (seconds)")),
                })
                .transpose()
        };
        let devices = match host.get("devices") {
            None => Vec::new(),
            Some(d) => {
                parse_devices(d).map_err(|e| format!("{kind}:{rest}: expected {} ({e})", option_help("devices")))?
            }
        };
        Ok(PythonOptions {
            target,
            interpreter: host.get("python").filter(|p| !p.is_empty()).map(std::path::PathBuf::from),
            batch: batching(kind, rest, &host)?,
            devices,
            call_timeout_s: seconds("timeout_s")?,
            load_timeout_s: seconds("load_timeout_s")?,
            policy_options,
            ensemble: None,
        })
    }
}

/// The options of `starvla:...` (see [`StarVlaConfig`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StarVlaOptions {
    pub url: String,
    pub unnorm_key: Option<String>,
    pub stats: Option<std::path::PathBuf>,
    pub chunk: Option<usize>,
    pub state: Option<bool>,
    pub ensemble: Option<Ensemble>,
}

impl StarVlaOptions {
    fn config(&self) -> StarVlaConfig {
        StarVlaConfig {
            unnorm_key: self.unnorm_key.clone(),
            stats: self.stats.clone(),
            chunk: self.chunk,
            state: self.state,
            ..StarVlaConfig::new(self.url.clone())
        }
    }
}

/// The options of an in-process checkpoint policy (`openvla:`, `oft:`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CheckpointOptions {
    pub dir: std::path::PathBuf,
    pub unnorm_key: Option<String>,
    pub batch: Option<Batching>,
    /// Weight-only quantisation of the linear layers (`quant=int8|int4`).
    pub quant: Quantization,
    /// One model replica per device, each with its own batcher (`devices=cuda:0,cuda:1`, with
    /// `batch`; one device needs no `batch`); empty: one model on the default device (the first
    /// GPU, else the CPU, which `models::cpu_fallback` refuses on a GPU machine and for a large
    /// model: `devices=cpu` runs it there on purpose).
    pub devices: Vec<ModelDevice>,
    /// The language model's attention (`attention=eager|sdpa`); `None`: the model's default on
    /// its device ([`Attention::model_default`]).
    pub attention: Option<Attention>,
    /// `ensemble=` (`oft:` only: OpenVLA predicts one action at a time).
    pub ensemble: Option<Ensemble>,
}

impl CheckpointOptions {
    fn options(&self) -> Vec<String> {
        let mut options: Vec<String> = self.unnorm_key.iter().map(|k| format!("unnorm={k}")).collect();
        options.extend(self.batch.iter().flat_map(Batching::options));
        if !self.devices.is_empty() {
            options.push(format!("devices={}", devices_text(&self.devices)));
        }
        if self.quant != Quantization::None {
            options.push(format!("quant={}", self.quant));
        }
        if let Some(a) = self.attention {
            options.push(format!("attention={a}"));
        }
        options
    }

    /// The CUDA devices its replicas run on (the default device is cuda:0 where libtorch sees a
    /// GPU).
    #[cfg(feature = "torch")]
    fn cuda_devices(&self) -> Vec<usize> {
        let default_is_cuda = || tch::Cuda::is_available();
        self.replica_devices()
            .into_iter()
            .filter_map(|d| match d {
                Some(ModelDevice::Cuda(i)) => Some(i),
                Some(ModelDevice::Cpu) => None,
                None => default_is_cuda().then_some(0),
            })
            .collect()
    }

    /// The replicas' devices: the listed ones, or the default device once.
    #[cfg(feature = "torch")]
    fn replica_devices(&self) -> Vec<Option<ModelDevice>> {
        match self.devices.is_empty() {
            true => vec![None],
            false => self.devices.iter().copied().map(Some).collect(),
        }
    }
}

/// How a model policy's forwards are shared between the rollout workers (`batch=N[&wait_ms=W]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Batching {
    /// Most episodes in one forward.
    pub max_episodes: usize,
    /// The longest a forward waits, once a query has arrived, for the other episodes in progress
    /// to send theirs (it goes as soon as all have). Short by default: on the H100 a 200 ms wait
    /// filled the forwards (15 episodes each instead of 10) but put all 32 workers' renders at
    /// the same moment, and renders from 32 GL contexts at once took 505 ms instead of 305: 24.1
    /// policy steps/s against 27.1 (`data/benchmarks/gpu-end-to-end-h100-2026-11-24`). A loaded
    /// CPU box may need more for the forwards to fill, which `run`'s batch summary shows.
    pub wait_ms: u64,
}

impl Batching {
    pub const DEFAULT_WAIT_MS: u64 = 20;

    fn options(&self) -> Vec<String> {
        let mut o = vec![format!("batch={}", self.max_episodes)];
        if self.wait_ms != Self::DEFAULT_WAIT_MS {
            o.push(format!("wait_ms={}", self.wait_ms));
        }
        o
    }
}

impl PolicySpec {
    /// The policy that process `k` of `n` runs (`pipeline run --processes n`): the listed
    /// `devices=` dealt out in turn (process k takes devices k, k + n, ...), so that each process
    /// holds its own GPUs' replicas; a policy without a device list is the same in every process
    /// (each then loads its own model, on the default device). An error when the list is shorter
    /// than `n`, which would leave a process without a device.
    pub fn device_share(&self, k: usize, n: usize) -> Result<PolicySpec, String> {
        if n == 1 {
            return Ok(self.clone());
        }
        let share = |devices: &[ModelDevice]| -> Result<Vec<ModelDevice>, String> {
            if devices.is_empty() {
                // each process would load its own model on the default device, leaving the
                // machine's other GPUs idle: the devices are the user's to say
                let listed = (0..n).map(|i| format!("cuda:{i}")).collect::<Vec<_>>().join(",");
                return Err(format!(
                    "--processes {n} deals the policy's devices out, but {} lists none: add devices={listed} (or one device {n} times, for {n} replicas on it)",
                    self.name()
                ));
            }
            if devices.len() < n {
                return Err(format!(
                    "--processes {n} deals the policy's devices out, one process at least one each, but devices={} lists {}: list {n} or more devices, or ask for {} processes",
                    devices_text(devices),
                    devices.len(),
                    devices.len()
                ));
            }
            Ok(devices.iter().copied().skip(k).step_by(n).collect())
        };
        let mut policy = self.clone();
        match &mut policy {
            #[cfg(feature = "torch")]
            PolicySpec::OpenVla(o) | PolicySpec::Oft(o) => o.devices = share(&o.devices)?,
            PolicySpec::Python(o) => o.devices = share(&o.devices)?,
            PolicySpec::TorchScript { .. } => {
                return Err(format!(
                    "--processes {n}: torchscript: runs on one device, so every process would load its own copy there; run it in one process"
                ));
            }
            _ => {}
        }
        Ok(policy)
    }

    /// How many devices the policy string lists (`devices=`; 0 for none and for policies without
    /// a device list).
    pub fn model_devices_listed(&self) -> usize {
        match self {
            #[cfg(feature = "torch")]
            PolicySpec::OpenVla(o) | PolicySpec::Oft(o) => o.devices.len(),
            PolicySpec::Python(o) => o.devices.len(),
            _ => 0,
        }
    }

    /// The CUDA devices an in-process model of this policy runs on (none for the others): a run
    /// keeps its cameras' GL contexts off them where the machine has other GPUs
    /// (`libero_sim::gl::keep_renders_off`).
    pub fn model_cuda_devices(&self) -> Vec<usize> {
        match self {
            #[cfg(feature = "torch")]
            PolicySpec::OpenVla(o) | PolicySpec::Oft(o) => o.cuda_devices(),
            PolicySpec::Python(o) => o
                .devices
                .iter()
                .filter_map(|d| match d {
                    ModelDevice::Cuda(i) => Some(*i),
                    ModelDevice::Cpu => None,
                })
                .collect(),
            _ => Vec::new(),
        }
    }

    /// A fresh instance for one rollout worker.
    pub fn instantiate(&self) -> Result<Box<dyn Policy>, PolicyError> {
        let mut policy = self.instantiate_kind()?;
        if let Some(e) = self.ensemble() {
            policy.set_ensemble(e).map_err(|detail| PolicyError { policy: self.to_string(), detail })?;
        }
        Ok(policy)
    }

    fn instantiate_kind(&self) -> Result<Box<dyn Policy>, PolicyError> {
        Ok(match self {
            PolicySpec::Random => Box::new(RandomPolicy::new()),
            PolicySpec::Lift => Box::new(LiftPolicy),
            PolicySpec::Expert => Box::new(Expert::new()),
            PolicySpec::NanAt(n) => Box::new(NanAtPolicy { at: *n }),
            PolicySpec::ExpertDrop => Box::new(ExpertDrop::new()),
            PolicySpec::TorchScript { file, batch, device, .. } => {
                load_torchscript(file, *batch, *device, &self.to_string())?
            }
            PolicySpec::OpenVla(o) => load_openvla(o, &self.to_string())?,
            PolicySpec::Oft(o) => load_oft(o, &self.to_string())?,
            PolicySpec::Openpi { url, replan_steps, .. } => Box::new(OpenpiPolicy::connect(OpenpiConfig {
                replan_steps: Self::openpi_replan_steps(*replan_steps, Benchmark::Libero),
                ..OpenpiConfig::new(url.clone())
            })?),
            PolicySpec::VlaEval { url } => Box::new(VlaEvalPolicy::connect(VlaEvalConfig::new(url.clone()))?),
            PolicySpec::StarVla(o) => Box::new(StarVlaPolicy::connect(o.config())?),
            PolicySpec::Python(o) => {
                let config = o.host_config(Benchmark::Libero);
                let kind = o.target.kind();
                batched(&self.to_string(), o.batching(), &o.replica_devices(), kind, |d| {
                    crate::python_host::PythonHostModel::start(&config, d)
                        .map_err(|detail| PolicyError { policy: kind.into(), detail })
                })?
            }
        })
    }

    /// A fresh instance for one rollout worker of an ALOHA-sim run; kinds without an ALOHA form
    /// are refused by [`check_benchmark`](Self::check_benchmark) before any episode.
    pub fn instantiate_aloha(&self) -> Result<Box<dyn crate::aloha::AlohaPolicy>, PolicyError> {
        let mut policy = self.instantiate_aloha_kind()?;
        if let Some(e) = self.ensemble() {
            policy.set_ensemble(e).map_err(|detail| PolicyError { policy: self.to_string(), detail })?;
        }
        Ok(policy)
    }

    fn instantiate_aloha_kind(&self) -> Result<Box<dyn crate::aloha::AlohaPolicy>, PolicyError> {
        use crate::aloha::{NanAtAloha, RandomWalkAloha, ScriptedAloha};
        Ok(match self {
            PolicySpec::Random => Box::new(RandomWalkAloha::new()),
            PolicySpec::Expert => Box::new(ScriptedAloha),
            PolicySpec::NanAt(n) => Box::new(NanAtAloha::new(*n)),
            PolicySpec::Openpi { url, replan_steps, .. } => Box::new(OpenpiAlohaPolicy::connect(OpenpiConfig {
                replan_steps: Self::openpi_replan_steps(*replan_steps, Benchmark::AlohaSim),
                ..OpenpiConfig::new(url.clone())
            })?),
            #[cfg(feature = "torch")]
            PolicySpec::TorchScript { file, batch: None, device, .. } => {
                Box::new(crate::models::torchscript_aloha::TorchScriptAloha::load_on(file, *device)?)
            }
            PolicySpec::Python(o) => {
                use crate::batching::{BatchedAlohaPolicy, shared_replicas};
                let config = o.host_config(Benchmark::AlohaSim);
                let (kind, devices, batching) = (o.target.kind(), o.replica_devices(), o.batching());
                let wait = std::time::Duration::from_millis(batching.wait_ms);
                let replicas = shared_replicas(&self.to_string(), devices.len(), |i| {
                    crate::python_host::PythonAlohaHost::start(&config, devices[i])
                        .map(|host| (host, batching.max_episodes, wait))
                        .map_err(|detail| PolicyError { policy: kind.into(), detail })
                })?;
                Box::new(BatchedAlohaPolicy::on_replicas(replicas, kind))
            }
            _ => {
                return Err(PolicyError {
                    policy: self.to_string(),
                    detail: self
                        .check_benchmark(Benchmark::AlohaSim)
                        .err()
                        .unwrap_or_else(|| "this build has no ALOHA-sim form of it (built without torch)".into()),
                });
            }
        })
    }

    /// The actions executed of each openpi chunk: the `?replan=N` given, else what the
    /// benchmark's openpi example executes (`examples/libero`: 5; `examples/aloha_sim`'s
    /// `ActionChunkBroker`: 10).
    pub fn openpi_replan_steps(given: Option<usize>, benchmark: Benchmark) -> usize {
        given.unwrap_or(match benchmark {
            Benchmark::Libero => LIBERO_REPLAN_STEPS,
            Benchmark::AlohaSim => ALOHA_REPLAN_STEPS,
        })
    }

    /// Whether this policy can act on `benchmark`: a LIBERO policy sends 7-D end-effector deltas,
    /// an ALOHA-sim env takes 14-D joint targets. Checked before a run starts; a TorchScript
    /// module's `model.json` says which benchmark it is for.
    pub fn check_benchmark(&self, benchmark: Benchmark) -> Result<(), String> {
        let module_for = |file: &std::path::Path| torchscript_benchmark(file);
        match benchmark {
            Benchmark::Libero => match self {
                PolicySpec::TorchScript { file, .. } if module_for(file) == Ok(Benchmark::AlohaSim) => Err(format!(
                    "{}'s model.json says \"benchmark\": \"aloha_sim\": it returns 14-D joint actions, and these specs are LIBERO's (7-D end-effector actions); run it on an ALOHA-sim spec (pipeline specs --benchmark aloha_sim)",
                    file.display()
                )),
                _ => Ok(()),
            },
            Benchmark::AlohaSim => match self {
                PolicySpec::Random | PolicySpec::Expert | PolicySpec::NanAt(_) | PolicySpec::Openpi { .. } => Ok(()),
                PolicySpec::TorchScript { file, batch, .. } => match (module_for(file)?, batch) {
                    (Benchmark::AlohaSim, None) => Ok(()),
                    (Benchmark::AlohaSim, Some(_)) => Err(format!(
                        "{self}: ?batch= shares forwards between LIBERO episodes only; on ALOHA-sim run torchscript:{} (one forward per episode query)",
                        file.display()
                    )),
                    (Benchmark::Libero, _) => Err(format!(
                        "{}'s model.json does not say \"benchmark\": \"aloha_sim\", so it is a LIBERO module (7-D end-effector actions), and ALOHA-sim takes 14-D joint actions; export the ALOHA policy with a manifest of inputs [\"top\", \"state\"] and \"benchmark\": \"aloha_sim\" (see policies::models::torchscript_aloha)",
                        file.display()
                    )),
                },
                // the host checks the checkpoint's features against ALOHA-sim's when it loads
                PolicySpec::Python(_) => Ok(()),
                _ => Err(format!(
                    "the policy {self} acts in LIBERO's 7-D end-effector space, and ALOHA-sim (suite aloha_sim) takes {}-D joint actions (per arm 6 joint targets and a gripper); on ALOHA-sim run expert (the scripted control), random, nan-at:N, openpi:ws://..., lerobot:<checkpoint dir>, python:<module>:<factory> or a torchscript module made for aloha_sim",
                    Benchmark::AlohaSim.action_dim()
                )),
            },
        }
    }

    /// Short name stored in every episode row.
    pub fn name(&self) -> String {
        self.to_string()
    }

    /// Whether the policy is given camera images (a learned VLA); the baselines, diagnostics and
    /// the privileged expert see none, so a perturbation of the images means nothing to them.
    pub fn sees_cameras(&self) -> bool {
        matches!(
            self,
            PolicySpec::TorchScript { .. }
                | PolicySpec::OpenVla { .. }
                | PolicySpec::Oft { .. }
                | PolicySpec::Openpi { .. }
                | PolicySpec::VlaEval { .. }
                | PolicySpec::StarVla(_)
                | PolicySpec::Python(_)
        )
    }

    /// Baselines are expected to fail; results warn when one scores above 5%.
    /// Whether the policy's server keeps the action chunks, so the pipeline cannot tell a model
    /// query from a queued action (`vla-eval:`): a fixed real-time latency would be charged to
    /// every step.
    pub fn chunks_kept_remotely(&self) -> bool {
        matches!(self, PolicySpec::VlaEval { .. })
    }

    pub fn is_baseline(&self) -> bool {
        matches!(self, PolicySpec::Random | PolicySpec::Lift)
    }

    /// The identity for the run manifest, asking the policy itself where only it knows (a remote
    /// server's metadata): a server that cannot be reached fails the run before any episode.
    pub fn resolve_identity(&self, benchmark: Benchmark) -> Result<serde_json::Value, PolicyError> {
        let mut identity = self.resolve_kind_identity(benchmark)?;
        self.add_ensemble(&mut identity);
        Ok(identity)
    }

    /// Records the ensembling rule (a resume under another rule is then refused, as for any other
    /// identity change).
    fn add_ensemble(&self, identity: &mut serde_json::Value) {
        if let (Some(e), Some(object)) = (self.ensemble(), identity.as_object_mut()) {
            object.insert("ensemble".into(), serde_json::json!({"rule": e.to_string(), "reference": e.reference()}));
        }
    }

    fn resolve_kind_identity(&self, benchmark: Benchmark) -> Result<serde_json::Value, PolicyError> {
        match (self, benchmark) {
            (PolicySpec::Openpi { url, replan_steps, .. }, Benchmark::AlohaSim) => {
                Ok(OpenpiAlohaPolicy::connect(OpenpiConfig {
                    replan_steps: Self::openpi_replan_steps(*replan_steps, benchmark),
                    ..OpenpiConfig::new(url.clone())
                })?
                .identity())
            }
            #[cfg(feature = "torch")]
            (PolicySpec::TorchScript { file, device, .. }, Benchmark::AlohaSim) => {
                Ok(crate::models::torchscript_aloha::TorchScriptAloha::load_on(file, *device)?.identity())
            }
            (PolicySpec::Python(o), _) => self.resolve_python_identity(o, benchmark),
            (_, Benchmark::AlohaSim) => Ok(self.aloha_identity()),
            (_, Benchmark::Libero) => self.resolve_libero_identity(),
        }
    }

    /// The identity of the ALOHA-sim forms of the policies without a model or server (what
    /// [`instantiate_aloha`](Self::instantiate_aloha) makes of them).
    fn aloha_identity(&self) -> serde_json::Value {
        match self {
            PolicySpec::Expert => serde_json::json!({
                "kind": "scripted expert", "name": "expert", "privileged": true, "benchmark": "aloha_sim",
                "plan": "ACT's scripted policies (scripted_policy.py waypoint tables) recorded per episode in gym-aloha's end-effector scene with the mocap weld's solimp[0..2] = 0.9, replayed as 14-D joint targets in the unmodified joint-space env",
                "chunking": 1,
            }),
            PolicySpec::Random => serde_json::json!({
                "kind": "baseline", "name": "random", "benchmark": "aloha_sim",
                "distribution": "per joint a random walk from the first observed agent_pos (steps uniform in ±0.1 rad, within ±1.2 rad), grippers uniform [0, 1]",
                "rng": "ChaCha8 seeded per episode from the episode key", "chunking": 1,
            }),
            PolicySpec::NanAt(n) => serde_json::json!({
                "kind": "diagnostic", "name": "nan-at", "step": n, "benchmark": "aloha_sim",
                "action": "holds the first observed agent_pos, NaN at the step",
            }),
            other => other.kind_identity(),
        }
    }

    /// A Python policy's identity, from the host that will serve the run's first episodes (started
    /// now, for the benchmark's observations: a checkpoint that does not fit stops the run here).
    fn resolve_python_identity(
        &self,
        o: &PythonOptions,
        benchmark: Benchmark,
    ) -> Result<serde_json::Value, PolicyError> {
        let config = o.host_config(benchmark);
        let mut identity = crate::python_host::resolve_identity(&config, o.replica_devices()[0])
            .map_err(|detail| PolicyError { policy: self.to_string(), detail })?;
        identity["spec"] = serde_json::json!(self.to_string());
        identity["batch"] =
            serde_json::json!({"max_episodes_per_forward": o.batching().max_episodes, "wait_ms": o.batching().wait_ms});
        identity["replicas"] = serde_json::json!({
            "devices": o.replica_devices().iter().map(|d| d.map_or("default".to_string(), |d| d.to_string())).collect::<Vec<_>>(),
            "assignment": "one host process per device; each episode on the replica with the least (episodes in progress + 1) x recent call ms when it starts",
        });
        Ok(identity)
    }

    fn resolve_libero_identity(&self) -> Result<serde_json::Value, PolicyError> {
        match self {
            PolicySpec::Openpi { url, replan_steps, .. } => Ok(OpenpiPolicy::connect(OpenpiConfig {
                replan_steps: Self::openpi_replan_steps(*replan_steps, Benchmark::Libero),
                ..OpenpiConfig::new(url.clone())
            })?
            .identity()),
            PolicySpec::VlaEval { url } => Ok(VlaEvalPolicy::connect(VlaEvalConfig::new(url.clone()))?.identity()),
            PolicySpec::StarVla(o) => Ok(StarVlaPolicy::connect(o.config())?.identity()),
            #[cfg(feature = "torch")]
            PolicySpec::TorchScript { file, batch, device, .. } => {
                Ok(crate::models::torchscript::TorchScriptModel::load_on(file, *device)?
                    .identity(batch.map(|b| b.max_episodes)))
            }
            #[cfg(feature = "torch")]
            PolicySpec::OpenVla(o) => {
                let mut identity = crate::models::openvla::OpenVlaPolicy::identity_of(
                    &o.dir,
                    o.unnorm_key.as_deref(),
                    o.batch.map(|b| b.max_episodes),
                )?;
                placement_identity(&mut identity, o, "openvla")?;
                Ok(identity)
            }
            #[cfg(feature = "torch")]
            PolicySpec::Oft(o) => {
                let mut identity = crate::models::openvla::oft::OftPolicy::identity_of(
                    &o.dir,
                    o.unnorm_key.as_deref(),
                    o.batch.map(|b| b.max_episodes),
                )?;
                placement_identity(&mut identity, o, "oft")?;
                Ok(identity)
            }
            _ => Ok(self.kind_identity()),
        }
    }

    /// Identity for the manifest: what a reader needs to know which policy produced the steps
    /// (checkpoint hash, unnorm key, chunking and image preprocessing for model policies).
    pub fn identity(&self) -> serde_json::Value {
        let mut identity = self.kind_identity();
        self.add_ensemble(&mut identity);
        identity
    }

    fn kind_identity(&self) -> serde_json::Value {
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
            PolicySpec::OpenVla(o) | PolicySpec::Oft(o) => serde_json::json!({
                "kind": if matches!(self, PolicySpec::Oft(_)) { "openvla-oft" } else { "openvla" },
                "checkpoint": o.dir.display().to_string(), "unnorm_key": o.unnorm_key,
                "batch": o.batch.map(|b| b.max_episodes),
                "quantization": o.quant.to_string(), "devices": devices_text(&o.devices),
                "checkpoint_sha256": "read at run start (resolve_identity)",
            }),
            PolicySpec::TorchScript { file, .. } => serde_json::json!({
                "kind": "torchscript", "file": file.display().to_string(),
                "sha256": "read at run start (resolve_identity)",
            }),
            PolicySpec::Openpi { url, replan_steps, .. } => serde_json::json!({
                "kind": "remote", "name": "openpi", "url": url, "replan_steps": replan_steps,
                "server_metadata": "read at run start (resolve_identity)",
            }),
            PolicySpec::VlaEval { url } => serde_json::json!({
                "kind": "remote", "name": "vla-eval", "url": url,
                "server_hello": "read at run start (resolve_identity)",
            }),
            PolicySpec::StarVla(o) => serde_json::json!({
                "kind": "remote", "name": "starvla", "url": o.url, "unnorm_key": o.unnorm_key,
                "stats": o.stats.as_ref().map(|p| p.display().to_string()), "chunk": o.chunk, "state": o.state,
                "server_metadata": "read at run start (resolve_identity)",
            }),
            PolicySpec::Python(o) => serde_json::json!({
                "kind": o.target.kind(), "spec": self.to_string(),
                "describe": "read from the host at run start (resolve_identity)",
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
        let base = KindText(self).to_string();
        match self.ensemble() {
            None => f.write_str(&base),
            Some(e) => write!(f, "{base}{}ensemble={e}", if base.contains('?') { '&' } else { '?' }),
        }
    }
}

/// A policy's text without `ensemble=` (its kind and the kind's own options).
struct KindText<'a>(&'a PolicySpec);

impl fmt::Display for KindText<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let spec = self.0;
        match spec {
            PolicySpec::Random => f.write_str("random"),
            PolicySpec::Lift => f.write_str("lift"),
            PolicySpec::Expert => f.write_str("expert"),
            PolicySpec::NanAt(n) => write!(f, "nan-at:{n}"),
            PolicySpec::ExpertDrop => f.write_str("expert-drop"),
            PolicySpec::OpenVla(o) | PolicySpec::Oft(o) => {
                let kind = if matches!(spec, PolicySpec::Oft(_)) { "oft" } else { "openvla" };
                let options = o.options();
                match options.is_empty() {
                    true => write!(f, "{kind}:{}", o.dir.display()),
                    false => write!(f, "{kind}:{}?{}", o.dir.display(), options.join("&")),
                }
            }
            PolicySpec::TorchScript { file, batch, device, .. } => {
                let mut options: Vec<String> = batch.iter().flat_map(Batching::options).collect();
                options.extend(device.iter().map(|d| format!("devices={d}")));
                match options.is_empty() {
                    true => write!(f, "torchscript:{}", file.display()),
                    false => write!(f, "torchscript:{}?{}", file.display(), options.join("&")),
                }
            }
            PolicySpec::Openpi { url, replan_steps: None, .. } => write!(f, "openpi:{url}"),
            PolicySpec::Openpi { url, replan_steps: Some(n), .. } => write!(f, "openpi:{url}?replan={n}"),
            PolicySpec::VlaEval { url } => write!(f, "vla-eval:{url}"),
            PolicySpec::StarVla(o) => {
                let mut options: Vec<String> = o.unnorm_key.iter().map(|k| format!("unnorm={k}")).collect();
                options.extend(o.stats.iter().map(|p| format!("stats={}", p.display())));
                options.extend(o.chunk.iter().map(|n| format!("chunk={n}")));
                options.extend(o.state.iter().map(|s| format!("state={}", u8::from(*s))));
                match options.is_empty() {
                    true => write!(f, "starvla:{}", o.url),
                    false => write!(f, "starvla:{}?{}", o.url, options.join("&")),
                }
            }
            PolicySpec::Python(o) => {
                use crate::python_host::PythonTarget;
                match &o.target {
                    PythonTarget::Lerobot(dir) => write!(f, "lerobot:{}", dir.display())?,
                    PythonTarget::Module { module, factory } => write!(f, "python:{module}:{factory}")?,
                }
                let options = o.options();
                match options.is_empty() {
                    true => Ok(()),
                    false => write!(f, "?{}", options.join("&")),
                }
            }
        }
    }
}

impl FromStr for PolicySpec {
    type Err = String;
    /// `ensemble=` is a driver option any chunked policy takes, so it is read here, before the
    /// kind's own options.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (rest, ensemble) = take_ensemble(s)?;
        let spec = Self::parse_kind(&rest)?;
        match ensemble {
            None => Ok(spec),
            Some(e) => spec.with_ensemble(e).map_err(|why| format!("{s}: {why}")),
        }
    }
}

/// `s` without its `ensemble=` option, and the rule it names.
fn take_ensemble(s: &str) -> Result<(String, Option<Ensemble>), String> {
    let Some((target, query)) = s.split_once('?') else { return Ok((s.to_string(), None)) };
    let (mut ensemble, mut others) = (None, Vec::new());
    for option in query.split('&') {
        match option.strip_prefix("ensemble=") {
            Some(_) if ensemble.is_some() => return Err(format!("{s}: ensemble is given twice")),
            Some(rule) => ensemble = Some(rule.parse::<Ensemble>()?),
            None => others.push(option),
        }
    }
    Ok(match others.is_empty() {
        true => (target.to_string(), ensemble),
        false => (format!("{target}?{}", others.join("&")), ensemble),
    })
}

impl PolicySpec {
    /// The chunk-ensembling rule of a chunked policy (`ensemble=`), if any.
    pub fn ensemble(&self) -> Option<Ensemble> {
        match self {
            PolicySpec::TorchScript { ensemble, .. } | PolicySpec::Openpi { ensemble, .. } => *ensemble,
            PolicySpec::Oft(o) => o.ensemble,
            PolicySpec::StarVla(o) => o.ensemble,
            PolicySpec::Python(o) => o.ensemble,
            _ => None,
        }
    }

    /// This policy with its chunks combined by `e`; refused where there is nothing to combine, or
    /// where another option already says when the model is asked.
    fn with_ensemble(mut self, e: Ensemble) -> Result<Self, String> {
        let asked_by = |option: &str| {
            format!(
                "{option} and ensemble={e} both say when the model is asked; ensemble=newest|average|ema:..:N asks every N actions, temporal and adaptive every step"
            )
        };
        match &mut self {
            PolicySpec::TorchScript { ensemble, .. } | PolicySpec::Oft(CheckpointOptions { ensemble, .. }) => {
                *ensemble = Some(e)
            }
            PolicySpec::Openpi { replan_steps: Some(_), .. } => return Err(asked_by("replan=N")),
            PolicySpec::Openpi { ensemble, .. } => *ensemble = Some(e),
            PolicySpec::StarVla(StarVlaOptions { chunk: Some(_), .. }) => return Err(asked_by("chunk=N")),
            PolicySpec::StarVla(o) => o.ensemble = Some(e),
            PolicySpec::Python(o) if o.policy_options.iter().any(|(k, _)| k == "steps") => {
                return Err(asked_by("steps=N"));
            }
            PolicySpec::Python(o) => o.ensemble = Some(e),
            PolicySpec::OpenVla(_) => {
                return Err("OpenVLA predicts one action per query, so there are no chunks to ensemble".into());
            }
            PolicySpec::VlaEval { .. } => {
                return Err("vla-eval's server keeps the action chunks and sends one action at a time; set its own action_ensemble where the server is started".into());
            }
            _ => return Err("this policy predicts no action chunks, so there is nothing to ensemble".into()),
        }
        Ok(self)
    }

    fn parse_kind(s: &str) -> Result<Self, String> {
        match s {
            "random" => Ok(PolicySpec::Random),
            "lift" => Ok(PolicySpec::Lift),
            "expert" => Ok(PolicySpec::Expert),
            "expert-drop" => Ok(PolicySpec::ExpertDrop),
            _ if s.starts_with("openpi:") => parse_openpi(&s["openpi:".len()..]),
            _ if s.starts_with("vla-eval:") => parse_vla_eval(&s["vla-eval:".len()..]),
            _ if s.starts_with("starvla:") => parse_starvla(&s["starvla:".len()..]),
            _ if s.starts_with("lerobot:") => {
                Ok(PolicySpec::Python(PythonOptions::parse("lerobot", &s["lerobot:".len()..])?))
            }
            _ if s.starts_with("python:") => {
                Ok(PolicySpec::Python(PythonOptions::parse("python", &s["python:".len()..])?))
            }
            _ if s.starts_with("openvla:") && s.len() > "openvla:".len() => parse_openvla(&s["openvla:".len()..]),
            _ if s.starts_with("oft:") && s.len() > "oft:".len() => parse_oft(&s["oft:".len()..]),
            _ if s.starts_with("torchscript:") && s.len() > "torchscript:".len() => {
                parse_torchscript(&s["torchscript:".len()..])
            }
            _ => match s.strip_prefix("nan-at:").map(str::parse) {
                Some(Ok(n)) => Ok(PolicySpec::NanAt(n)),
                _ => Err(format!(
                    "unknown policy {s:?}; known: random, lift, expert, openpi:ws://host:port[?replan=N], vla-eval:ws://host:port, starvla:ws://host:port[?unnorm=<key>][&stats=<dataset_statistics.json>][&chunk=N][&state=0|1], torchscript:<model.pt>[?batch=N][&devices=cpu|cuda:N], openvla:<checkpoint dir>[?unnorm=<key>][&batch=N][&devices=cpu|cuda:0,cuda:1][&quant=int8|int4], oft:<checkpoint dir>[?unnorm=<key>][&batch=N][&devices=...][&quant=int8|int4], lerobot:<checkpoint dir>[?python=<interpreter>][&batch=N][&devices=...][&steps=N], python:<module>:<factory>[?python=<interpreter>][&key=value...]; diagnostics: nan-at:<policy step>, expert-drop; chunked policies (torchscript, oft, openpi, starvla, lerobot, python) also take {ENSEMBLE_HELP}"
                )),
            },
        }
    }
}

/// A worker's policy on the process-wide replicas of `spec` (its text, options included: one set
/// of model replicas, each with its batcher, per distinct spec), loading them with the first
/// worker: one replica per device, loaded in parallel.
fn batched<M: crate::batching::BatchModel>(
    spec: &str,
    batching: Batching,
    devices: &[Option<ModelDevice>],
    policy: &str,
    load: impl Fn(Option<ModelDevice>) -> Result<M, PolicyError> + Sync,
) -> Result<Box<dyn Policy>, PolicyError> {
    use crate::batching::{BatchedPolicy, shared_replicas};
    let wait = std::time::Duration::from_millis(batching.wait_ms);
    let replicas = shared_replicas(spec, devices.len(), |i| Ok((load(devices[i])?, batching.max_episodes, wait)))?;
    Ok(Box::new(BatchedPolicy::on_replicas(replicas, policy)))
}

/// Adds where the model runs and how its weights are stored to a checkpoint policy's identity,
/// after checking that each device exists here (a missing GPU stops the run before any episode).
#[cfg(feature = "torch")]
fn placement_identity(
    identity: &mut serde_json::Value,
    o: &CheckpointOptions,
    policy: &'static str,
) -> Result<(), PolicyError> {
    let (mut devices, mut on_gpu) = (Vec::new(), Vec::new());
    let size = crate::models::cpu_fallback::ModelSize::of_checkpoint(policy, &o.dir);
    for d in o.replica_devices() {
        let (device, kind) = crate::models::device_and_dtype(d, &size)
            .map_err(|detail| PolicyError { policy: policy.into(), detail })?;
        devices.push(format!("{device:?}"));
        on_gpu.push(device.is_cuda());
        identity["dtype"] = serde_json::json!(format!("{kind:?}"));
    }
    identity["replicas"] = serde_json::json!({
        "devices": devices,
        "assignment": "each episode on the replica with the least (episodes in progress + 1) x recent forward ms when it starts",
    });
    identity["quantization"] = serde_json::json!(o.quant.describe());
    let oft = matches!(policy, "oft");
    let attention_on = |gpu: bool| o.attention.unwrap_or(crate::placement::Attention::model_default(oft, gpu));
    let attention: Vec<&str> = on_gpu.iter().map(|&gpu| attention_on(gpu).describe()).collect();
    if on_gpu.iter().any(|&gpu| gpu && attention_on(gpu) == crate::placement::Attention::Sdpa) {
        // which kernels compute SDPA on a GPU (`placement::keep_cudnn_attention_last`)
        identity["sdpa_cudnn_environment"] =
            crate::placement::cudnn_attention_environment(|name| std::env::var_os(name));
    }
    identity["attention"] = serde_json::json!(if attention.windows(2).all(|w| w[0] == w[1]) {
        serde_json::json!(attention[0])
    } else {
        serde_json::json!(attention)
    });
    Ok(())
}

#[cfg(feature = "torch")]
fn load_torchscript(
    file: &std::path::Path,
    batch: Option<Batching>,
    device: Option<ModelDevice>,
    spec: &str,
) -> Result<Box<dyn Policy>, PolicyError> {
    use crate::models::torchscript::{TorchScriptModel, TorchScriptPolicy};
    match batch {
        None => Ok(Box::new(TorchScriptPolicy::load_on(file, device)?)),
        Some(n) => batched(spec, n, &[device], "torchscript", |d| TorchScriptModel::load_on(file, d)),
    }
}

#[cfg(feature = "torch")]
fn load_openvla(o: &CheckpointOptions, spec: &str) -> Result<Box<dyn Policy>, PolicyError> {
    use crate::models::openvla::{OpenVlaBatchModel, OpenVlaPolicy};
    let (dir, key, quant) = (&o.dir, &o.unnorm_key, o.quant);
    match o.batch {
        None => {
            let mut policy = OpenVlaPolicy::load(dir, key.clone(), o.devices.first().copied(), quant)?;
            if let Some(a) = o.attention {
                policy.set_attention(a);
            }
            Ok(Box::new(policy))
        }
        Some(n) => batched(spec, n, &o.replica_devices(), "openvla", |device| {
            let mut model = OpenVlaBatchModel::load(dir, key.clone(), device, quant)?;
            if let Some(a) = o.attention {
                model.set_attention(a);
            }
            Ok(model)
        }),
    }
}

#[cfg(feature = "torch")]
fn load_oft(o: &CheckpointOptions, spec: &str) -> Result<Box<dyn Policy>, PolicyError> {
    use crate::models::openvla::oft::{OftBatchModel, OftPolicy};
    let (dir, key, quant) = (&o.dir, &o.unnorm_key, o.quant);
    match o.batch {
        None => {
            let mut policy = OftPolicy::load(dir, key.clone(), o.devices.first().copied(), quant)?;
            if let Some(a) = o.attention {
                policy.set_attention(a);
            }
            Ok(Box::new(policy))
        }
        Some(n) => batched(spec, n, &o.replica_devices(), "oft", |device| {
            let mut model = OftBatchModel::load(dir, key.clone(), device, quant)?;
            if let Some(a) = o.attention {
                model.set_attention(a);
            }
            Ok(model)
        }),
    }
}

#[cfg(not(feature = "torch"))]
fn load_oft(_: &CheckpointOptions, _: &str) -> Result<Box<dyn Policy>, PolicyError> {
    Err(PolicyError {
        policy: "oft".into(),
        detail: "this build has no libtorch (built without the `torch` feature)".into(),
    })
}

#[cfg(not(feature = "torch"))]
fn load_openvla(_: &CheckpointOptions, _: &str) -> Result<Box<dyn Policy>, PolicyError> {
    Err(PolicyError {
        policy: "openvla".into(),
        detail: "this build has no libtorch (built without the `torch` feature)".into(),
    })
}

#[cfg(not(feature = "torch"))]
fn load_torchscript(
    _: &std::path::Path,
    _: Option<Batching>,
    _: Option<ModelDevice>,
    _: &str,
) -> Result<Box<dyn Policy>, PolicyError> {
    Err(PolicyError {
        policy: "torchscript".into(),
        detail: "this build has no libtorch (built without the `torch` feature)".into(),
    })
}

/// The `?a=b&c=d` options of a model policy, each given at most once and only from `known`.
fn model_options<'a>(
    kind: &str,
    rest: &'a str,
    known: &[&str],
) -> Result<(&'a str, std::collections::BTreeMap<&'a str, &'a str>), String> {
    let (target, query) = rest.split_once('?').map_or((rest, None), |(t, q)| (t, Some(q)));
    let mut options = std::collections::BTreeMap::new();
    for option in query.into_iter().flat_map(|q| q.split('&')) {
        match option.split_once('=') {
            Some((name, value)) if known.contains(&name) => {
                if options.insert(name, value).is_some() {
                    return Err(format!("{kind}:{rest}: {name} is given twice"));
                }
            }
            _ => {
                return Err(format!(
                    "{kind}:{rest}: unknown option {option:?}; the options are {}",
                    known.iter().map(|k| option_help(k)).collect::<Vec<_>>().join(", ")
                ));
            }
        }
    }
    Ok((target, options))
}

fn option_help(name: &str) -> &'static str {
    match name {
        "unnorm" => "unnorm=<dataset key>",
        "batch" => "batch=N with N >= 1 (episodes per forward)",
        "wait_ms" => "wait_ms=W (with batch: most milliseconds a forward waits for an episode in progress, default 20)",
        "stats" => "stats=<dataset_statistics.json> (the older generation's action bounds)",
        "chunk" => "chunk=N with N >= 1 (actions executed per query)",
        "state" => "state=0|1 (send the 8-D state)",
        "quant" => "quant=int8|int4 (weight-only quantisation of the linear layers)",
        "attention" => {
            "attention=eager|sdpa (the language model's attention; default: sdpa on a GPU, eager on the CPU for openvla, sdpa for oft)"
        }
        "devices" => {
            "devices=cuda:0,cuda:1 (where the model runs: cpu, cuda or cuda:N; several with batch, one model replica per device, a device may repeat; devices=cpu runs a model on the CPU on purpose)"
        }
        "device" => "devices=D (the one device the module runs on: cpu, cuda or cuda:N)",
        _ => "?",
    }
}

/// `batch=N[&wait_ms=W]` out of a model policy's options.
fn batching(
    kind: &str,
    rest: &str,
    options: &std::collections::BTreeMap<&str, &str>,
) -> Result<Option<Batching>, String> {
    let bad = |name: &str| format!("{kind}:{rest}: expected {}", option_help(name));
    let wait_ms = match options.get("wait_ms") {
        None => Batching::DEFAULT_WAIT_MS,
        Some(w) => w.parse::<u64>().map_err(|_| bad("wait_ms"))?,
    };
    match options.get("batch") {
        None if options.contains_key("wait_ms") => Err(format!("{kind}:{rest}: wait_ms needs batch=N")),
        None => Ok(None),
        Some(n) => match n.parse::<usize>() {
            Ok(max_episodes) if max_episodes >= 1 => Ok(Some(Batching { max_episodes, wait_ms })),
            _ => Err(bad("batch")),
        },
    }
}

/// `<dir>[?unnorm=<key>][&batch=N[&wait_ms=W]][&devices=...][&quant=...]` of `openvla:...`
/// (options in any order).
fn parse_openvla(rest: &str) -> Result<PolicySpec, String> {
    Ok(PolicySpec::OpenVla(checkpoint_options("openvla", rest)?))
}

/// The same options as `openvla:`, of `oft:...`.
fn parse_oft(rest: &str) -> Result<PolicySpec, String> {
    Ok(PolicySpec::Oft(checkpoint_options("oft", rest)?))
}

/// A checkpoint directory with `unnorm`, batching, device and quantisation options.
fn checkpoint_options(kind: &str, rest: &str) -> Result<CheckpointOptions, String> {
    let (dir, options) = model_options(kind, rest, &["unnorm", "batch", "wait_ms", "devices", "quant", "attention"])?;
    let bad = |name: &str, why: String| format!("{kind}:{rest}: expected {} ({why})", option_help(name));
    let unnorm_key = match options.get("unnorm") {
        Some(&"") => return Err(format!("{kind}:{rest}: expected {}", option_help("unnorm"))),
        k => k.map(|k| k.to_string()),
    };
    let quant = match options.get("quant") {
        None => Quantization::None,
        Some(q) => q.parse().map_err(|e| bad("quant", e))?,
    };
    let devices = match options.get("devices") {
        None => Vec::new(),
        Some(d) => parse_devices(d).map_err(|e| bad("devices", e))?,
    };
    let attention = match options.get("attention") {
        None => None,
        Some(a) => Some(a.parse().map_err(|e| bad("attention", e))?),
    };
    let batch = batching(kind, rest, &options)?;
    if devices.len() > 1 && batch.is_none() {
        return Err(format!(
            "{kind}:{rest}: several devices need batch=N (each device's replica serves its episodes through its own batcher)"
        ));
    }
    Ok(CheckpointOptions { dir: dir.into(), unnorm_key, batch, quant, devices, attention, ensemble: None })
}

/// The benchmark a TorchScript module's `model.json` declares (`"benchmark"`, LIBERO when absent),
/// read without loading the module (so a run is refused before any model loads).
fn torchscript_benchmark(file: &std::path::Path) -> Result<Benchmark, String> {
    let manifest = file.with_extension("json");
    let text = std::fs::read_to_string(&manifest).map_err(|e| {
        format!(
            "{}: {e}; a TorchScript policy needs its manifest beside it (see policies::models::torchscript)",
            manifest.display()
        )
    })?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format!("{}: not JSON: {e}", manifest.display()))?;
    match v.get("benchmark").and_then(serde_json::Value::as_str) {
        None | Some("libero") => Ok(Benchmark::Libero),
        Some("aloha_sim") => Ok(Benchmark::AlohaSim),
        Some(other) => Err(format!("{}: unknown benchmark {other:?}; known: libero, aloha_sim", manifest.display())),
    }
}

/// `<file>[?batch=N[&wait_ms=W]][&devices=D]` of `torchscript:...`: one device (the module is
/// what its author exported; it gets one replica).
fn parse_torchscript(rest: &str) -> Result<PolicySpec, String> {
    let (file, options) = model_options("torchscript", rest, &["batch", "wait_ms", "devices"])?;
    let device = match options.get("devices") {
        None => None,
        Some(d) => match parse_devices(d) {
            Ok(devices) if devices.len() == 1 => Some(devices[0]),
            Ok(_) => return Err(format!("torchscript:{rest}: expected {} (one device)", option_help("device"))),
            Err(e) => return Err(format!("torchscript:{rest}: expected {} ({e})", option_help("device"))),
        },
    };
    Ok(PolicySpec::TorchScript {
        file: file.into(),
        batch: batching("torchscript", rest, &options)?,
        device,
        ensemble: None,
    })
}

/// `ws://host:port[?replan=N]` of `openpi:...`.
fn parse_openpi(rest: &str) -> Result<PolicySpec, String> {
    let (url, query) = rest.split_once('?').map_or((rest, None), |(u, q)| (u, Some(q)));
    if !url.starts_with("ws://") {
        return Err(format!("openpi:{rest}: the server address must be a ws:// URL, e.g. openpi:ws://localhost:8000"));
    }
    let replan_steps = match query {
        None => None,
        Some(q) => match q.strip_prefix("replan=").map(str::parse::<usize>) {
            Some(Ok(n)) if n >= 1 => Some(n),
            _ => {
                return Err(format!(
                    "openpi:{rest}: the only option is ?replan=N with N >= 1 (actions executed per chunk)"
                ));
            }
        },
    };
    Ok(PolicySpec::Openpi { url: url.to_string(), replan_steps, ensemble: None })
}

/// `ws://host:port[?unnorm=<key>][&stats=<file>][&chunk=N][&state=0|1]` of `starvla:...`
/// (options in any order; which apply depends on the server's generation, checked at connect).
fn parse_starvla(rest: &str) -> Result<PolicySpec, String> {
    let (url, options) = model_options("starvla", rest, &["unnorm", "stats", "chunk", "state"])?;
    if !url.starts_with("ws://") || url.len() == "ws://".len() {
        return Err(format!(
            "starvla:{rest}: the server address must be a ws:// URL, e.g. starvla:ws://localhost:10093"
        ));
    }
    let bad = |name: &str| format!("starvla:{rest}: expected {}", option_help(name));
    let text = |name: &str| match options.get(name) {
        Some(&"") => Err(bad(name)),
        v => Ok(v.map(|v| v.to_string())),
    };
    let chunk = match options.get("chunk") {
        None => None,
        Some(n) => Some(n.parse::<usize>().ok().filter(|&n| n >= 1).ok_or_else(|| bad("chunk"))?),
    };
    let state = match options.get("state") {
        None => None,
        Some(&"0") => Some(false),
        Some(&"1") => Some(true),
        Some(_) => return Err(bad("state")),
    };
    Ok(PolicySpec::StarVla(StarVlaOptions {
        url: url.to_string(),
        unnorm_key: text("unnorm")?,
        stats: text("stats")?.map(Into::into),
        chunk,
        state,
        ensemble: None,
    }))
}

/// `ws://host:port` of `vla-eval:...` (no options: the server's HELLO says what to send).
fn parse_vla_eval(url: &str) -> Result<PolicySpec, String> {
    if !url.starts_with("ws://") || url.len() == "ws://".len() {
        return Err(format!(
            "vla-eval:{url}: the server address must be a ws:// URL, e.g. vla-eval:ws://localhost:8000"
        ));
    }
    if url.contains('?') {
        return Err(format!("vla-eval:{url}: takes no options (the server's observation params decide what is sent)"));
    }
    Ok(PolicySpec::VlaEval { url: url.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn processes_deal_the_devices_out_in_turn() {
        let share = |text: &str, k: usize, n: usize| -> Result<String, String> {
            text.parse::<PolicySpec>().unwrap().device_share(k, n).map(|p| p.to_string())
        };
        let four = "oft:/c?batch=64&devices=cuda:0,cuda:1,cuda:2,cuda:3";
        assert_eq!(share(four, 0, 4).unwrap(), "oft:/c?batch=64&devices=cuda:0");
        assert_eq!(share(four, 3, 4).unwrap(), "oft:/c?batch=64&devices=cuda:3");
        assert_eq!(share(four, 1, 2).unwrap(), "oft:/c?batch=64&devices=cuda:1,cuda:3");
        assert_eq!(share("lerobot:/c?devices=cuda:0,cuda:1", 1, 2).unwrap(), "lerobot:/c?devices=cuda:1");
        // no model: the same policy in every process; a model without a device list is refused
        assert_eq!(share("expert", 1, 3).unwrap(), "expert");
        assert_eq!(share("openpi:ws://h:1", 0, 2).unwrap(), "openpi:ws://h:1");
        let err = share("openvla:/c?batch=8", 1, 2).unwrap_err();
        assert!(err.contains("lists none") && err.contains("devices=cuda:0,cuda:1"), "{err}");
        assert!(share("torchscript:/m.pt", 0, 2).unwrap_err().contains("one device"));
        assert_eq!(share("openvla:/c?batch=8", 0, 1).unwrap(), "openvla:/c?batch=8");
        let err = share("openvla:/c?batch=8&devices=cuda:0,cuda:1", 0, 4).unwrap_err();
        assert!(
            err.contains("--processes 4") && err.contains("lists 2") && err.contains("ask for 2 processes"),
            "{err}"
        );
    }

    #[test]
    fn ensemble_is_an_option_of_every_chunked_policy_and_refused_where_it_cannot_mean_anything() {
        for (text, printed) in [
            ("oft:/c?ensemble=average:4&batch=8", "oft:/c?batch=8&ensemble=average:4"),
            ("torchscript:/m.pt?ensemble=temporal:0.01", "torchscript:/m.pt?ensemble=temporal:0.01"),
            ("openpi:ws://h:1?ensemble=ema:0.5:2", "openpi:ws://h:1?ensemble=ema:0.5:2"),
            ("starvla:ws://h:1?ensemble=adaptive:3:0.1&unnorm=k", "starvla:ws://h:1?unnorm=k&ensemble=adaptive:3:0.1"),
            ("python:m:f?ensemble=newest:2&size=4", "python:m:f?size=4&ensemble=newest:2"),
        ] {
            let p: PolicySpec = text.parse().unwrap_or_else(|e| panic!("{text}: {e}"));
            assert_eq!(p.to_string(), printed);
            assert_eq!(printed.parse::<PolicySpec>().unwrap(), p, "{printed}");
            let rule = printed.rsplit("ensemble=").next().unwrap();
            assert_eq!(p.ensemble().unwrap().to_string(), rule);
            assert_eq!(p.identity()["ensemble"]["rule"], rule, "{}", p.identity());
        }
        for (text, says) in [
            ("openvla:/c?ensemble=average:2", "one action per query"),
            ("vla-eval:ws://h:1?ensemble=average:2", "set its own action_ensemble"),
            ("lift?ensemble=average:2", "nothing to ensemble"),
            ("openpi:ws://h:1?replan=5&ensemble=average:2", "replan=N and ensemble=average:2 both say"),
            ("starvla:ws://h:1?chunk=7&ensemble=temporal:0.01", "chunk=N and ensemble"),
            ("lerobot:/c?steps=5&ensemble=average:2", "steps=N and ensemble"),
            ("oft:/c?ensemble=average:2&ensemble=newest:2", "given twice"),
            ("oft:/c?ensemble=median:2", "unknown rule"),
        ] {
            let err = text.parse::<PolicySpec>().unwrap_err();
            assert!(err.contains(says), "{text}: {err}");
        }
    }

    #[test]
    fn starvla_specs_parse_in_any_option_order_and_print_back() {
        let p: PolicySpec = "starvla:ws://localhost:10093".parse().unwrap();
        assert_eq!(p.to_string(), "starvla:ws://localhost:10093");
        assert!(p.sees_cameras());
        let p: PolicySpec =
            "starvla:ws://h:1?state=1&chunk=7&stats=/c/dataset_statistics.json&unnorm=franka".parse().unwrap();
        let expected = StarVlaOptions {
            url: "ws://h:1".into(),
            unnorm_key: Some("franka".into()),
            stats: Some("/c/dataset_statistics.json".into()),
            chunk: Some(7),
            state: Some(true),
            ensemble: None,
        };
        assert_eq!(p, PolicySpec::StarVla(expected.clone()));
        let printed = "starvla:ws://h:1?unnorm=franka&stats=/c/dataset_statistics.json&chunk=7&state=1";
        assert_eq!(p.to_string(), printed);
        assert_eq!(printed.parse::<PolicySpec>().unwrap(), PolicySpec::StarVla(expected));
        for (bad, says) in [
            ("starvla:localhost:1", "ws://"),
            ("starvla:ws://h:1?chunk=0", "chunk=N"),
            ("starvla:ws://h:1?state=yes", "state=0|1"),
            ("starvla:ws://h:1?unnorm=", "unnorm=<dataset key>"),
            ("starvla:ws://h:1?replan=2", "unknown option"),
            ("nope", "starvla:ws://host:port"),
        ] {
            let e = bad.parse::<PolicySpec>().unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn vla_eval_specs_parse_and_print_back() {
        let p: PolicySpec = "vla-eval:ws://localhost:8000".parse().unwrap();
        assert_eq!(p, PolicySpec::VlaEval { url: "ws://localhost:8000".into() });
        assert_eq!(p.to_string(), "vla-eval:ws://localhost:8000");
        assert!(p.sees_cameras());
        assert!("vla-eval:localhost:8000".parse::<PolicySpec>().unwrap_err().contains("ws://"));
        assert!("vla-eval:ws://h:1?replan=2".parse::<PolicySpec>().unwrap_err().contains("no options"));
        assert!("nope".parse::<PolicySpec>().unwrap_err().contains("vla-eval:ws://host:port"));
    }

    #[test]
    fn python_host_specs_parse_and_print_back_in_canonical_order() {
        use crate::python_host::PythonTarget;
        let p: PolicySpec = "lerobot:ckpt?steps=10&batch=8&python=/v/bin/python&devices=cuda:0,cuda:1".parse().unwrap();
        let PolicySpec::Python(o) = &p else { panic!("{p:?}") };
        assert_eq!(o.target, PythonTarget::Lerobot("ckpt".into()));
        assert_eq!(o.devices, [ModelDevice::Cuda(0), ModelDevice::Cuda(1)]);
        assert_eq!(o.policy_options, [("steps".to_string(), "10".to_string())]);
        assert_eq!(p.to_string(), "lerobot:ckpt?python=/v/bin/python&batch=8&devices=cuda:0,cuda:1&steps=10");
        assert_eq!(p.to_string().parse::<PolicySpec>().unwrap(), p);
        assert_eq!(p.model_cuda_devices(), [0, 1]);
        assert!(p.sees_cameras());
        // python: passes its own keys through; lerobot: refuses them
        let p: PolicySpec = "python:pkg.mod:make?ckpt=/m&timeout_s=5".parse().unwrap();
        let PolicySpec::Python(o) = &p else { panic!("{p:?}") };
        assert_eq!(o.target, PythonTarget::Module { module: "pkg.mod".into(), factory: "make".into() });
        assert_eq!(o.policy_options, [("ckpt".to_string(), "/m".to_string())]);
        assert_eq!((o.call_timeout_s, o.batching().max_episodes), (Some(5), PythonOptions::DEFAULT_BATCH));
        let err = |s: &str| s.parse::<PolicySpec>().unwrap_err();
        assert!(err("lerobot:ckpt?ckpt=/m").contains("unknown option \"ckpt=/m\""), "{}", err("lerobot:ckpt?ckpt=/m"));
        assert!(err("lerobot:ckpt?steps=0").contains("steps=N with N >= 1"));
        assert!(err("lerobot:ckpt?benchmark=aloha_sim").contains("comes from the specs"));
        assert!(err("python:make").contains("python:<module>:<factory>"));
        assert!(err("python:m:f?k=1&k=2").contains("given twice"));
        assert!(err("lerobot:ckpt?timeout_s=0").contains("timeout_s=S with S >= 1"));
        // both benchmarks: the host checks the checkpoint's features against the run's
        let lerobot = PolicySpec::Python(PythonOptions::parse("lerobot", "ckpt").unwrap());
        assert_eq!(lerobot.check_benchmark(Benchmark::AlohaSim), Ok(()));
        assert_eq!(lerobot.check_benchmark(Benchmark::Libero), Ok(()));
    }

    #[test]
    fn openpi_specs_parse_and_print_back() {
        let p: PolicySpec = "openpi:ws://localhost:8000".parse().unwrap();
        assert_eq!(p, PolicySpec::Openpi { url: "ws://localhost:8000".into(), replan_steps: None, ensemble: None });
        assert_eq!(PolicySpec::openpi_replan_steps(None, Benchmark::Libero), 5);
        assert_eq!(PolicySpec::openpi_replan_steps(None, Benchmark::AlohaSim), 10);
        assert_eq!(PolicySpec::openpi_replan_steps(Some(3), Benchmark::AlohaSim), 3);
        assert_eq!(p.to_string(), "openpi:ws://localhost:8000");
        let p: PolicySpec = "openpi:ws://h:1?replan=10".parse().unwrap();
        assert_eq!(p.to_string(), "openpi:ws://h:1?replan=10");
        assert!("openpi:http://h:1".parse::<PolicySpec>().unwrap_err().contains("ws://"));
        assert!("openpi:ws://h:1?replan=0".parse::<PolicySpec>().unwrap_err().contains("replan=N"));
        assert!("nope".parse::<PolicySpec>().unwrap_err().contains("openpi:ws://"));
    }

    #[test]
    fn replicas_and_quantisation_parse_and_print_back() {
        let text = "openvla:/c?quant=int4&devices=cuda:0,cuda:1&batch=32&unnorm=k";
        let p: PolicySpec = text.parse().unwrap();
        let PolicySpec::OpenVla(o) = &p else { panic!("{p:?}") };
        assert_eq!(o.devices, [ModelDevice::Cuda(0), ModelDevice::Cuda(1)]);
        assert_eq!(o.quant, Quantization::Int4);
        let printed = "openvla:/c?unnorm=k&batch=32&devices=cuda:0,cuda:1&quant=int4";
        assert_eq!(p.to_string(), printed);
        assert_eq!(printed.parse::<PolicySpec>().unwrap(), p);
        let p: PolicySpec = "oft:/c?batch=4&devices=cpu,cpu&quant=int8".parse().unwrap();
        assert_eq!(p.to_string(), "oft:/c?batch=4&devices=cpu,cpu&quant=int8");
        assert_eq!(p.identity()["devices"], "cpu,cpu");
        // one device needs no batcher: `devices=cpu` is how a model runs on the CPU on purpose
        let p: PolicySpec = "openvla:/c?devices=cpu".parse().unwrap();
        let PolicySpec::OpenVla(o) = &p else { panic!("{p:?}") };
        assert_eq!((o.devices.as_slice(), o.batch), (&[ModelDevice::Cpu][..], None));
        assert_eq!(p.to_string(), "openvla:/c?devices=cpu");
        // a TorchScript module takes one device, with or without batch
        for (text, device, printed) in [
            ("torchscript:/m.pt?devices=cpu", Some(ModelDevice::Cpu), "torchscript:/m.pt?devices=cpu"),
            (
                "torchscript:/m.pt?devices=cuda&batch=4",
                Some(ModelDevice::Cuda(0)),
                "torchscript:/m.pt?batch=4&devices=cuda:0",
            ),
            ("torchscript:/m.pt?batch=4", None, "torchscript:/m.pt?batch=4"),
        ] {
            let p: PolicySpec = text.parse().unwrap();
            let PolicySpec::TorchScript { device: d, .. } = &p else { panic!("{p:?}") };
            assert_eq!(*d, device, "{text}");
            assert_eq!(p.to_string(), printed);
            assert_eq!(printed.parse::<PolicySpec>().unwrap(), p);
        }
    }

    #[test]
    fn attention_is_an_option_of_checkpoint_policies_and_a_bad_one_names_the_choices() {
        let p: PolicySpec = "openvla:/c?attention=eager&unnorm=k".parse().unwrap();
        let PolicySpec::OpenVla(o) = &p else { panic!("{p:?}") };
        assert_eq!(o.attention, Some(Attention::Eager));
        assert_eq!(p.to_string(), "openvla:/c?unnorm=k&attention=eager");
        let p: PolicySpec = "oft:/c?attention=sdpa".parse().unwrap();
        assert_eq!(p.to_string(), "oft:/c?attention=sdpa");
        let PolicySpec::OpenVla(o) = "openvla:/c".parse().unwrap() else { panic!() };
        assert_eq!(o.attention, None);
        let e = "openvla:/c?attention=flash".parse::<PolicySpec>().unwrap_err();
        assert!(e.contains("attention=eager|sdpa") && e.contains("flash"), "{e}");
        // the defaults: the published loop's flash attention on a GPU, the parity reference's eager on a CPU
        assert_eq!(Attention::model_default(false, true), Attention::Sdpa);
        assert_eq!(Attention::model_default(false, false), Attention::Eager);
        assert_eq!(Attention::model_default(true, false), Attention::Sdpa);
    }

    #[test]
    fn openvla_specs_parse_in_any_option_order_and_print_back() {
        let dir = std::path::PathBuf::from("/ckpt/openvla-7b");
        let cases = [
            ("openvla:/ckpt/openvla-7b", None, None, "openvla:/ckpt/openvla-7b"),
            ("openvla:/ckpt/openvla-7b?unnorm=k", Some("k"), None, "openvla:/ckpt/openvla-7b?unnorm=k"),
            ("openvla:/ckpt/openvla-7b?batch=8", None, Some((8, 20)), "openvla:/ckpt/openvla-7b?batch=8"),
            (
                "openvla:/ckpt/openvla-7b?batch=8&unnorm=k",
                Some("k"),
                Some((8, 20)),
                "openvla:/ckpt/openvla-7b?unnorm=k&batch=8",
            ),
            (
                "openvla:/ckpt/openvla-7b?wait_ms=500&batch=4",
                None,
                Some((4, 500)),
                "openvla:/ckpt/openvla-7b?batch=4&wait_ms=500",
            ),
        ];
        for (text, unnorm, batch, printed) in cases {
            let batch = batch.map(|(max_episodes, wait_ms)| Batching { max_episodes, wait_ms });
            let p: PolicySpec = text.parse().unwrap();
            let options = CheckpointOptions {
                dir: dir.clone(),
                unnorm_key: unnorm.map(str::to_string),
                batch,
                quant: Quantization::None,
                devices: Vec::new(),
                attention: None,
                ensemble: None,
            };
            let expected = PolicySpec::OpenVla(options.clone());
            assert_eq!(p, expected, "{text}");
            assert_eq!(p.to_string(), printed);
            assert_eq!(printed.parse::<PolicySpec>().unwrap(), expected, "{printed} reads back");
            // oft: takes the same options
            let oft_text = text.replacen("openvla:", "oft:", 1);
            let p: PolicySpec = oft_text.parse().unwrap();
            let expected = PolicySpec::Oft(options);
            assert_eq!(p, expected, "{oft_text}");
            assert_eq!(p.to_string(), printed.replacen("openvla:", "oft:", 1));
            assert!(p.sees_cameras());
        }
        assert!("nope".parse::<PolicySpec>().unwrap_err().contains("oft:<checkpoint dir>"));
        for (bad, says) in [
            ("openvla:/c?batch=0", "batch=N"),
            ("openvla:/c?unnorm=", "unnorm=<dataset key>"),
            ("openvla:/c?unnorm=a&unnorm=b", "twice"),
            ("openvla:/c?batch=2&batch=4", "twice"),
            ("openvla:/c?replan=4", "unknown option"),
            ("openvla:/c?wait_ms=5", "needs batch=N"),
            ("openvla:/c?batch=2&wait_ms=x", "wait_ms=W"),
            ("torchscript:/m.pt?unnorm=k", "unknown option"),
            ("oft:/c?unnorm=", "unnorm=<dataset key>"),
            ("oft:/c?replan=8", "unknown option"),
            ("torchscript:/m.pt?batch=0", "batch=N"),
            ("openvla:/c?devices=cuda:0,cuda:1", "several devices need batch=N"),
            ("torchscript:/m.pt?devices=cpu,cuda:0", "one device"),
            ("torchscript:/m.pt?devices=gpu", "cuda:N"),
            ("openvla:/c?batch=2&devices=gpu0", "cuda:N"),
            ("oft:/c?quant=int2", "int8 or int4"),
            ("torchscript:/m.pt?quant=int8", "unknown option"),
        ] {
            let e = bad.parse::<PolicySpec>().unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }
}
