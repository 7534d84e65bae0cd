//! `pipeline executor`: Ballista's executor with our functions. Its `rollout` finds each task's
//! run from the task's `libero.*` keys ([`ExecutorRuns`]) and runs the episodes on this machine,
//! with this machine's bundles, writing their parts to the run location.

use super::run_config::{LiberoRun, config_producer, runtime_env, session_state};
use anyhow::{Context, Result};
use ballista_core::registry::BallistaFunctionRegistry;
use ballista_executor::executor_process::{ExecutorProcessConfig, start_executor_process};
use datafusion::common::{DataFusionError, Result as DfResult};
use datafusion::config::ConfigOptions;
use indicatif::ProgressBar;
use libero_policies::PolicySpec;
use libero_schema::{RunManifest, Suite};
use libero_sim::bundle::BundleSet;
use libero_udfs::rollout::{RolloutContext, RunProtocol, RunResolver};
use libero_udfs::run_store::RunStore;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;
use std::sync::{Arc, Mutex};

pub const EXAMPLES: &str = "\
Examples:
  pipeline executor --scheduler 127.0.0.1:50050              # beside a scheduler on this machine
  pipeline executor --scheduler SCHED:50050 --bind 0.0.0.0 --external-host $(hostname) --vcores 16";

#[derive(clap::Args)]
pub struct Args {
    /// The scheduler, HOST:PORT (`pipeline scheduler`).
    #[arg(long, default_value = "127.0.0.1:50050")]
    scheduler: String,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    bind: String,
    /// The host name other nodes reach this executor by (default: the --bind address).
    #[arg(long)]
    external_host: Option<String>,
    /// Port of the executor's data (Arrow Flight) service.
    #[arg(long, default_value_t = 50051)]
    port: u16,
    /// Port of the executor's gRPC service.
    #[arg(long, default_value_t = 50052)]
    grpc_port: u16,
    /// Tasks run at once (one episode each by default): default one per core.
    #[arg(long)]
    vcores: Option<usize>,
    /// Seconds between heartbeats to the scheduler.
    #[arg(long, default_value_t = 10)]
    heartbeat_s: u64,
    /// Folder for the executor's intermediate query data (default: a temporary folder).
    #[arg(long)]
    work_dir: Option<String>,
}

pub fn run(bundles: &Path, args: Args) -> Result<()> {
    let (scheduler_host, scheduler_port) = args
        .scheduler
        .rsplit_once(':')
        .and_then(|(h, p)| Some((h.to_string(), p.parse::<u16>().ok()?)))
        .with_context(|| format!("--scheduler {}: use HOST:PORT", args.scheduler))?;
    let runs = Arc::new(ExecutorRuns::new(bundles)?);
    let registry = BallistaFunctionRegistry::from(&session_state(config_producer(), runs.clone())?);
    let vcores = args.vcores.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let config = ExecutorProcessConfig {
        bind_host: args.bind.clone(),
        external_host: args.external_host.clone(),
        port: args.port,
        grpc_port: args.grpc_port,
        scheduler_host,
        scheduler_port,
        scheduler_connect_timeout_seconds: 10,
        vcores,
        work_dir: args.work_dir.clone(),
        executor_heartbeat_interval_seconds: args.heartbeat_s,
        override_function_registry: Some(Arc::new(registry)),
        override_config_producer: Some(Arc::new(config_producer)),
        override_runtime_producer: Some(Arc::new(|_config: &datafusion::prelude::SessionConfig| runtime_env())),
        ..Default::default()
    };
    eprintln!(
        "pipeline executor {} on {}:{} ({vcores} slots, bundles {}) for the scheduler {}",
        std::process::id(),
        args.bind,
        args.port,
        runs.bundles.root().display(),
        args.scheduler
    );
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async { start_executor_process(Arc::new(config)).await.context("the executor stopped") })
}

/// The runs this executor has run episodes of, each checked once against this executor's build,
/// MuJoCo and bundles; a run that does not match is refused, with what differs.
#[derive(Debug)]
pub struct ExecutorRuns {
    bundles: Arc<BundleSet>,
    /// The store writes' runtime: the task threads that call `rollout` are busy running episodes,
    /// so the writes get threads of their own.
    io: tokio::runtime::Runtime,
    runs: Mutex<HashMap<(String, String), Arc<RolloutContext>>>,
}

impl ExecutorRuns {
    pub fn new(bundles: &Path) -> Result<Self> {
        let bundles = Arc::new(BundleSet::open(bundles)?);
        let io = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
        Ok(ExecutorRuns { bundles, io, runs: Mutex::default() })
    }

    fn open(&self, run: &LiberoRun) -> Result<RolloutContext> {
        let manifest: RunManifest =
            serde_json::from_str(&run.manifest).context("libero.manifest is not a run manifest")?;
        let tasks: BTreeSet<(Suite, u32)> = run
            .tasks
            .split(',')
            .filter(|t| !t.is_empty())
            .map(|t| {
                let (suite, task) = t.rsplit_once('/').context("libero.tasks: suite/task_id")?;
                Ok((suite.parse().map_err(anyhow::Error::msg)?, task.parse()?))
            })
            .collect::<Result<_>>()?;
        check_same_build(&manifest, &self.bundles, &tasks)?;
        let policy: PolicySpec = manifest.policy.parse().map_err(anyhow::Error::msg)?;
        let identity = policy.resolve_identity(libero_schema::Benchmark::Libero)?; // ALOHA-sim runs are local only
        if identity != manifest.policy_identity {
            anyhow::bail!(
                "the policy {} here is not the run's: its identity here is {identity}, the run's manifest says {}. Give every executor the same checkpoint (or server) as the client.",
                manifest.policy,
                manifest.policy_identity
            );
        }
        let max_steps: BTreeMap<Suite, u32> = manifest
            .max_steps
            .iter()
            .map(|(s, n)| Ok((s.parse().map_err(anyhow::Error::msg)?, *n as u32)))
            .collect::<Result<_>>()?;
        let protocol = RunProtocol {
            max_steps,
            // a distributed run is LIBERO's (`pipeline run` refuses ALOHA-sim on a cluster)
            aloha_max_steps: libero_schema::benchmark::aloha::LEROBOT_MAX_STEPS,
            num_steps_wait: manifest.num_steps_wait as u32,
            stop_on_success: manifest.stop_on_success,
            instruction_source: manifest.instruction_source,
            realtime: manifest.realtime,
            protocol: manifest.protocol,
        };
        let store = self.io.block_on(RunStore::connect(&run.location))?;
        Ok(RolloutContext::new(
            self.bundles.clone(),
            policy,
            protocol,
            manifest.run_config.clone(),
            run.manifest.clone(),
            store,
            self.io.handle().clone(),
            ProgressBar::hidden(),
        )
        .skipping_stored_episodes()
        .with_episode_delay(std::time::Duration::from_millis(run.episode_delay_ms)))
    }
}

impl RunResolver for ExecutorRuns {
    fn resolve(&self, config: &ConfigOptions) -> DfResult<Arc<RolloutContext>> {
        let run = config.extensions.get::<LiberoRun>().filter(|r| !r.location.is_empty()).ok_or_else(|| {
            DataFusionError::Execution(
                "rollout(): this task names no run (no libero.location key): submit runs with `pipeline run --engine ballista://...`, to a `pipeline scheduler`".into(),
            )
        })?;
        let key = (run.location.clone(), run.manifest.clone());
        let mut runs = self.runs.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(ctx) = runs.get(&key) {
            return Ok(ctx.clone());
        }
        // Not retryable (an Execution error fails the job at once, with this message): every
        // executor of the same build would refuse it the same way.
        // Off the task's thread, which is a runtime's: opening the store blocks on its runtime.
        let opened = std::thread::scope(|s| s.spawn(|| self.open(run)).join().expect("opening a run panicked"));
        let ctx = opened.map_err(|e| {
            DataFusionError::Execution(format!(
                "executor {} (pid {}) refuses the episodes of the run {}: {e:#}",
                libero_udfs::compaction::hostname(),
                std::process::id(),
                run.location
            ))
        })?;
        eprintln!("run {}: build, MuJoCo and bundles match its manifest; running its episodes", run.location);
        let ctx = Arc::new(ctx);
        runs.retain(|(location, _), _| location != &run.location);
        runs.insert(key, ctx.clone());
        Ok(ctx)
    }
}

/// A run's manifest against this process: the same build (git revision and version), MuJoCo,
/// bundle format, and the same bundles (hash and files) for the run's tasks.
fn check_same_build(manifest: &RunManifest, bundles: &BundleSet, tasks: &BTreeSet<(Suite, u32)>) -> Result<()> {
    let mut differences = vec![];
    let here = (env!("PIPELINE_GIT_REVISION"), env!("CARGO_PKG_VERSION"));
    if (manifest.git_revision.as_str(), manifest.pipeline_version.as_str()) != here {
        differences.push(format!(
            "build: pipeline {} at git {} here, the run's is {} at git {} (install the client's build on every executor)",
            here.1, here.0, manifest.pipeline_version, manifest.git_revision
        ));
    }
    let mujoco = libero_sim::mujoco_version();
    if manifest.mujoco_version != mujoco {
        differences.push(format!("MuJoCo {mujoco} here, the run's is {}", manifest.mujoco_version));
    }
    if manifest.bundle_format_version != libero_schema::bundle_format::BUNDLE_FORMAT_VERSION {
        differences.push(format!(
            "bundle format {} here, the run's is {}",
            libero_schema::bundle_format::BUNDLE_FORMAT_VERSION,
            manifest.bundle_format_version
        ));
    }
    let used: Vec<(String, i32)> = tasks.iter().map(|(s, t)| (s.name(), *t as i32)).collect();
    match crate::run::bundles_hash(bundles, used.iter().map(|(s, t)| (s.as_str(), *t)), manifest.protocol) {
        Ok(hash) if hash == manifest.bundles_hash => {
            libero_sim::bundle_integrity::verify_tasks(bundles, tasks)
                .map_err(|e| anyhow::anyhow!("the bundles here ({}) are damaged: {e}", bundles.root().display()))?;
        }
        Ok(hash) => differences.push(format!(
            "bundles {} here hash to {hash} for the run's {} tasks, the run's are {} (give every executor the client's bundles)",
            bundles.root().display(),
            tasks.len(),
            manifest.bundles_hash
        )),
        Err(e) => differences.push(format!("bundles {}: {e:#}", bundles.root().display())),
    }
    if differences.is_empty() {
        return Ok(());
    }
    anyhow::bail!("this executor differs from the run's manifest:\n  {}", differences.join("\n  "))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A manifest made here for libero_spatial task 0 passes; one naming another build, another
    /// MuJoCo or other bundles is refused with each difference named.
    #[test]
    fn a_manifest_of_another_build_mujoco_or_bundles_is_refused_with_what_differs() {
        let bundles = BundleSet::open(crate::bundles_location::resolve(None).unwrap()).unwrap();
        let suite: Suite = "libero_spatial".parse().unwrap();
        let tasks = BTreeSet::from([(suite, 0)]);
        let manifest = RunManifest {
            tables_version: libero_schema::tables::TABLES_VERSION,
            run_config: "0123456789abcdef".into(),
            created_at: "2026-11-25T00:00:00Z".into(),
            git_revision: env!("PIPELINE_GIT_REVISION").into(),
            pipeline_version: env!("CARGO_PKG_VERSION").into(),
            mujoco_version: libero_sim::mujoco_version(),
            bundle_format_version: libero_schema::bundle_format::BUNDLE_FORMAT_VERSION,
            bundles_hash: crate::run::bundles_hash(&bundles, [("libero_spatial", 0)], Default::default()).unwrap(),
            policy: "random".into(),
            policy_identity: serde_json::json!({}),
            num_steps_wait: 10,
            max_steps: BTreeMap::from([("libero_spatial".to_string(), 220)]),
            instruction_source: libero_schema::InstructionSource::Published,
            stop_on_success: false,
            substeps_per_step: 25,
            control_freq_hz: 20,
            env: libero_schema::Benchmark::Libero,
            realtime: None,
            protocol: Default::default(),
        };
        check_same_build(&manifest, &bundles, &tasks).unwrap();
        let other = RunManifest {
            git_revision: "0000000".into(),
            mujoco_version: "3.2.3".into(),
            bundles_hash: "feed".into(),
            ..manifest
        };
        let err = check_same_build(&other, &bundles, &tasks).unwrap_err().to_string();
        for what in ["build: pipeline", "at git 0000000", "MuJoCo 3.3.7 here, the run's is 3.2.3", "the run's are feed"]
        {
            assert!(err.contains(what), "{what:?} not in: {err}");
        }
    }
}
