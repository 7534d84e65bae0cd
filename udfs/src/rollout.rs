//! The `rollout` UDF: spec rows in, episodes run, Parquet parts out.
//!
//! `rollout(suite, task_id, init_state_id, seed [, extras])` runs the episode of every row of the
//! batch in parallel across cores (rayon; one `LiberoEnv` per worker thread, reused while the
//! worker stays on the same task), writes its steps part and then its episode part to the run
//! store, and returns `{episode_key, success, n_policy_steps, error_kind}` per row. `extras` is an
//! optional struct of the spec's other columns, appended to the episode row ("carried through").
//!
//! An episode that fails (unstable physics, a bad action, a policy error, even a panic) becomes an
//! episode row with `error_kind`/`error` set and the run goes on; only a storage failure stops
//! the query, since nothing could be recorded.

use crate::aloha_episode::{AlohaWorker, run_aloha_episode};
use crate::episode::{EpisodeContext, EpisodeError, EpisodeProtocol, EpisodeSummary, episode_batch, run_episode};
use crate::perturbation::EpisodePerturbation;
use crate::policy_cameras::PolicyCameras;
use crate::run_store::{RunStore, parquet_bytes};
use crate::steps_batch::EpisodeKey;
use arrow::array::{Array, ArrayRef, AsArray, BooleanArray, Int32Array, RecordBatch, StringArray, StructArray};
use arrow::datatypes::{DataType, Field, Fields, Int32Type, Int64Type};
use datafusion::common::{Result, exec_err, plan_err};
use datafusion::logical_expr::{ColumnarValue, ScalarFunctionArgs, ScalarUDF, ScalarUDFImpl, Signature, Volatility};
use indicatif::ProgressBar;
use libero_policies::PolicySpec;
use libero_schema::{Benchmark, Suite};
use libero_sim::SimError;
use libero_sim::aloha::{AlohaBundle, AlohaTask};
use libero_sim::bundle::{BundleSet, TaskBundle};
use libero_sim::env::LiberoEnv;
use mujoco_rs::prelude::MjModel;
use rayon::prelude::*;
use sha2::{Digest, Sha256};
use std::cell::RefCell;
use std::collections::{BTreeMap, HashMap};
use std::hash::{Hash, Hasher};
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, Weak};

/// Everything a rollout needs besides the spec rows.
pub struct RolloutContext {
    pub bundles: Arc<BundleSet>,
    pub policy: PolicySpec,
    /// The policy as the run names it in `episodes.policy`: `policy`'s own text, except in a
    /// process of `pipeline run --processes`, whose `policy` holds only its share of the devices
    /// while its episodes belong to the run's policy ([`RolloutContext::with_policy_label`]).
    policy_label: String,
    pub protocol: RunProtocol,
    pub run_config: String,
    /// The manifest as JSON, stored in every part's key-value metadata.
    pub manifest_json: String,
    pub store: RunStore,
    /// Runtime for the store's async writes (rayon workers are not runtime threads).
    pub runtime: tokio::runtime::Handle,
    pub progress: ProgressBar,
    /// Return an episode whose part the store already holds instead of running it again (set by
    /// distributed runs, whose engine may run a task twice: a retry, a lost executor's tasks).
    skip_stored_episodes: bool,
    /// Sleep this long before each episode: only for tests that must kill a worker mid-run.
    episode_delay: std::time::Duration,
    successes: AtomicU64,
    finished: AtomicU64,
    tasks: TaskCache,
    /// The ALOHA-sim bundle, for a run of that benchmark (its spec rows' suite is `aloha_sim`).
    aloha: Option<Arc<AlohaBundle>>,
}

/// The protocol settings of a run: what every episode's [`EpisodeProtocol`] is made from.
#[derive(Debug, Clone)]
pub struct RunProtocol {
    /// Episode cap in policy steps per suite (a suite not listed gets its protocol's cap).
    pub max_steps: BTreeMap<Suite, u32>,
    /// ALOHA-sim's episode cap (lerobot's 400 by default; gym-aloha's registration says 300).
    pub aloha_max_steps: u32,
    pub num_steps_wait: u32,
    pub stop_on_success: bool,
    pub instruction_source: libero_schema::InstructionSource,
    /// Real-time evaluation (`--latency-ms`); None: the env waits for every answer.
    pub realtime: Option<libero_schema::real_time::RealTime>,
    /// Which published loop the LIBERO episodes reproduce (the spec column `protocol`).
    pub protocol: libero_schema::EvalProtocol,
}

impl RunProtocol {
    /// An ALOHA-sim episode's protocol: no wait steps, the run's ALOHA cap.
    pub fn aloha_episode(&self) -> EpisodeProtocol {
        EpisodeProtocol {
            max_steps: self.aloha_max_steps,
            num_steps_wait: 0,
            stop_on_success: self.stop_on_success,
            instruction_source: self.instruction_source,
            realtime: self.realtime,
            protocol: None,
        }
    }

    pub fn episode(&self, suite: Suite) -> EpisodeProtocol {
        EpisodeProtocol {
            max_steps: self.max_steps.get(&suite).copied().unwrap_or_else(|| self.protocol.max_steps(suite.base)),
            num_steps_wait: self.num_steps_wait,
            stop_on_success: self.stop_on_success,
            instruction_source: self.instruction_source,
            realtime: self.realtime,
            protocol: Some(self.protocol),
        }
    }
}

/// A task's bundle and its compiled model.
type CompiledTask = Arc<(TaskBundle, MjModel)>;
/// Filled once, by the first worker that needs the task; the others wait for it. Workers hold it
/// while they run the task's episodes.
type TaskSlot = Arc<OnceLock<Result<CompiledTask, SimError>>>;
/// A task's slot as the cache holds it: alive only while some worker holds the slot.
type WeakTaskSlot = Weak<OnceLock<Result<CompiledTask, SimError>>>;
/// A worker's env, kept while its episodes are of one task.
struct WorkerEnv {
    task: (Suite, u32),
    /// Keeps the compiled task alive for the other workers on it.
    _slot: TaskSlot,
    env: LiberoEnv,
    /// The policy cameras' renderer of this env, kept across the task's episodes: a renderer
    /// uploads the scene's meshes and textures when it is made (~500 ms on an H200, all workers'
    /// uploads queued on a shared GL thread), and nothing an episode changes in the model
    /// (`EpisodeEdits`: poses, lights, colours) is in what it uploaded.
    cameras: Option<PolicyCameras>,
}

/// Each task's bundle and compiled model, compiled once while workers need it and copied for each.
///
/// The cache holds tasks weakly: a task lives while a worker runs its episodes (the worker holds
/// its slot) and is dropped when the last one moves on. A compiled task with its decoded textures
/// is ~300 MB, so keeping every task of a run (40 canonical, 90 in libero_90, hundreds in the
/// perturbation suites) would grow with the run; this way memory is bounded by the tasks in
/// flight, at most one per worker. Runs are ordered by task and split into units of one task, so
/// a task is compiled about once per run, and at most once per worker that takes a unit of it.
#[derive(Default)]
struct TaskCache {
    slots: Mutex<HashMap<(Suite, u32), WeakTaskSlot>>,
    compiling: Mutex<()>,
    compiles: AtomicU64,
}

impl TaskCache {
    fn get(&self, bundles: &BundleSet, suite: Suite, task: u32) -> TaskSlot {
        let slot = {
            let mut slots = self.slots.lock().expect("task cache lock");
            slots.retain(|_, w| w.strong_count() > 0);
            match slots.get(&(suite, task)).and_then(Weak::upgrade) {
                Some(slot) => slot,
                None => {
                    let slot: TaskSlot = Arc::default();
                    slots.insert((suite, task), Arc::downgrade(&slot));
                    slot
                }
            }
        };
        slot.get_or_init(|| {
            // One compile at a time: MuJoCo's compiler peaks at ~4x the model it makes (a 330 MB
            // LIBERO model with its decoded textures passes 1.3 GB), so two concurrent compiles
            // alone would pass the 3 GB a run of any size stays within. A compile takes ~2 s, a
            // task's episodes minutes: the wait costs little.
            let _one_at_a_time = self.compiling.lock().unwrap_or_else(|e| e.into_inner());
            self.compiles.fetch_add(1, Ordering::Relaxed);
            let compiled = bundles.load(suite, task).and_then(|bundle| {
                let model = libero_sim::scene::compile(&bundle)?;
                Ok(Arc::new((bundle, model)))
            });
            clear_mujoco_asset_cache();
            release_freed_memory();
            compiled
        });
        slot
    }
}

/// MuJoCo 3.x keeps decoded assets of past compiles in a global cache of up to 500 MB, so a
/// later compile of the same textures is faster. A run compiles each task about once, and a
/// LIBERO scene's textures alone are ~200 MB: the cache would hold 500 MB of a run's memory for
/// little, so it is emptied after each compile. (A capacity of 0, which should turn it off,
/// crashes MuJoCo 3.3.7's compiler.) Compiled models are the same with or without it.
fn clear_mujoco_asset_cache() {
    // SAFETY: mj_getCache returns MuJoCo's global cache; clearing it is thread-safe, and it is
    // done under the compile lock, so no compile is reading it.
    unsafe {
        mujoco_rs::mujoco_c::mj_clearCache(mujoco_rs::mujoco_c::mj_getCache());
    }
}

/// Give the memory malloc holds free back to the system. The compiler's many transient
/// allocations come from the heap, which glibc does not shrink on its own: without this, a run's
/// resident set keeps every compile's peak.
pub fn release_freed_memory() {
    // SAFETY: malloc_trim only releases free memory of the allocator; it is thread-safe.
    unsafe {
        libc::malloc_trim(0);
    }
}

impl RolloutContext {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        bundles: Arc<BundleSet>,
        policy: PolicySpec,
        protocol: RunProtocol,
        run_config: String,
        manifest_json: String,
        store: RunStore,
        runtime: tokio::runtime::Handle,
        progress: ProgressBar,
    ) -> Self {
        RolloutContext {
            bundles,
            policy_label: policy.name(),
            policy,
            protocol,
            run_config,
            manifest_json,
            store,
            runtime,
            progress,
            skip_stored_episodes: false,
            episode_delay: std::time::Duration::ZERO,
            successes: AtomicU64::new(0),
            finished: AtomicU64::new(0),
            tasks: TaskCache::default(),
            aloha: None,
        }
    }

    /// Run ALOHA-sim's spec rows (suite `aloha_sim`) on this bundle.
    pub fn with_aloha(mut self, bundle: Arc<AlohaBundle>) -> Self {
        self.aloha = Some(bundle);
        self
    }

    /// Return the stored outcome of an episode whose part exists instead of running it again, so
    /// that an engine's re-execution of a task (a retry, a lost executor's tasks) neither repeats
    /// nor overwrites an episode.
    pub fn skipping_stored_episodes(mut self) -> Self {
        self.skip_stored_episodes = true;
        self
    }

    /// Store `label` as the episodes' policy (the run's, where `policy` is one process's share).
    pub fn with_policy_label(mut self, label: String) -> Self {
        self.policy_label = label;
        self
    }

    /// Sleep before each episode (tests that kill a worker while episodes are in flight).
    pub fn with_episode_delay(mut self, delay: std::time::Duration) -> Self {
        self.episode_delay = delay;
        self
    }

    /// How many times a task's model was compiled in this run (about once per task; at most once
    /// per worker and task).
    pub fn task_compiles(&self) -> u64 {
        self.tasks.compiles.load(Ordering::Relaxed)
    }
}

/// The fields of the struct `rollout(...)` returns per row.
pub fn rollout_result_fields() -> Fields {
    Fields::from(vec![
        Field::new("episode_key", DataType::Utf8, false),
        Field::new("success", DataType::Boolean, false),
        Field::new("n_policy_steps", DataType::Int32, false),
        Field::new("error_kind", DataType::Utf8, true),
    ])
}

#[derive(Debug)]
pub struct RolloutUdf {
    source: RunSource,
    signature: Signature,
}

/// Finds the run a `rollout` call belongs to from the session configuration it runs under: on a
/// distributed engine's worker the UDF is registered once per process, before any run exists, and
/// each task carries its run's settings as configuration keys.
pub trait RunResolver: Send + Sync + std::fmt::Debug {
    fn resolve(&self, config: &datafusion::config::ConfigOptions) -> Result<Arc<RolloutContext>>;
}

/// Where a `rollout` UDF's run comes from.
#[derive(Debug, Clone)]
enum RunSource {
    /// One run, known when the UDF is made (the local engine).
    Fixed(Arc<RolloutContext>),
    /// The run named by each call's configuration (a distributed engine's worker or planner).
    Resolved(Arc<dyn RunResolver>),
}

impl std::fmt::Debug for RolloutContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RolloutContext").field("policy", &self.policy).field("run_config", &self.run_config).finish()
    }
}

impl PartialEq for RolloutUdf {
    fn eq(&self, other: &Self) -> bool {
        match (&self.source, &other.source) {
            (RunSource::Fixed(a), RunSource::Fixed(b)) => Arc::ptr_eq(a, b),
            (RunSource::Resolved(a), RunSource::Resolved(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}
impl Eq for RolloutUdf {}
impl Hash for RolloutUdf {
    fn hash<H: Hasher>(&self, state: &mut H) {
        match &self.source {
            RunSource::Fixed(ctx) => ctx.run_config.hash(state),
            RunSource::Resolved(_) => "resolved".hash(state),
        }
    }
}

impl RolloutUdf {
    pub fn new(ctx: Arc<RolloutContext>) -> Self {
        Self::with_source(RunSource::Fixed(ctx))
    }

    fn with_source(source: RunSource) -> Self {
        // Volatile: never constant-folded or de-duplicated; every call runs episodes.
        RolloutUdf { source, signature: Signature::user_defined(Volatility::Volatile) }
    }
}

pub fn rollout_udf(ctx: Arc<RolloutContext>) -> ScalarUDF {
    ScalarUDF::from(RolloutUdf::new(ctx))
}

/// A `rollout` whose run each call's configuration names (see [`RunResolver`]).
pub fn resolved_rollout_udf(resolver: Arc<dyn RunResolver>) -> ScalarUDF {
    ScalarUDF::from(RolloutUdf::with_source(RunSource::Resolved(resolver)))
}

impl ScalarUDFImpl for RolloutUdf {
    fn name(&self) -> &str {
        "rollout"
    }
    fn signature(&self) -> &Signature {
        &self.signature
    }
    fn return_type(&self, _arg_types: &[DataType]) -> Result<DataType> {
        Ok(DataType::Struct(rollout_result_fields()))
    }
    fn coerce_types(&self, arg_types: &[DataType]) -> Result<Vec<DataType>> {
        let ok = |t: &DataType| t.is_integer();
        match arg_types {
            [s, t, i, e, rest @ ..] if ok(t) && ok(i) && ok(e) && rest.len() <= 1 => {
                let mut v = vec![DataType::Utf8, DataType::Int32, DataType::Int32, DataType::Int64];
                if !matches!(s, DataType::Utf8 | DataType::LargeUtf8 | DataType::Utf8View) {
                    return plan_err!("rollout(): suite must be a string, got {s}");
                }
                match rest.first() {
                    Some(x @ DataType::Struct(_)) => v.push(x.clone()),
                    Some(x) => {
                        return plan_err!("rollout(): the 5th argument (extras) must be a struct, got {x}");
                    }
                    None => {}
                }
                Ok(v)
            }
            _ => plan_err!("rollout(suite, task_id, init_state_id, seed [, extras struct]) got {arg_types:?}"),
        }
    }
    fn invoke_with_args(&self, args: ScalarFunctionArgs) -> Result<ColumnarValue> {
        let ctx = match &self.source {
            RunSource::Fixed(ctx) => ctx.clone(),
            RunSource::Resolved(resolver) => resolver.resolve(&args.config_options)?,
        };
        let ctx = ctx.as_ref();
        let arrays = ColumnarValue::values_to_arrays(&args.args)?;
        let suites = arrays[0].as_string::<i32>();
        let tasks = arrays[1].as_primitive::<Int32Type>();
        let inits = arrays[2].as_primitive::<Int32Type>();
        let seeds = arrays[3].as_primitive::<Int64Type>();
        let extras: Option<RecordBatch> = arrays.get(4).map(|a| RecordBatch::from(a.as_struct()));
        let n = suites.len();
        let mut perturbations = Vec::with_capacity(n);
        for i in 0..n {
            if suites.is_null(i) || tasks.is_null(i) || inits.is_null(i) || seeds.is_null(i) {
                return exec_err!("rollout(): row {i} has a null key column");
            }
            let p = match &extras {
                Some(x) => EpisodePerturbation::from_row(x, i),
                None => Ok(EpisodePerturbation::default()),
            };
            match p {
                Ok(p) => perturbations.push(p),
                Err(e) => return exec_err!("rollout(): row {i}: {e}"),
            }
        }
        // Work units: runs of consecutive rows of one task, split so every core gets work. A unit
        // runs on one worker, which keeps its env (and its touched MuJoCo arena) across the unit.
        let unit_cap = n.div_ceil(2 * rayon::current_num_threads()).max(1);
        let mut units: Vec<std::ops::Range<usize>> = vec![];
        for i in 0..n {
            match units.last_mut() {
                Some(u)
                    if u.len() < unit_cap
                        && suites.value(u.start) == suites.value(i)
                        && tasks.value(u.start) == tasks.value(i) =>
                {
                    u.end = i + 1
                }
                _ => units.push(i..i + 1),
            }
        }
        // Inside `rayon::scope` so that even a single unit runs on a rayon worker: a parallel
        // iterator runs an unsplit item on the calling thread, here a tokio worker, where the
        // store's `block_on` would panic.
        let results: Vec<anyhow::Result<RowResult>> = rayon::scope(|_| {
            units
                .into_par_iter()
                .flat_map_iter(|unit| {
                    unit.map(|i| {
                        let p = &perturbations[i];
                        let variant = p.variant();
                        let key = EpisodeKey::with_variant(
                            suites.value(i),
                            tasks.value(i),
                            inits.value(i),
                            seeds.value(i),
                            variant.as_deref(),
                        );
                        let extras = extras.as_ref().map(|x| x.slice(i, 1));
                        run_row(ctx, &key, p, extras.as_ref())
                    })
                    .collect::<Vec<_>>()
                })
                .collect()
        });
        let mut keys = Vec::with_capacity(n);
        let mut success = Vec::with_capacity(n);
        let mut steps = Vec::with_capacity(n);
        let mut kinds = Vec::with_capacity(n);
        for r in results {
            let (k, s, t, e) = r.map_err(|e| datafusion::error::DataFusionError::External(e.into()))?;
            keys.push(k);
            success.push(s);
            steps.push(t);
            kinds.push(e);
        }
        let columns: Vec<ArrayRef> = vec![
            Arc::new(StringArray::from(keys)),
            Arc::new(BooleanArray::from(success)),
            Arc::new(Int32Array::from(steps)),
            Arc::new(StringArray::from(kinds)),
        ];
        Ok(ColumnarValue::Array(Arc::new(StructArray::try_new(rollout_result_fields(), columns, None)?)))
    }
}

/// What `rollout` returns for one row: episode key, success, policy steps, error kind.
type RowResult = (String, bool, i32, Option<String>);

thread_local! {
    /// The worker's env, kept while consecutive episodes are of the same task, with the task's
    /// cache slot (which keeps the compiled task alive for the other workers on it).
    static WORKER_ENV: RefCell<Option<WorkerEnv>> = const { RefCell::new(None) };
}

/// Seed of the policy's randomness for an episode: a stable hash of the episode key, so reruns
/// and resumed runs reproduce the same actions.
pub fn policy_seed(key: &EpisodeKey) -> u64 {
    let h = Sha256::digest(key.episode_key.as_bytes());
    u64::from_le_bytes(h[..8].try_into().expect("8 bytes"))
}

/// Run one spec row's episode and store its parts (or, when the context skips stored episodes and
/// its part exists, return what the part holds).
fn run_row(
    ctx: &RolloutContext,
    key: &EpisodeKey,
    perturbation: &EpisodePerturbation,
    extras: Option<&RecordBatch>,
) -> anyhow::Result<RowResult> {
    let name = key.part_name();
    if ctx.skip_stored_episodes
        && let Some(part) = ctx.runtime.block_on(ctx.store.get(&format!("episodes/{name}")))?
    {
        ctx.progress.inc(1);
        return stored_outcome(key, part);
    }
    if !ctx.episode_delay.is_zero() {
        std::thread::sleep(ctx.episode_delay);
    }
    let (steps, summary, protocol) = match Benchmark::of_suite(&key.suite) {
        Benchmark::Libero => {
            let suite: Suite = key.suite.parse().map_err(anyhow::Error::msg)?;
            let protocol = ctx.protocol.episode(suite);
            let (steps, summary) = run_libero(ctx, key, perturbation, suite, &protocol);
            (steps, summary, protocol)
        }
        Benchmark::AlohaSim => {
            let protocol = ctx.protocol.aloha_episode();
            let (steps, summary) = run_aloha(ctx, key, &protocol);
            (steps, summary, protocol)
        }
    };
    let steps = steps?;
    let params = perturbation.canonical();
    let ectx = EpisodeContext {
        policy: &ctx.policy_label,
        perturbation_params: params.as_deref(),
        run_config: &ctx.run_config,
        protocol: &protocol,
    };
    let episode = episode_batch(key, &summary, &ectx, extras)?;
    let steps_bytes = parquet_bytes(&steps, Some(&ctx.manifest_json))?;
    let episode_bytes = parquet_bytes(&episode, Some(&ctx.manifest_json))?;
    ctx.runtime.block_on(async {
        ctx.store.put(&format!("steps/{name}"), steps_bytes).await?;
        ctx.store.put(&format!("episodes/{name}"), episode_bytes).await
    })?;
    let finished = ctx.finished.fetch_add(1, Ordering::Relaxed) + 1;
    let successes = ctx.successes.fetch_add(summary.success() as u64, Ordering::Relaxed) + summary.success() as u64;
    ctx.progress.set_message(format!("success {successes}/{finished}"));
    ctx.progress.inc(1);
    Ok((
        key.episode_key.clone(),
        summary.success(),
        summary.n_policy_steps as i32,
        summary.error.as_ref().map(|e| e.kind.to_string()),
    ))
}

/// One LIBERO episode on the worker's env (kept while the worker stays on the task), caught if
/// it panics: its steps and summary.
fn run_libero(
    ctx: &RolloutContext,
    key: &EpisodeKey,
    perturbation: &EpisodePerturbation,
    suite: Suite,
    protocol: &EpisodeProtocol,
) -> (arrow::error::Result<RecordBatch>, EpisodeSummary) {
    let run = || -> (arrow::error::Result<RecordBatch>, EpisodeSummary) {
        WORKER_ENV.with(|cell| {
            let mut cached = cell.borrow_mut();
            let task = (suite, key.task_id as u32);
            if cached.as_ref().is_none_or(|w| w.task != task) {
                if cached.take().is_some() {
                    release_freed_memory();
                }
                let slot = ctx.tasks.get(&ctx.bundles, suite, task.1);
                let env = slot.get().expect("filled by get").clone().and_then(|bm| {
                    let model = bm.1.clone().ok_or_else(|| SimError::Other("mj_copyModel failed".into()))?;
                    LiberoEnv::with_model(&bm.0, model)
                });
                match env {
                    Ok(env) => *cached = Some(WorkerEnv { task, _slot: slot, env, cameras: None }),
                    Err(e) => {
                        let instruction = ctx
                            .bundles
                            .entry(suite, task.1)
                            .map(|t| t.instructions.given(protocol.instruction_source, suite.perturbation.is_some()))
                            .map(|(text, source)| (text.to_string(), source))
                            .unwrap_or_default();
                        let s = EpisodeSummary::failed_to_start(instruction, EpisodeError::from_sim(&e));
                        return (Ok(RecordBatch::new_empty(libero_schema::tables::steps())), s);
                    }
                }
            }
            let WorkerEnv { env, cameras, .. } = cached.as_mut().expect("env just cached");
            let mut policy = match ctx.policy.instantiate() {
                Ok(p) => p,
                Err(e) => {
                    let (text, source) = env.bundle().task.instruction(protocol.instruction_source);
                    let s = EpisodeSummary::failed_to_start(
                        (text.to_string(), source),
                        EpisodeError { kind: "policy", message: e.to_string() },
                    );
                    return (Ok(RecordBatch::new_empty(libero_schema::tables::steps())), s);
                }
            };
            let (steps, summary) =
                run_episode(env, cameras, policy.as_mut(), key, protocol, perturbation, policy_seed(key));
            policy.end_episode();
            if summary.error.is_some() {
                // a failed render may leave its renderer in any state: the next episode makes its own
                *cameras = None;
            }
            (steps.finish(), summary)
        })
    };
    match std::panic::catch_unwind(AssertUnwindSafe(run)) {
        Ok(r) => r,
        Err(panic) => {
            // The cached env may be mid-step; drop it.
            WORKER_ENV.with(|c| c.borrow_mut().take());
            let msg = panic_message(panic.as_ref());
            let s =
                EpisodeSummary::failed_to_start((String::new(), ""), EpisodeError { kind: "internal", message: msg });
            (Ok(RecordBatch::new_empty(libero_schema::tables::steps())), s)
        }
    }
}

thread_local! {
    /// The worker's ALOHA-sim env, kept while consecutive episodes are of the same task.
    static ALOHA_WORKER: RefCell<Option<AlohaWorker>> = const { RefCell::new(None) };
}

/// One ALOHA-sim episode on the worker's env, caught if it panics: its steps and summary.
fn run_aloha(
    ctx: &RolloutContext,
    key: &EpisodeKey,
    protocol: &EpisodeProtocol,
) -> (arrow::error::Result<RecordBatch>, EpisodeSummary) {
    let empty = || RecordBatch::new_empty(libero_schema::tables::aloha_steps());
    let task = AlohaTask::from_id(key.task_id as i64);
    let instruction = task.map(|t| t.instruction().to_string()).unwrap_or_default();
    let failed = |kind: &'static str, message: String| {
        (Ok(empty()), EpisodeSummary::failed_to_start((instruction.clone(), "task"), EpisodeError { kind, message }))
    };
    // the spec validation refuses both before a run starts
    let (Some(bundle), Some(task)) = (ctx.aloha.as_ref(), task) else {
        return failed(
            "bundle",
            format!("{}: no ALOHA-sim bundle in this run, or no task {}", key.episode_key, key.task_id),
        );
    };
    let run = || {
        ALOHA_WORKER.with(|cell| {
            let mut cached = cell.borrow_mut();
            if cached.as_ref().is_none_or(|w| w.task != task) {
                match AlohaWorker::new(bundle, task) {
                    Ok(w) => *cached = Some(w),
                    Err(e) => return failed("bundle", e.to_string()),
                }
            }
            let worker = cached.as_mut().expect("worker just cached");
            let mut policy = match ctx.policy.instantiate_aloha() {
                Ok(p) => p,
                Err(e) => return failed("policy", e.to_string()),
            };
            run_aloha_episode(worker, bundle, policy.as_mut(), key, protocol, policy_seed(key))
        })
    };
    match std::panic::catch_unwind(AssertUnwindSafe(run)) {
        Ok(r) => r,
        Err(panic) => {
            ALOHA_WORKER.with(|c| c.borrow_mut().take());
            let msg = panic_message(panic.as_ref());
            failed("internal", msg)
        }
    }
}

/// The text of a caught panic (an episode's `internal` error).
fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "panic".into())
}

/// What `rollout` returns for an episode whose part is stored: read from the part.
fn stored_outcome(key: &EpisodeKey, part: bytes::Bytes) -> anyhow::Result<RowResult> {
    use anyhow::Context;
    let batches: Vec<RecordBatch> = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(part)?
        .build()?
        .collect::<std::result::Result<_, _>>()?;
    let row = batches.iter().find(|b| b.num_rows() > 0).context("an empty episode part")?;
    let column = |name: &str| row.column_by_name(name).with_context(|| format!("episode part without {name}"));
    let success = column("success")?.as_boolean().value(0);
    let steps = column("n_policy_steps")?.as_primitive::<Int32Type>().value(0);
    let kind = column("error_kind")?;
    let kind = (!kind.is_null(0)).then(|| kind.as_string::<i32>().value(0).to_string());
    Ok((key.episode_key.clone(), success, steps, kind))
}
