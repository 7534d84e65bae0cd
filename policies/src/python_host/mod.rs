//! Policies that are Python programs, run in a Python process the pipeline starts and manages:
//! `lerobot:<checkpoint dir>` (a lerobot 0.6.1 checkpoint, fed as `lerobot-eval` feeds it) and
//! `python:<module>:<factory>` (any Python object with `describe()` and `act(batch)`).
//!
//! The binary never links libpython: it starts `<interpreter> -u libero_eval_host.py` (the
//! script is compiled into the binary and written out once per content hash), and speaks
//! [`frames`] over the host's stdin/stdout ([`process`]). The interpreter is the user's: the
//! policy string's `python=` option, else `LIBERO_EVAL_PYTHON`; so a lerobot venv, a JAX venv
//! (an Octo port through `python:`), anything with NumPy.
//!
//! A host serves one model replica: [`PythonHostModel`] is a [`BatchModel`], so the rollout
//! workers' queries share its calls (`batch=N`), each episode keeps its own action queue (the
//! first `executed_steps` of each chunk the host returns), and `devices=cuda:0,cuda:1` starts one
//! host per device. A host that crashes, hangs past `timeout_s` or answers nonsense turns the
//! episodes of that call into error rows and is started again for the next call; a policy that
//! raises costs only that call's episodes (the host keeps serving). On ALOHA-sim the same host
//! is a [`PythonAlohaHost`]: gym-aloha's `top` camera and `agent_pos` in, 14-D actions out.

pub mod frames;
mod process;

use crate::Action;
use crate::aloha::{AlohaAction, AlohaObservation};
use crate::batching::{BatchModel, Request};
use crate::placement::ModelDevice;
use frames::{Array, Frame};
pub use process::{HostCommand, HostProcess};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Duration;

/// The host script and lerobot's adapter, as shipped in `policies/python/`.
const HOST_SCRIPT: &str = include_str!("../../python/libero_eval_host.py");
const LEROBOT_ADAPTER: &str = include_str!("../../python/lerobot_policy.py");
/// The frames' protocol version the script speaks (`PROTOCOL` there).
pub const PROTOCOL: u64 = 1;
/// The environment variable naming the interpreter when the policy string does not.
pub const PYTHON_ENV: &str = "LIBERO_EVAL_PYTHON";

/// What the host runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PythonTarget {
    /// A lerobot checkpoint directory (`config.json`, `model.safetensors`, the processors).
    Lerobot(PathBuf),
    /// `module:factory`: `factory(device=..., **options)` returns the policy object.
    Module { module: String, factory: String },
}

impl PythonTarget {
    fn argument(&self) -> String {
        match self {
            PythonTarget::Lerobot(dir) => {
                let dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.clone());
                format!("lerobot:{}", dir.display())
            }
            PythonTarget::Module { module, factory } => format!("python:{module}:{factory}"),
        }
    }

    pub fn kind(&self) -> &'static str {
        match self {
            PythonTarget::Lerobot(_) => "lerobot",
            PythonTarget::Module { .. } => "python",
        }
    }
}

/// Everything that starts a host and feeds it, from the policy string.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PythonHostConfig {
    pub target: PythonTarget,
    /// `python=`; else [`PYTHON_ENV`].
    pub interpreter: Option<PathBuf>,
    /// The benchmark whose observations are sent (`libero`, `aloha_sim`).
    pub benchmark: String,
    /// Options passed to the policy as strings (`steps`, `tokenizer` for lerobot; any for python:).
    pub options: Vec<(String, String)>,
    /// Longest wait for one call's actions (`timeout_s=`, default 120 s); loading has its own
    /// (`load_timeout_s=`, default 1200 s: a 4 B checkpoint's hash and load on a cold disk).
    pub call_timeout: Duration,
    pub load_timeout: Duration,
    /// `ensemble=` is set: a lerobot checkpoint answers its whole chunk (`chunk_size` actions),
    /// not the first `n_action_steps`, so the rule sees every prediction (ACT's temporal
    /// ensembling weighs all `chunk_size` of them).
    pub whole_chunks: bool,
}

impl PythonHostConfig {
    pub const DEFAULT_CALL_TIMEOUT_S: u64 = 120;
    pub const DEFAULT_LOAD_TIMEOUT_S: u64 = 1200;

    /// The interpreter to start, checked to exist: the fix is named when none is given or found.
    pub fn interpreter(&self) -> Result<PathBuf, String> {
        let path = match &self.interpreter {
            Some(p) => p.clone(),
            None => match std::env::var_os(PYTHON_ENV) {
                Some(p) if !p.is_empty() => PathBuf::from(p),
                _ => {
                    return Err(format!(
                        "{} policies run in a Python interpreter you name: add ?python=/path/to/venv/bin/python to the policy, or set {PYTHON_ENV}; {}",
                        self.target.kind(),
                        self.install_hint()
                    ));
                }
            },
        };
        if !path.exists() {
            return Err(format!("the Python interpreter {} does not exist; {}", path.display(), self.install_hint()));
        }
        Ok(path)
    }

    fn install_hint(&self) -> &'static str {
        match self.target {
            PythonTarget::Lerobot(_) => {
                "a venv with lerobot 0.6.1 (Python >= 3.12): python3.12 -m venv V && V/bin/pip install torch==2.11.0 torchvision==0.26.0 'lerobot[pi,smolvla]==0.6.1' (./setup.sh --tests makes one at .lerobot-venv)"
            }
            PythonTarget::Module { .. } => "any interpreter with NumPy and your policy's packages",
        }
    }

    /// How to start the host for `device` (None: the host's default, CUDA where torch sees it).
    pub fn command(&self, device: Option<ModelDevice>) -> Result<HostCommand, String> {
        let interpreter = self.interpreter()?;
        let script = host_script()?;
        let mut args = vec!["--target".to_string(), self.target.argument()];
        if let Some(d) = device {
            args.extend(["--device".to_string(), d.to_string()]);
        }
        let mut options = self.options.clone();
        if matches!(self.target, PythonTarget::Lerobot(_)) {
            options.push(("benchmark".into(), self.benchmark.clone()));
            if self.whole_chunks {
                options.push(("whole_chunk".into(), "1".into()));
            }
        }
        for (k, v) in options {
            args.extend(["--option".to_string(), format!("{k}={v}")]);
        }
        let label = match device {
            Some(d) => format!("{} {d}", self.target.kind()),
            None => self.target.kind().to_string(),
        };
        Ok(HostCommand { interpreter, script, args, label })
    }
}

/// The host script, written once per content hash under the temp folder (a run may start many
/// hosts; a binary of another version writes its own).
fn host_script() -> Result<PathBuf, String> {
    let hash = format!("{:x}", Sha256::new().chain_update(HOST_SCRIPT).chain_update(LEROBOT_ADAPTER).finalize());
    let dir = std::env::temp_dir().join(format!("libero-eval-host-{}", &hash[..12]));
    let script = dir.join("libero_eval_host.py");
    if script.exists() && dir.join("lerobot_policy.py").exists() {
        return Ok(script);
    }
    let write = |name: &str, text: &str| -> std::io::Result<()> {
        std::fs::create_dir_all(&dir)?;
        let tmp = dir.join(format!("{name}.{}", std::process::id()));
        std::fs::write(&tmp, text)?;
        std::fs::rename(&tmp, dir.join(name))
    };
    write("lerobot_policy.py", LEROBOT_ADAPTER)
        .and_then(|_| write("libero_eval_host.py", HOST_SCRIPT))
        .map_err(|e| format!("cannot write the Python host script to {}: {e}", dir.display()))?;
    Ok(script)
}

/// What the policy's `describe()` asks of the pipeline, and the rest of it for the manifest.
#[derive(Debug, Clone)]
pub struct Description {
    /// LIBERO's cameras' square size (`agentview`, `wrist`); None on ALOHA-sim.
    pub camera_size: Option<u32>,
    pub wrist: bool,
    /// ALOHA-sim's `top` camera (480 × 640, its only one).
    pub top: bool,
    pub executed_steps: usize,
    pub identity: Value,
}

impl Description {
    /// From the host's `ready` frame, checked against the benchmark's cameras and action width.
    fn from_ready(ready: &Frame, benchmark: &str) -> Result<Self, String> {
        let benchmark_action_dim = benchmark_action_dim(benchmark);
        let protocol = ready.header.get("protocol").and_then(Value::as_u64);
        if protocol != Some(PROTOCOL) {
            return Err(format!("the host speaks protocol {protocol:?}, this pipeline {PROTOCOL}"));
        }
        let d = ready.header.get("describe").cloned().unwrap_or(Value::Null);
        if !d.is_object() {
            return Err(format!("describe() returned {d}, expected a dict"));
        }
        let observation = d.get("observation").cloned().unwrap_or(json!({}));
        let cameras: Vec<&str> = observation
            .get("cameras")
            .and_then(Value::as_array)
            .map(|c| c.iter().filter_map(Value::as_str).collect())
            .unwrap_or_default();
        let known: &[&str] = if benchmark == "aloha_sim" { &["top"] } else { &["agentview", "wrist"] };
        if let Some(c) = cameras.iter().find(|c| !known.contains(c)) {
            return Err(format!(
                "describe()[\"observation\"][\"cameras\"] names {c:?}, and {benchmark} renders {known:?}"
            ));
        }
        let square = cameras.iter().any(|c| *c != "top");
        let camera_size = match (square, observation.get("camera_size").and_then(Value::as_u64)) {
            (false, _) => None,
            (true, Some(s)) if (16..=2048).contains(&s) => Some(s as u32),
            (true, other) => {
                return Err(format!(
                    "describe()[\"observation\"][\"camera_size\"] is {other:?}: a policy that reads cameras names their square size (16..2048)"
                ));
            }
        };
        let action_dim = d.get("action_dim").and_then(Value::as_u64).unwrap_or(benchmark_action_dim as u64) as usize;
        if action_dim != benchmark_action_dim {
            return Err(format!(
                "the policy's actions are {action_dim}-D, and this benchmark takes {benchmark_action_dim}-D actions"
            ));
        }
        let executed_steps = match d.get("executed_steps").and_then(Value::as_u64) {
            Some(n) if n >= 1 => n as usize,
            None => 1,
            Some(n) => return Err(format!("describe()[\"executed_steps\"] is {n}; it must be >= 1")),
        };
        Ok(Description {
            camera_size,
            wrist: cameras.contains(&"wrist"),
            top: cameras.contains(&"top"),
            executed_steps,
            identity: d,
        })
    }
}

/// One host process as a [`BatchModel`]: each call sends the batch's observations and returns
/// each episode's chunk (its first `executed_steps` actions are executed).
pub struct PythonHostModel {
    command: HostCommand,
    host: Option<HostProcess>,
    description: Description,
    call_timeout: Duration,
    load_timeout: Duration,
}

impl PythonHostModel {
    /// The host for `device`: the one [`resolve_identity`] left running for this command, else a
    /// new one (a 4 B checkpoint is hashed and loaded once per run, not twice).
    pub fn start(config: &PythonHostConfig, device: Option<ModelDevice>) -> Result<Self, String> {
        let command = config.command(device)?;
        let mut parked = PARKED.lock().map_err(|_| "the parked hosts' lock is poisoned".to_string())?;
        if let Some(i) =
            parked.iter().position(|m| m.command.args == command.args && m.command.interpreter == command.interpreter)
        {
            return Ok(parked.swap_remove(i));
        }
        drop(parked);
        Self::start_new(command, config)
    }

    fn start_new(command: HostCommand, config: &PythonHostConfig) -> Result<Self, String> {
        let (host, ready) =
            HostProcess::start(&command, config.load_timeout).map_err(|e| with_fix(&e, &config.target))?;
        let description = Description::from_ready(&ready, &config.benchmark)?;
        Ok(PythonHostModel {
            command,
            host: Some(host),
            description,
            call_timeout: config.call_timeout,
            load_timeout: config.load_timeout,
        })
    }

    pub fn description(&self) -> &Description {
        &self.description
    }

    /// One call: `frame` (the batch's observations) out, each episode's chunk of `D`-wide actions
    /// back.
    fn call<const D: usize>(
        &mut self,
        frame: Result<Frame, String>,
        batch: usize,
    ) -> Result<Vec<Vec<[f32; D]>>, CallError> {
        if self.host.is_none() {
            let (host, _) = HostProcess::start(&self.command, self.load_timeout).map_err(CallError::HostDied)?;
            self.host = Some(host);
        }
        let frame = frame.map_err(CallError::Policy)?;
        let host = self.host.as_mut().expect("started above");
        let reply = match host.request(&frame, self.call_timeout, "waiting for the actions") {
            Ok(r) => r,
            Err(e) => {
                self.host = None;
                return Err(CallError::HostDied(e));
            }
        };
        match reply.op() {
            "actions" => split_actions::<D>(&reply, batch).map_err(|e| {
                self.host = None; // an answer we cannot read: start afresh rather than trust the next
                CallError::HostDied(format!("the Python host {} answered malformed actions: {e}", self.command.label))
            }),
            "error" => Err(CallError::Policy(format!(
                "the policy raised:\n{}",
                reply.header.get("message").and_then(Value::as_str).unwrap_or("").trim_end()
            ))),
            other => {
                self.host = None;
                Err(CallError::HostDied(format!("the Python host {} answered {other:?}", self.command.label)))
            }
        }
    }
}

enum CallError {
    /// The call failed; the host keeps serving.
    Policy(String),
    /// The host was killed or died; the next call starts a new one.
    HostDied(String),
}

/// Each request's chunk, or every request's share of the call's failure.
fn answers<A>(result: Result<Vec<Vec<A>>, CallError>, batch: usize) -> Vec<Result<Vec<A>, String>> {
    match result {
        Ok(chunks) => chunks.into_iter().map(Ok).collect(),
        Err(CallError::Policy(e)) => (0..batch).map(|_| Err(e.clone())).collect(),
        Err(CallError::HostDied(e)) => {
            let e = format!("{e}\n(these episodes are error rows; the host is started again for the next ones)");
            (0..batch).map(|_| Err(e.clone())).collect()
        }
    }
}

impl BatchModel for PythonHostModel {
    fn predict_batch(&mut self, requests: &[Request]) -> Vec<Result<Vec<Action>, String>> {
        let frame = observation_frame(requests, &self.description);
        answers(self.call::<7>(frame, requests.len()), requests.len())
    }

    fn camera_size(&self) -> Option<u32> {
        self.description.camera_size
    }

    fn wants_wrist_camera(&self) -> bool {
        self.description.wrist
    }

    fn replan_steps(&self) -> usize {
        self.description.executed_steps
    }
}

/// A host serving ALOHA-sim episodes: the batch's `top` images and `agent_pos` out, 14-D actions
/// back (started with the benchmark `aloha_sim`, so its `describe()` was checked against it).
pub struct PythonAlohaHost(PythonHostModel);

impl PythonAlohaHost {
    pub fn start(config: &PythonHostConfig, device: Option<ModelDevice>) -> Result<Self, String> {
        PythonHostModel::start(config, device).map(PythonAlohaHost)
    }
}

impl BatchModel<AlohaObservation, AlohaAction> for PythonAlohaHost {
    fn predict_batch(&mut self, requests: &[Request<AlohaObservation>]) -> Vec<Result<Vec<AlohaAction>, String>> {
        let frame = aloha_observation_frame(requests, &self.0.description);
        answers(self.0.call::<14>(frame, requests.len()), requests.len())
    }

    fn reads_cameras(&self) -> bool {
        self.0.description.top
    }

    fn wants_wrist_camera(&self) -> bool {
        false
    }

    fn replan_steps(&self) -> usize {
        self.0.description.executed_steps
    }
}

fn benchmark_action_dim(benchmark: &str) -> usize {
    match benchmark {
        "aloha_sim" => libero_schema::Benchmark::AlohaSim.action_dim(),
        _ => 7,
    }
}

/// A missing package is the user's most likely load failure: name the fix beside Python's error.
fn with_fix(error: &str, target: &PythonTarget) -> String {
    let missing = error.split("No module named '").nth(1).and_then(|rest| rest.split('\'').next());
    match (missing, target) {
        (Some(module), PythonTarget::Lerobot(_)) => format!(
            "{error}\nthe interpreter has no lerobot (it lacks the module {module:?}): install lerobot 0.6.1 there (pip install torch==2.11.0 torchvision==0.26.0 'lerobot[pi,smolvla]==0.6.1', Python >= 3.12), or name another interpreter with ?python="
        ),
        (Some(module), PythonTarget::Module { .. }) => format!(
            "{error}\nthe interpreter cannot import {module:?}: install it there, or put the policy's folder on PYTHONPATH (the host imports from the working directory and PYTHONPATH)"
        ),
        (None, _) => error.to_string(),
    }
}

/// An `act` frame without its arrays: per episode its task, seed and policy step.
fn act_frame<O>(requests: &[Request<O>], policy_step: impl Fn(&O) -> u32) -> Frame {
    let episodes: Vec<Value> = requests
        .iter()
        .map(|r| json!({"task": r.instruction, "seed": r.episode_seed, "policy_step": policy_step(&r.obs)}))
        .collect();
    Frame::new(json!({"op": "act", "episodes": episodes}))
}

/// The batch's observations as the host reads them (the docs book's "Python policies" page):
/// per episode its task, seed and policy step; arrays stacked over the batch, the cameras as
/// rendered (robosuite's orientation, rows bottom-up), the robot state in robosuite's terms
/// (`eef_quat` is `robot0_eef_quat`, x, y, z, w).
fn observation_frame(requests: &[Request], d: &Description) -> Result<Frame, String> {
    let mut frame = act_frame(requests, |o| o.policy_step);
    let b = requests.len();
    let stack = |f: &dyn Fn(&crate::Observation) -> Vec<f64>, shape: &[usize]| {
        let values: Vec<f64> = requests.iter().flat_map(|r| f(&r.obs)).collect();
        Array::f64([&[b], shape].concat(), &values)
    };
    let a = &mut frame.arrays;
    a.insert("eef_pos".into(), stack(&|o| o.eef_pos.to_vec(), &[3]));
    // robosuite's robot0_eef_quat: the hand body's quaternion in (x, y, z, w).
    a.insert("eef_quat".into(), stack(&|o| vec![o.hand_quat[1], o.hand_quat[2], o.hand_quat[3], o.hand_quat[0]], &[4]));
    a.insert("eef_mat".into(), stack(&|o| o.eef_mat.to_vec(), &[3, 3]));
    a.insert("gripper_qpos".into(), stack(&|o| o.gripper_qpos.to_vec(), &[2]));
    a.insert("gripper_qvel".into(), stack(&|o| o.gripper_qvel.to_vec(), &[2]));
    a.insert("joint_pos".into(), stack(&|o| o.joint_pos.to_vec(), &[7]));
    a.insert("joint_vel".into(), stack(&|o| o.joint_vel.to_vec(), &[7]));
    if let Some(size) = d.camera_size {
        let mut cameras = vec![("agentview", true)];
        if d.wrist {
            cameras.push(("wrist", false));
        }
        for (name, agentview) in cameras {
            let mut bytes = Vec::with_capacity(b * (size * size * 3) as usize);
            for r in requests {
                let images = r.obs.images.as_ref().ok_or("the rollout sent no camera images")?;
                let image = if agentview { &images.agentview } else { &images.wrist };
                if (image.width, image.height) != (size, size) || image.rgb.len() != (size * size * 3) as usize {
                    return Err(format!(
                        "the {name} image is {}x{}, the policy asked for {size}x{size}",
                        image.width, image.height
                    ));
                }
                bytes.extend_from_slice(&image.rgb);
            }
            a.insert(name.into(), Array::u8(vec![b, size as usize, size as usize, 3], bytes));
        }
    }
    Ok(frame)
}

/// ALOHA-sim's batch as the host reads it: per episode its task (gym-aloha's name), seed and
/// policy step; `agent_pos` (B, 14) and, when the policy reads it, `top` (B, 480, 640, 3) uint8
/// upright, as gym-aloha's `pixels_agent_pos` observation holds them.
fn aloha_observation_frame(requests: &[Request<AlohaObservation>], d: &Description) -> Result<Frame, String> {
    let mut frame = act_frame(requests, |o| o.policy_step);
    let b = requests.len();
    let agent_pos: Vec<f64> = requests.iter().flat_map(|r| r.obs.agent_pos).collect();
    frame.arrays.insert("agent_pos".into(), Array::f64(vec![b, agent_pos.len() / b.max(1)], &agent_pos));
    if d.top {
        let first = requests.first().and_then(|r| r.obs.top.as_ref()).ok_or("the rollout sent no top image")?;
        let (w, h) = (first.width as usize, first.height as usize);
        let mut bytes = Vec::with_capacity(b * w * h * 3);
        for r in requests {
            let top = r.obs.top.as_ref().ok_or("the rollout sent no top image")?;
            if (top.width as usize, top.height as usize) != (w, h) || top.rgb.len() != w * h * 3 {
                return Err(format!(
                    "the top images of one call differ in size ({}x{} and {w}x{h})",
                    top.width, top.height
                ));
            }
            bytes.extend_from_slice(&top.rgb);
        }
        frame.arrays.insert("top".into(), Array::u8(vec![b, h, w, 3], bytes));
    }
    Ok(frame)
}

/// The reply's `actions` (B, T, D) float32 as one chunk per episode, checked: the batch size,
/// the action width, at least one action, every number finite.
fn split_actions<const D: usize>(reply: &Frame, batch: usize) -> Result<Vec<Vec<[f32; D]>>, String> {
    let action_dim = D;
    let actions = reply.arrays.get("actions").ok_or("no \"actions\" array")?;
    let [b, t, d] = actions.shape[..] else {
        return Err(format!("actions of shape {:?}, expected (batch, steps, action dim)", actions.shape));
    };
    if b != batch || d != action_dim || t == 0 {
        return Err(format!("actions of shape ({b}, {t}, {d}), expected ({batch}, steps >= 1, {action_dim})"));
    }
    let values = actions.to_f32()?;
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "a non-finite action value ({}) at episode {}, step {}",
            values[i],
            i / (t * d),
            (i / d) % t
        ));
    }
    Ok(values
        .chunks_exact(t * d)
        .map(|episode| episode.chunks_exact(d).map(|a| <[f32; D]>::try_from(a).expect("d == D")).collect())
        .collect())
}

/// Hosts started by [`resolve_identity`], waiting for the run's first worker to take them.
static PARKED: Mutex<Vec<PythonHostModel>> = Mutex::new(Vec::new());

/// Stop the hosts [`resolve_identity`] left for replicas this process will not run (the parent of
/// `pipeline run --processes`, whose episodes run in other processes): each holds its model.
pub fn release_parked_hosts() {
    if let Ok(mut parked) = PARKED.lock() {
        parked.clear();
    }
}

/// Starts one host to read the policy's description for the run manifest (before any episode:
/// a policy that cannot load stops the run here), and leaves it for the run's replica on that
/// device.
pub fn resolve_identity(config: &PythonHostConfig, device: Option<ModelDevice>) -> Result<Value, String> {
    let model = PythonHostModel::start(config, device)?;
    let mut identity = model.description.identity.clone();
    identity["interpreter_given"] = json!(model.command.interpreter.display().to_string());
    identity["host"] = json!({
        "protocol": PROTOCOL,
        "script_sha256": format!("{:x}", Sha256::digest(HOST_SCRIPT)),
        "adapter_sha256": format!("{:x}", Sha256::digest(LEROBOT_ADAPTER)),
        "call_timeout_s": config.call_timeout.as_secs(),
    });
    PARKED.lock().map_err(|_| "the parked hosts' lock is poisoned".to_string())?.push(model);
    Ok(identity)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ready(describe: Value) -> Frame {
        Frame::new(json!({"op": "ready", "protocol": PROTOCOL, "describe": describe}))
    }

    #[test]
    fn a_description_names_the_cameras_its_benchmark_renders() {
        // ALOHA-sim's top camera has its own size: no camera_size needed
        let aloha = ready(json!({"observation": {"cameras": ["top"]}, "action_dim": 14, "executed_steps": 10}));
        let d = Description::from_ready(&aloha, "aloha_sim").unwrap();
        assert!(d.top && !d.wrist && d.camera_size.is_none());
        assert_eq!(d.executed_steps, 10);
        assert!(Description::from_ready(&aloha, "libero").unwrap_err().contains("names \"top\", and libero renders"));
        let libero = ready(json!({"observation": {"cameras": ["agentview", "wrist"], "camera_size": 360}}));
        let d = Description::from_ready(&libero, "libero").unwrap();
        assert_eq!((d.camera_size, d.wrist, d.top), (Some(360), true, false));
        assert!(Description::from_ready(&libero, "aloha_sim").unwrap_err().contains("names \"agentview\""));
        let unsized_ = ready(json!({"observation": {"cameras": ["agentview"]}}));
        assert!(Description::from_ready(&unsized_, "libero").unwrap_err().contains("camera_size"));
        let seven = ready(json!({"observation": {"cameras": ["top"]}, "action_dim": 7}));
        assert!(
            Description::from_ready(&seven, "aloha_sim").unwrap_err().contains("7-D, and this benchmark takes 14-D")
        );
    }
}
