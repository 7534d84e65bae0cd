//! One forward for several episodes: dynamic batching of the rollout workers' queries.
//!
//! The rollout runs episodes in parallel, one per worker thread, each calling its policy's `act`
//! synchronously. A model on a GPU wants those queries together: [`Batcher`] owns one
//! [`BatchModel`] on its own thread; every worker's [`BatchedPolicy`] sends its query and waits;
//! once a query has arrived the batcher waits for the other episodes in progress (up to
//! `max_batch`, and at most `max_wait` for a straggler), answers them with one `predict_batch`
//! call, and routes each chunk back to its worker.
//!
//! The batcher knows the episodes in progress from [`Policy::reset`] and [`Policy::end_episode`]:
//! a forward goes as soon as every one has sent its query, and the last episodes of a run never
//! wait for workers that have none. How long to wait for a straggler is a trade measured on the
//! H100 (`data/benchmarks/gpu-end-to-end-h100-2026-11-24`): with a short wait the workers split
//! into groups that alternate, one group's renders waiting on the GPU while the other's forward
//! runs; with a long one the forwards fill but all workers render at once, and 32 GL contexts
//! rendering together are slower still. The renderer, not the forward, is the next limit.
//!
//! With N workers the batch is up to N episodes, and an episode's actions are the same as with a
//! batch of one (a batch changes the arithmetic only where the model's kernels do).
//!
//! The batcher is the benchmark's: its types default to LIBERO's observation and 7-D action
//! ([`BatchedPolicy`]); ALOHA-sim's episodes share calls alike with its observation and 14-D
//! action ([`BatchedAlohaPolicy`]).
//!
//! Several devices: [`Replicas`] holds one batcher per model replica (one per GPU, say); each
//! episode is served by one replica from its start to its end, and each replica batches its own
//! share. An episode starts on the replica where (its episodes in progress + 1) × (its recent
//! forward's duration) is least: alike devices share the episodes evenly, and a slower one takes
//! fewer. Devices of one machine are not alike in a run: on two H100s the replica whose GPU also
//! did the process's renders took 218 ms per forward against the other's 168
//! (`data/benchmarks/gpu-two-h100-cudnn-last-2026-11-27`), and a box may mix cards. Split evenly,
//! two GPUs ran 1.75× one; weighted, the other GPU took 132–136 of 240 episodes and two ran 1.91×
//! and 1.88× (`data/benchmarks/gpu-two-h100-weighted-2026-11-28`). A forward's duration grows with
//! its batch, so the share settles instead of running away to the faster device. Forwards under a
//! millisecond count as one; a replica that has run none counts as the others' mean (all alike
//! before any forward). A forward that failed as a whole (it panicked, out of GPU memory say, or
//! answered every request with an error) counts as a second or more, up to a minute, so a failing
//! device is given fewer episodes and smaller batches instead of more, and is tried again once the
//! others hold enough.

use crate::aloha::{AlohaAction, AlohaObservation, AlohaPolicy};
use crate::chunking::ActionChunker;
use crate::{ActTiming, Action, Observation, Policy, PolicyError};
use std::any::Any;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// One worker's query, as the model receives it.
pub struct Request<O = Observation> {
    pub instruction: String,
    /// The episode's seed ([`Policy::reset`]): a model that samples (flow-matching noise) draws
    /// from it, so an episode's actions do not depend on the episodes sharing its forward.
    pub episode_seed: u64,
    pub obs: O,
    /// What the model's [`BatchModel::preparer`] made of `obs` on the asking worker's thread.
    pub prepared: Option<Box<dyn Any + Send>>,
}

/// A model's host-side preparation of one query (image preprocessing), run by the asking worker.
pub type Preparer<O = Observation> = Arc<dyn Fn(&O) -> Result<Box<dyn Any + Send>, String> + Send + Sync>;

/// One forward over the requests whose worker prepared their inputs (a `P`, made by the model's
/// [`BatchModel::preparer`]), answered in the requests' order. A request without them fails alone
/// and the rest share the forward; a forward that fails fails each of them with its error.
/// `query` makes a request's input to the forward from its `P` and instruction; `answer` makes an
/// episode's actions from its prediction.
pub fn forward_prepared<'a, P: 'static, O, Q, R, A>(
    requests: &'a [Request<O>],
    query: impl Fn(&'a P, &'a str) -> Q,
    forward: impl FnOnce(&[Q]) -> Result<Vec<R>, String>,
    answer: impl Fn(R) -> Result<Vec<A>, String>,
) -> Vec<Result<Vec<A>, String>> {
    let prepared: Vec<Result<&'a P, String>> = requests
        .iter()
        .map(|r| {
            r.prepared
                .as_ref()
                .and_then(|p| p.downcast_ref::<P>())
                .ok_or_else(|| "the worker sent no prepared inputs".to_string())
        })
        .collect();
    let ready: Vec<Q> =
        prepared.iter().zip(requests).filter_map(|(p, r)| p.as_ref().ok().map(|p| query(p, &r.instruction))).collect();
    let mut predictions = match forward(&ready) {
        Ok(p) => p.into_iter(),
        Err(e) => return prepared.into_iter().map(|p| Err(p.err().unwrap_or_else(|| e.clone()))).collect(),
    };
    prepared
        .into_iter()
        .map(|p| {
            p?;
            answer(predictions.next().ok_or_else(|| "the batch returned too few predictions".to_string())?)
        })
        .collect()
}

/// A model that predicts an action chunk for each of several (instruction, observation) pairs
/// in one call; `O` and `A` are the benchmark's observation and action (LIBERO's by default).
pub trait BatchModel<O = Observation, A = Action>: Send + 'static {
    /// One chunk per request, in the requests' order.
    fn predict_batch(&mut self, requests: &[Request<O>]) -> Vec<Result<Vec<A>, String>>;
    /// The preparation of a query's inputs that needs no model state, run on the asking worker's
    /// thread, in parallel with the other workers, instead of serially on the batching thread
    /// while the accelerator waits. On the H100 OpenVLA's image preprocessing took 100 ms of a
    /// 460 ms forward cycle of 16 episodes there (`data/benchmarks/gpu-end-to-end-*`).
    fn preparer(&self) -> Option<Preparer<O>> {
        None
    }
    /// Whether the model reads a camera: LIBERO's at [`BatchModel::camera_size`], ALOHA-sim's
    /// `top` at its fixed 480 × 640.
    fn reads_cameras(&self) -> bool {
        self.camera_size().is_some()
    }
    /// [`crate::Policy::wants_wrist_camera`] of the model's policies.
    fn wants_wrist_camera(&self) -> bool {
        true
    }
    /// Camera size the model needs (`None`: proprio only).
    fn camera_size(&self) -> Option<u32> {
        None
    }
    /// Actions of each chunk executed before the episode's next query.
    fn replan_steps(&self) -> usize {
        1
    }
    /// The device the replica runs on (`cuda:1`), named in the error rows of a forward that
    /// failed as a whole, so a user sees which GPU failed (`scripts/bench/gpu_failure.sh`).
    fn device_label(&self) -> Option<String> {
        None
    }
}

/// One shared set of `count` replicas per name (e.g. a model's policy string) for the whole
/// process: every rollout worker's policy instance must reach the same ones. The first caller
/// loads them, each in its own thread (`make(i)` for replica i: (model, most episodes per
/// forward, longest wait)); a replica that fails to load fails them all.
pub fn shared_replicas<O: Clone + Send + 'static, A: Send + 'static, M: BatchModel<O, A>>(
    name: &str,
    count: usize,
    make: impl Fn(usize) -> Result<(M, usize, Duration), PolicyError> + Sync,
) -> Result<Arc<Replicas<O, A>>, PolicyError> {
    let mut map = REPLICAS.get_or_init(Default::default).lock().expect("replicas");
    if let Some(shared) = map.get(name) {
        return shared.replicas.clone().downcast::<Replicas<O, A>>().map_err(|_| PolicyError {
            policy: name.into(),
            detail: "this policy's replicas serve another benchmark in this process".into(),
        });
    }
    let loaded: Vec<Result<(M, usize, Duration), PolicyError>> = std::thread::scope(|scope| {
        let make = &make;
        let threads: Vec<_> = (0..count.max(1)).map(|i| scope.spawn(move || make(i))).collect();
        threads.into_iter().map(|t| t.join().expect("a replica's loading thread panicked")).collect()
    });
    let mut batchers = Vec::with_capacity(loaded.len());
    for replica in loaded {
        let (model, max_batch, max_wait) = replica?;
        batchers.push(Batcher::start(model, max_batch, max_wait));
    }
    let replicas = Replicas::new(batchers);
    let stats = replicas.batchers.iter().map(|b| b.stats.clone()).collect();
    map.insert(name.to_string(), SharedReplicas { replicas: replicas.clone(), stats });
    Ok(replicas)
}

/// A name's replicas, of whichever benchmark's types, and each batcher's statistics.
struct SharedReplicas {
    replicas: Arc<dyn Any + Send + Sync>,
    stats: Vec<Arc<Mutex<BatchStats>>>,
}

static REPLICAS: std::sync::OnceLock<Mutex<std::collections::HashMap<String, SharedReplicas>>> =
    std::sync::OnceLock::new();

/// Every shared batcher of this process by name (`NAME [replica i of n]` where there are
/// several), with the batch sizes it has run (the run prints them, so a user sees whether the
/// forwards were full and the replicas shared the work).
pub fn shared_batcher_stats() -> Vec<(String, BatchStats)> {
    let Some(map) = REPLICAS.get() else { return Vec::new() };
    let map = map.lock().expect("replicas");
    let mut stats = Vec::new();
    for (name, shared) in map.iter() {
        let n = shared.stats.len();
        for (i, b) in shared.stats.iter().enumerate() {
            let label = if n == 1 { name.clone() } else { format!("{name} [replica {} of {n}]", i + 1) };
            stats.push((label, b.lock().expect("stats").clone()));
        }
    }
    stats.sort_by(|a, b| a.0.cmp(&b.0));
    stats
}

/// A model's replicas, one [`Batcher`] each, and which serves the next episode.
pub struct Replicas<O = Observation, A = Action> {
    batchers: Vec<Arc<Batcher<O, A>>>,
    /// Held while an episode picks its replica, so that workers starting together spread.
    choosing: Mutex<()>,
}

impl<O, A> Replicas<O, A> {
    /// At least one batcher; all of one model (the first one's cameras and chunking stand for all).
    pub fn new(batchers: Vec<Arc<Batcher<O, A>>>) -> Arc<Self> {
        assert!(!batchers.is_empty(), "a model needs at least one replica");
        Arc::new(Replicas { batchers, choosing: Mutex::new(()) })
    }

    /// One replica.
    pub fn single(batcher: Arc<Batcher<O, A>>) -> Arc<Self> {
        Replicas::new(vec![batcher])
    }

    /// The replica for an episode that starts now, counted in its episodes in progress: the one
    /// with the least (episodes in progress + 1) × recent forward ms (the lowest index among
    /// equals; see the module's doc).
    fn start_episode(&self) -> usize {
        let _choosing = self.choosing.lock().unwrap_or_else(|p| p.into_inner());
        let durations: Vec<f64> = self.batchers.iter().map(|b| b.recent_forward_ms()).collect();
        let known: Vec<f64> = durations.iter().copied().filter(|&ms| ms > 0.0).collect();
        // a replica without a forward yet counts as the others' mean (all alike when none has run)
        let unknown = if known.is_empty() { 1.0 } else { known.iter().sum::<f64>() / known.len() as f64 };
        // one snapshot: episodes may end (without `choosing`) while the replicas are compared
        let costs: Vec<f64> = (self.batchers.iter().zip(&durations))
            .map(|(b, &ms)| {
                let ms = if ms > 0.0 { ms } else { unknown };
                (b.in_progress.load(Ordering::SeqCst) + 1) as f64 * ms.max(1.0)
            })
            .collect();
        let i = (1..costs.len()).fold(0, |best, i| if costs[i] < costs[best] { i } else { best });
        let b = &self.batchers[i];
        b.stats.lock().unwrap_or_else(|p| p.into_inner()).episodes += 1;
        b.in_progress.fetch_add(1, Ordering::SeqCst);
        i
    }

    fn end_episode(&self, replica: usize) {
        self.batchers[replica].in_progress.fetch_sub(1, Ordering::SeqCst);
    }

    /// Each replica's batch sizes, in the replicas' order.
    pub fn stats(&self) -> Vec<BatchStats> {
        self.batchers.iter().map(|b| b.stats()).collect()
    }

    fn first(&self) -> &Batcher<O, A> {
        &self.batchers[0]
    }
}

/// The pauses before a forward that ran out of memory is tried again (15 s in all, then its
/// episodes are error rows): long enough for a passing neighbour on the device, short enough that
/// a device that stays full costs a batch's episodes, not the run's time.
const OUT_OF_MEMORY_RETRIES: [Duration; 4] =
    [Duration::from_secs(1), Duration::from_secs(2), Duration::from_secs(4), Duration::from_secs(8)];

thread_local! {
    /// Set on a batching thread: its forwards' panics are caught and answered
    /// ([`Batcher::start`]), so an out-of-memory one needs no report of its own.
    static CATCHES_FORWARD_PANICS: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether the process's panic hook reports a panic: not one that says "out of memory" on a
/// batching thread, which says it itself in one line ("ran out of memory on a batch of N; trying
/// again", or, once the tries run out, that its episodes are error rows, which store the message).
/// Reported, each try's panic printed libtorch's C++ stack too: a 40 s out-of-memory on one of two
/// H200s filled 69 kB of stderr with 14 of them (`data/benchmarks/gpu-failure-h200-2026-11-29`).
fn panic_reported(on_batching_thread: bool, payload: &(dyn Any + Send)) -> bool {
    !(on_batching_thread && panic_text(payload).contains("out of memory"))
}

/// Wraps the process's panic hook (once) with [`panic_reported`]; every other panic is reported
/// as before.
fn quiet_caught_out_of_memory_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let report = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if panic_reported(CATCHES_FORWARD_PANICS.with(std::cell::Cell::get), info.payload()) {
                report(info);
            }
        }));
    });
}

/// A caught panic's message, without the C++ stack libtorch's errors carry after it (not for an
/// error row).
fn panic_text(panic: &(dyn Any + Send)) -> String {
    let msg = panic
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "a panic without a message".into());
    msg.split("\nException raised from").next().unwrap_or_default().trim_end().to_string()
}

/// Forward ids, distinct across every batcher of the process (the replicas of a model too), so that
/// the stored steps count the forwards of a run ([`ActTiming::forward_id`]).
static FORWARD_IDS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

type Reply<A> = Sender<(Result<Vec<A>, String>, ActTiming)>;
/// A worker's query: the request, when it was sent, where to answer.
type Query<O, A> = (Request<O>, Instant, Reply<A>);
/// When a query was sent, and where to answer it.
type Sent<A> = (Instant, Reply<A>);

/// Batch sizes the batcher has run, for tests and benchmarks.
#[derive(Debug, Default, Clone)]
pub struct BatchStats {
    /// Episodes started on this batcher (with several replicas, its share of the run's).
    pub episodes: usize,
    /// Episodes per forward, in order.
    pub batches: Vec<usize>,
    /// Each forward's wall time on the batching thread, ms (`ActTiming::forward_ms`): per replica,
    /// so that a run on several GPUs shows whether one device's forwards are slower.
    pub forward_ms: Vec<f32>,
}

impl BatchStats {
    /// `"12 forwards, 3.5 episodes per forward on average, at most 4; 41.2 ms per forward (median 40.0)"`,
    /// led by `"5 episodes, "` where the batcher counted the episodes it served (a replica's).
    pub fn summary(&self) -> String {
        let n = self.batches.len();
        let total: usize = self.batches.iter().sum();
        let max = self.batches.iter().max().copied().unwrap_or(0);
        let mean = if n == 0 { 0.0 } else { total as f64 / n as f64 };
        let episodes = if self.episodes > 0 { format!("{} episodes, ", self.episodes) } else { String::new() };
        let mut text = format!("{episodes}{n} forwards, {mean:.1} episodes per forward on average, at most {max}");
        if !self.forward_ms.is_empty() {
            let mut ms = self.forward_ms.clone();
            ms.sort_by(f32::total_cmp);
            let mean_ms = ms.iter().map(|&m| f64::from(m)).sum::<f64>() / ms.len() as f64;
            text += &format!("; {mean_ms:.1} ms per forward (median {:.1})", ms[ms.len() / 2]);
        }
        text
    }
}

/// The thread that owns the model and answers batches.
pub struct Batcher<O = Observation, A = Action> {
    queue: Mutex<Sender<Query<O, A>>>,
    preparer: Option<Preparer<O>>,
    camera_size: Option<u32>,
    reads_cameras: bool,
    wants_wrist_camera: bool,
    /// Episodes in progress on this batcher's policies: a forward waits for all of them.
    in_progress: Arc<AtomicUsize>,
    replan_steps: usize,
    stats: Arc<Mutex<BatchStats>>,
    /// A moving average of this batcher's forward ms (f64 bits; 0: no forward yet), which
    /// [`Replicas`] weighs its episodes by.
    recent_forward_ms: Arc<AtomicU64>,
}

impl<O, A> Batcher<O, A> {
    /// The moving average of this batcher's forward ms; 0 before its first forward.
    fn recent_forward_ms(&self) -> f64 {
        f64::from_bits(self.recent_forward_ms.load(Ordering::SeqCst))
    }

    /// The model's [`BatchModel::replan_steps`].
    pub fn replan_steps(&self) -> usize {
        self.replan_steps
    }

    pub fn stats(&self) -> BatchStats {
        self.stats.lock().expect("stats").clone()
    }
}

impl<O: Clone + Send + 'static, A: Send + 'static> Batcher<O, A> {
    /// Start the batching thread for `model`.
    pub fn start(model: impl BatchModel<O, A>, max_batch: usize, max_wait: Duration) -> Arc<Self> {
        Self::start_retrying(model, max_batch, max_wait, &OUT_OF_MEMORY_RETRIES)
    }

    /// [`Batcher::start`], pausing `retries` before each new try of a forward that ran out of memory.
    fn start_retrying(
        mut model: impl BatchModel<O, A>,
        max_batch: usize,
        max_wait: Duration,
        retries: &'static [Duration],
    ) -> Arc<Self> {
        let (tx, rx): (Sender<Query<O, A>>, Receiver<_>) = channel();
        let stats = Arc::new(Mutex::new(BatchStats::default()));
        let (camera_size, replan_steps, preparer) = (model.camera_size(), model.replan_steps(), model.preparer());
        let (wants_wrist_camera, reads_cameras) = (model.wants_wrist_camera(), model.reads_cameras());
        let on_device = model.device_label().map(|d| format!(" on {d}")).unwrap_or_default();
        let thread_stats = stats.clone();
        let in_progress = Arc::new(AtomicUsize::new(0));
        let thread_in_progress = in_progress.clone();
        let recent_forward_ms = Arc::new(AtomicU64::new(0));
        let thread_recent = recent_forward_ms.clone();
        quiet_caught_out_of_memory_panics();
        std::thread::spawn(move || {
            CATCHES_FORWARD_PANICS.with(|c| c.set(true));
            // Ends when every sender (every policy and the batcher itself) is gone.
            while let Ok(first) = rx.recv() {
                let mut pending = vec![first];
                let deadline = std::time::Instant::now() + max_wait;
                // every episode in progress (one query each at most), up to max_batch
                while pending.len() < max_batch.min(thread_in_progress.load(Ordering::SeqCst)).max(1) {
                    let left = deadline.saturating_duration_since(std::time::Instant::now());
                    match rx.recv_timeout(left) {
                        Ok(r) => pending.push(r),
                        Err(_) => break,
                    }
                }
                let (requests, replies): (Vec<Request<O>>, Vec<Sent<A>>) =
                    pending.into_iter().map(|(request, sent, reply)| (request, (sent, reply))).unzip();
                let started = Instant::now();
                // A panicking model (e.g. CUDA out of memory at a large batch) answers every pending
                // request with its message instead of silently ending the batching thread. Out of
                // memory is often passing (another process on the device, a neighbour's peak), and a
                // failed forward fails every episode in it: that one is tried again after a pause
                // (OUT_OF_MEMORY_RETRIES), which on an H200 turned a 6 s hog from 61 of 80 episodes
                // lost into none (`data/benchmarks/gpu-failure-h200-2026-11-29`).
                let mut panicked = false;
                let mut answers = Vec::new();
                for (attempt, pause) in retries.iter().copied().map(Some).chain([None]).enumerate() {
                    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| model.predict_batch(&requests))) {
                        Ok(a) => {
                            answers = a;
                            break;
                        }
                        Err(panic) => {
                            let msg = panic_text(panic.as_ref());
                            let n = requests.len();
                            if let Some(pause) = pause.filter(|_| msg.contains("out of memory")) {
                                eprintln!(
                                    "the model{on_device} ran out of memory on a batch of {n}; trying again in {} s ({} of {})",
                                    pause.as_secs(),
                                    attempt + 1,
                                    retries.len()
                                );
                                std::thread::sleep(pause);
                                continue;
                            }
                            panicked = true;
                            let tries =
                                if attempt > 0 { format!(", tried {} times", attempt + 1) } else { String::new() };
                            if msg.contains("out of memory") {
                                // the hook kept quiet about it (panic_reported)
                                eprintln!(
                                    "the model{on_device} ran out of memory on a batch of {n}{tries}: its {n} episodes are error rows"
                                );
                            }
                            let hint = "if it ran out of GPU memory, lower the policy's ?batch=N or free the device";
                            answers = (0..n)
                                .map(|_| {
                                    Err(format!("the model{on_device} failed on a batch of {n}{tries}: {msg} ({hint})"))
                                })
                                .collect();
                            break;
                        }
                    }
                }
                let forward_ms = started.elapsed().as_secs_f32() * 1e3;
                answers.resize_with(replies.len(), || Err("the model returned fewer answers than requests".into()));
                {
                    let mut stats = thread_stats.lock().expect("stats");
                    stats.batches.push(replies.len());
                    stats.forward_ms.push(forward_ms);
                }
                // the last ~8 forwards weigh most; a forward that failed as a whole (a panic, or
                // TorchScript's out-of-memory error on every request) was quick but served nobody:
                // its replica counts as taking a second or more (up to a minute, so that it is tried
                // again), so that new episodes go elsewhere and its batches shrink
                let failed = panicked || (!answers.is_empty() && answers.iter().all(Result::is_err));
                let before = f64::from_bits(thread_recent.load(Ordering::SeqCst));
                let ms = f64::from(forward_ms);
                let recent = if failed {
                    (2.0 * before).clamp(1000.0, 60_000.0)
                } else if before > 0.0 {
                    0.875 * before + 0.125 * ms
                } else {
                    ms
                };
                thread_recent.store(recent.max(f64::MIN_POSITIVE).to_bits(), Ordering::SeqCst);
                let forward_batch = replies.len() as u32;
                let forward_id = FORWARD_IDS.fetch_add(1, Ordering::SeqCst);
                for ((sent, reply), answer) in replies.into_iter().zip(answers) {
                    let queue_ms = started.saturating_duration_since(sent).as_secs_f32() * 1e3;
                    let timing = ActTiming { queue_ms, prepare_ms: None, forward_ms, forward_id, forward_batch };
                    let _ = reply.send((answer, timing));
                }
            }
        });
        Arc::new(Batcher {
            queue: Mutex::new(tx),
            preparer,
            camera_size,
            reads_cameras,
            wants_wrist_camera,
            in_progress,
            replan_steps,
            stats,
            recent_forward_ms,
        })
    }

    /// Prepare the query here (the worker's thread), send it, wait for its forward's answer.
    fn ask(&self, instruction: &str, episode_seed: u64, obs: &O) -> Result<(Vec<A>, ActTiming), String> {
        let t0 = Instant::now();
        let prepared = self.preparer.as_ref().map(|prepare| prepare(obs)).transpose()?;
        let prepare_ms = self.preparer.as_ref().map(|_| t0.elapsed().as_secs_f32() * 1e3);
        let request = Request { instruction: instruction.to_string(), episode_seed, obs: obs.clone(), prepared };
        let (tx, rx) = channel();
        self.queue
            .lock()
            .map_err(|_| "the batcher's queue is poisoned".to_string())?
            .send((request, Instant::now(), tx))
            .map_err(|_| "the batching thread has stopped".to_string())?;
        let (answer, timing) = rx.recv().map_err(|_| "the batching thread dropped the request".to_string())?;
        answer.map(|chunk| (chunk, ActTiming { prepare_ms, ..timing }))
    }
}

/// One worker's episodes on a model's shared [`Replicas`], whatever the benchmark: executes the
/// model's `replan_steps` of each chunk its batch answers, each episode on the replica it started
/// on. [`BatchedPolicy`] (LIBERO) and [`BatchedAlohaPolicy`] (ALOHA-sim) are this behind their
/// benchmark's policy trait.
struct ReplicaClient<O, A> {
    replicas: Arc<Replicas<O, A>>,
    chunker: ActionChunker<A>,
    instruction: String,
    episode_seed: u64,
    name: String,
    last_timing: Option<ActTiming>,
    /// The replica serving the episode in progress, counted in its episodes in progress.
    replica: Option<usize>,
}

impl<O: Clone + Send + 'static, A: Copy + Send + AsRef<[f32]> + AsMut<[f32]> + 'static> ReplicaClient<O, A> {
    fn new(replicas: Arc<Replicas<O, A>>, replan_steps: usize, name: &str) -> Self {
        ReplicaClient {
            replicas,
            chunker: ActionChunker::new(replan_steps),
            instruction: String::new(),
            episode_seed: 0,
            name: name.into(),
            last_timing: None,
            replica: None,
        }
    }

    fn on_replicas(replicas: Arc<Replicas<O, A>>, name: &str) -> Self {
        let replan = replicas.first().replan_steps();
        Self::new(replicas, replan, name)
    }

    fn batcher(&self) -> &Batcher<O, A> {
        &self.replicas.batchers[self.replica.unwrap_or(0)]
    }

    fn reset(&mut self, instruction: &str, episode_seed: u64) {
        self.instruction = instruction.to_string();
        self.episode_seed = episode_seed;
        self.chunker.reset();
        if self.replica.is_none() {
            self.replica = Some(self.replicas.start_episode());
        }
    }

    fn act(&mut self, obs: &O) -> Result<A, PolicyError> {
        let err = |detail: String| PolicyError { policy: self.name.clone(), detail };
        self.last_timing = None;
        if self.chunker.needs_query() {
            let (chunk, timing) = self.batcher().ask(&self.instruction, self.episode_seed, obs).map_err(err)?;
            self.last_timing = Some(timing);
            self.chunker.push_chunk(chunk).map_err(err)?;
        }
        self.chunker.next_action().ok_or_else(|| err("no action queued".into()))
    }
}

impl<O, A> ReplicaClient<O, A> {
    fn end_episode(&mut self) {
        if let Some(replica) = self.replica.take() {
            self.replicas.end_episode(replica);
        }
    }
}

impl<O, A> Drop for ReplicaClient<O, A> {
    fn drop(&mut self) {
        self.end_episode();
    }
}

/// One worker's view of a model's shared [`Replicas`]: a LIBERO [`Policy`] that executes
/// `replan_steps` of each chunk the batch answers, each episode on the replica it started on.
pub struct BatchedPolicy(ReplicaClient<Observation, Action>);

impl BatchedPolicy {
    /// On one batcher.
    pub fn new(batcher: Arc<Batcher>, replan_steps: usize, name: &str) -> Self {
        BatchedPolicy(ReplicaClient::new(Replicas::single(batcher), replan_steps, name))
    }

    /// On `replicas`, executing each chunk as far as the model's [`BatchModel::replan_steps`].
    pub fn on_replicas(replicas: Arc<Replicas>, name: &str) -> Self {
        BatchedPolicy(ReplicaClient::on_replicas(replicas, name))
    }

    /// The replica serving the episode in progress.
    pub fn replica(&self) -> Option<usize> {
        self.0.replica
    }
}

impl Policy for BatchedPolicy {
    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        self.0.chunker.set_ensemble(Some(ensemble));
        Ok(())
    }

    fn queries_model(&self) -> bool {
        self.0.chunker.needs_query()
    }

    fn reset(&mut self, instruction: &str, episode_seed: u64) {
        self.0.reset(instruction, episode_seed);
    }

    fn end_episode(&mut self) {
        self.0.end_episode();
    }

    fn camera_size(&self) -> Option<u32> {
        self.0.replicas.first().camera_size.filter(|_| self.0.chunker.needs_query())
    }

    fn wants_wrist_camera(&self) -> bool {
        self.0.replicas.first().wants_wrist_camera
    }

    fn act(&mut self, obs: &Observation) -> Result<Action, PolicyError> {
        self.0.act(obs)
    }

    fn last_timing(&self) -> Option<ActTiming> {
        self.0.last_timing
    }
}

/// [`BatchedPolicy`]'s ALOHA-sim form: an [`AlohaPolicy`] whose episodes share the calls of a
/// model's replicas. The request's instruction is gym-aloha's task name (`env.task`, what
/// lerobot-eval passes as an ALOHA observation's `task`); an episode starts on a replica at its
/// first query and ends when the worker drops the policy.
pub struct BatchedAlohaPolicy(ReplicaClient<AlohaObservation, AlohaAction>);

impl BatchedAlohaPolicy {
    pub fn on_replicas(replicas: Arc<Replicas<AlohaObservation, AlohaAction>>, name: &str) -> Self {
        BatchedAlohaPolicy(ReplicaClient::on_replicas(replicas, name))
    }
}

impl AlohaPolicy for BatchedAlohaPolicy {
    fn reset(&mut self, episode_seed: u64) {
        // the task is known at the first observation; the replica is chosen now
        self.0.reset("", episode_seed);
    }

    fn act(&mut self, obs: &AlohaObservation) -> Result<AlohaAction, PolicyError> {
        if self.0.instruction != obs.task {
            self.0.instruction = obs.task.to_string();
        }
        self.0.act(obs)
    }

    fn wants_top_camera(&self) -> bool {
        self.0.replicas.first().reads_cameras && self.0.chunker.needs_query()
    }

    fn set_ensemble(&mut self, ensemble: crate::ensembling::Ensemble) -> Result<(), String> {
        self.0.chunker.set_ensemble(Some(ensemble));
        Ok(())
    }

    fn queries_model(&self) -> bool {
        self.0.chunker.needs_query()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Barrier;

    /// A request as a worker sends it, with `prepared` as its model's preparer made it (or not).
    fn prepared_request(instruction: &str, prepared: Option<f64>) -> Request {
        Request {
            instruction: instruction.to_string(),
            episode_seed: 0,
            obs: Observation::default(),
            prepared: prepared.map(|x| Box::new(x) as Box<dyn Any + Send>),
        }
    }

    #[test]
    fn a_request_without_prepared_inputs_fails_alone_and_a_failed_forward_fails_the_rest() {
        let requests =
            [prepared_request("a", Some(1.0)), prepared_request("b", None), prepared_request("c", Some(3.0))];
        let mut forwarded = vec![];
        let answers = forward_prepared(
            &requests,
            |x: &f64, instruction| (*x, instruction.to_string()),
            |ready| {
                forwarded = ready.to_vec();
                Ok(ready.iter().map(|(x, _)| x * 10.0).collect())
            },
            |y| Ok(vec![[y as f32, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]]),
        );
        // only the prepared requests reach the forward, and each gets its own prediction back
        assert_eq!(forwarded, vec![(1.0, "a".to_string()), (3.0, "c".to_string())]);
        assert_eq!(answers[0].as_ref().unwrap()[0][0], 10.0);
        assert_eq!(answers[1].as_ref().unwrap_err(), "the worker sent no prepared inputs");
        assert_eq!(answers[2].as_ref().unwrap()[0][0], 30.0);

        let failed: Vec<Result<Vec<Action>, String>> = forward_prepared(
            &requests,
            |x: &f64, _| *x,
            |_| Err::<Vec<f64>, _>("out of memory".to_string()),
            |_| Ok(vec![]),
        );
        let errors: Vec<String> = failed.into_iter().map(|a| a.unwrap_err()).collect();
        assert_eq!(errors, ["out of memory", "the worker sent no prepared inputs", "out of memory"]);

        let short: Vec<Result<Vec<Action>, String>> =
            forward_prepared(&requests, |x: &f64, _| *x, |_| Ok(vec![1.0]), |_| Ok(vec![]));
        assert!(short[0].is_ok());
        assert_eq!(short[2].as_ref().unwrap_err(), "the batch returned too few predictions");
    }

    #[test]
    fn the_summary_gives_episodes_and_milliseconds_per_forward() {
        let stats = BatchStats { episodes: 0, batches: vec![2, 4, 3], forward_ms: vec![30.0, 50.0, 40.0] };
        assert_eq!(
            stats.summary(),
            "3 forwards, 3.0 episodes per forward on average, at most 4; 40.0 ms per forward (median 40.0)"
        );
        let replica = BatchStats { episodes: 5, ..stats };
        assert!(replica.summary().starts_with("5 episodes, 3 forwards, "), "{}", replica.summary());
        let unused = BatchStats::default();
        assert_eq!(unused.summary(), "0 forwards, 0.0 episodes per forward on average, at most 0");
    }

    /// Echoes each request's eef x and the batch size, so routing and batching are visible.
    struct Echo;
    impl BatchModel for Echo {
        fn predict_batch(&mut self, requests: &[Request]) -> Vec<Result<Vec<Action>, String>> {
            let n = requests.len() as f32;
            requests
                .iter()
                .map(|r| {
                    if r.instruction == "fail" {
                        return Err("refused".into());
                    }
                    // the worker's preparation: its eef x, doubled
                    let x = *r.prepared.as_ref().and_then(|p| p.downcast_ref::<f64>()).ok_or("not prepared")?;
                    Ok((0..4).map(|k| [(x / 2.0) as f32, k as f32, n, 0.0, 0.0, 0.0, -1.0]).collect())
                })
                .collect()
        }

        fn preparer(&self) -> Option<Preparer> {
            Some(Arc::new(|obs: &Observation| Ok(Box::new(obs.eef_pos[0] * 2.0) as Box<dyn Any + Send>)))
        }
    }

    #[test]
    fn concurrent_workers_share_one_forward_and_get_their_own_answers() {
        let batcher = Batcher::start(Echo, 8, Duration::from_millis(200));
        let workers = 6;
        let barrier = Arc::new(Barrier::new(workers));
        let handles: Vec<_> = (0..workers)
            .map(|w| {
                let (batcher, barrier) = (batcher.clone(), barrier.clone());
                std::thread::spawn(move || {
                    let mut p = BatchedPolicy::new(batcher, 2, "echo");
                    p.reset("task", 0);
                    let obs = Observation { eef_pos: [w as f64, 0.0, 0.0], ..Default::default() };
                    barrier.wait();
                    (0..4).map(|_| (p.act(&obs).unwrap(), p.last_timing())).collect::<Vec<_>>()
                })
            })
            .collect();
        for (w, h) in handles.into_iter().enumerate() {
            let (actions, timings): (Vec<Action>, Vec<Option<ActTiming>>) = h.join().unwrap().into_iter().unzip();
            // A timing where the step queried the model (steps 0 and 2), naming the forward's size,
            // which the echo wrote into the action.
            assert!(timings[1].is_none() && timings[3].is_none(), "queued actions have no timing: {timings:?}");
            for k in [0, 2] {
                let t = timings[k].unwrap_or_else(|| panic!("worker {w} step {k}: no timing"));
                assert_eq!(t.forward_batch as f32, actions[k][2], "worker {w} step {k}");
                assert!(t.queue_ms >= 0.0 && t.forward_ms >= 0.0 && t.prepare_ms.is_some(), "{t:?}");
            }
            assert!(timings[2].unwrap().forward_id > timings[0].unwrap().forward_id);
            // Its own eef x; replan 2 of a chunk of 4: positions 0, 1, then a new chunk's 0, 1.
            assert!(actions.iter().all(|a| a[0] == w as f32), "worker {w}: {actions:?}");
            assert_eq!(actions.iter().map(|a| a[1]).collect::<Vec<_>>(), [0.0, 1.0, 0.0, 1.0]);
        }
        let stats = batcher.stats();
        assert_eq!(stats.batches.iter().sum::<usize>(), 2 * workers, "{stats:?}");
        assert!(stats.batches.iter().any(|&b| b > 1), "no two queries shared a forward: {stats:?}");
    }

    /// Answers with its own number, so the replica that served a query is visible.
    struct Numbered(f32);
    impl BatchModel for Numbered {
        fn predict_batch(&mut self, requests: &[Request]) -> Vec<Result<Vec<Action>, String>> {
            requests.iter().map(|_| Ok(vec![[self.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]])).collect()
        }
    }

    #[test]
    fn episodes_spread_over_the_replicas_and_stay_on_theirs() {
        let replicas =
            shared_replicas("numbered-test", 3, |i| Ok((Numbered(i as f32), 4, Duration::from_millis(1)))).unwrap();
        // the same name reaches the same replicas, whatever the count asked
        assert!(Arc::ptr_eq(
            &replicas,
            &shared_replicas("numbered-test", 1, |_| Ok((Numbered(9.0), 1, Duration::ZERO))).unwrap()
        ));
        let mut workers: Vec<BatchedPolicy> =
            (0..7).map(|_| BatchedPolicy::on_replicas(replicas.clone(), "numbered")).collect();
        for w in workers.iter_mut() {
            w.reset("task", 0);
        }
        // 7 episodes over 3 replicas: 3, 2, 2 in the order they started
        let served: Vec<usize> = workers.iter().map(|w| w.replica().unwrap()).collect();
        assert_eq!(served, [0, 1, 2, 0, 1, 2, 0]);
        for (w, &r) in workers.iter_mut().zip(&served) {
            for _ in 0..3 {
                assert_eq!(w.act(&Observation::default()).unwrap()[0], r as f32, "an episode stays on its replica");
            }
        }
        // two episodes end on replica 0 and one on 2: the next two start there, the fewest first
        // (forwards this quick count alike whatever a loaded machine's scheduler made of them)
        for b in &replicas.batchers {
            b.recent_forward_ms.store(0.5f64.to_bits(), Ordering::SeqCst);
        }
        workers[0].end_episode();
        workers[3].end_episode();
        workers[2].end_episode();
        workers[0].reset("task", 1);
        workers[2].reset("task", 1);
        assert_eq!((workers[0].replica(), workers[2].replica()), (Some(0), Some(2)));
        let stats = replicas.stats();
        assert_eq!(stats.len(), 3);
        assert_eq!(stats.iter().map(|s| s.batches.iter().sum::<usize>()).sum::<usize>(), 7 * 3);
        let labels: Vec<String> =
            shared_batcher_stats().into_iter().map(|(n, _)| n).filter(|n| n.starts_with("numbered-test")).collect();
        assert_eq!(
            labels,
            ["numbered-test [replica 1 of 3]", "numbered-test [replica 2 of 3]", "numbered-test [replica 3 of 3]"]
        );
        for w in workers.iter_mut() {
            w.end_episode();
        }
        assert!(replicas.batchers.iter().all(|b| b.in_progress.load(Ordering::SeqCst) == 0));
    }

    /// Takes its number of milliseconds per forward.
    struct Sleepy(u64);
    impl BatchModel for Sleepy {
        fn predict_batch(&mut self, requests: &[Request]) -> Vec<Result<Vec<Action>, String>> {
            std::thread::sleep(Duration::from_millis(self.0));
            requests.iter().map(|_| Ok(vec![[0.0; 7]])).collect()
        }
    }

    #[test]
    fn a_slower_replica_takes_fewer_episodes() {
        let replicas = Replicas::new(vec![
            Batcher::start(Sleepy(40), 8, Duration::from_millis(1)),
            Batcher::start(Sleepy(4), 8, Duration::from_millis(1)),
        ]);
        let mut workers: Vec<BatchedPolicy> =
            (0..12).map(|_| BatchedPolicy::on_replicas(replicas.clone(), "sleepy")).collect();
        // before any forward the two count alike: the first two episodes take one each
        for w in workers.iter_mut().take(2) {
            w.reset("task", 0);
            w.act(&Observation::default()).unwrap();
        }
        assert_eq!((workers[0].replica(), workers[1].replica()), (Some(0), Some(1)));
        // each forward's time went into its replica's average (a sleep takes at least its time)
        let measured: Vec<f64> = replicas.batchers.iter().map(|b| b.recent_forward_ms()).collect();
        assert!(measured[0] >= 40.0 && measured[1] >= 4.0, "{measured:?}");
        // the exact figures from here on, so that a loaded machine's late wake-ups change nothing:
        // the 40 ms replica weighs (1 + 1) × 40 = 80 against the other's (n + 1) × 4, so the next
        // ten episodes all go to the fast one
        for (b, ms) in replicas.batchers.iter().zip([40.0f64, 4.0]) {
            b.recent_forward_ms.store(ms.to_bits(), Ordering::SeqCst);
        }
        for w in workers.iter_mut().skip(2) {
            w.reset("task", 0);
        }
        let on_fast = workers.iter().filter(|w| w.replica() == Some(1)).count();
        assert_eq!(on_fast, 11, "the 4 ms replica has {on_fast} of 12 episodes");
        let stats = replicas.stats();
        assert_eq!(stats[0].episodes + stats[1].episodes, 12);
        assert!(stats[1].summary().starts_with(&format!("{on_fast} episodes, ")), "{}", stats[1].summary());
    }

    /// Panics on every forward, at once (an error no pause cures: no retries).
    struct Broken;
    impl BatchModel for Broken {
        fn predict_batch(&mut self, _: &[Request]) -> Vec<Result<Vec<Action>, String>> {
            panic!("CUDA error: unspecified launch failure (simulated)")
        }
    }

    #[test]
    fn a_replica_whose_forwards_panic_takes_fewer_episodes() {
        let replicas = Replicas::new(vec![
            Batcher::start(Broken, 8, Duration::from_millis(1)),
            Batcher::start(Sleepy(20), 8, Duration::from_millis(1)),
        ]);
        let mut workers: Vec<BatchedPolicy> =
            (0..8).map(|_| BatchedPolicy::on_replicas(replicas.clone(), "mixed")).collect();
        workers[0].reset("task", 0);
        workers[1].reset("task", 0);
        assert!(workers[0].act(&Observation::default()).is_err() && workers[1].act(&Observation::default()).is_ok());
        // the broken replica's quick failure counts as a second per forward, not as speed
        for w in workers.iter_mut().skip(2) {
            w.reset("task", 0);
        }
        let on_broken = workers.iter().filter(|w| w.replica() == Some(0)).count();
        assert_eq!(on_broken, 1, "{:?}", workers.iter().map(|w| w.replica()).collect::<Vec<_>>());
    }

    #[test]
    fn a_forward_that_refuses_every_request_counts_as_a_second_up_to_a_minute() {
        let batcher = Batcher::start(Echo, 4, Duration::from_millis(1));
        let mut p = BatchedPolicy::new(batcher.clone(), 1, "echo");
        p.reset("fail", 0);
        assert!(p.act(&Observation::default()).is_err());
        assert_eq!(batcher.recent_forward_ms(), 1000.0);
        batcher.recent_forward_ms.store(50_000f64.to_bits(), Ordering::SeqCst);
        p.reset("fail", 0);
        assert!(p.act(&Observation::default()).is_err());
        assert_eq!(batcher.recent_forward_ms(), 60_000.0, "capped, so that the replica is tried again");
        p.reset("ok", 0);
        assert!(p.act(&Observation::default()).is_ok());
        assert!(batcher.recent_forward_ms() < 60_000.0, "a forward that served its requests counts as its time");
    }

    #[test]
    fn a_replica_that_fails_to_load_fails_the_model() {
        let e = shared_replicas("failing-test", 2, |i| match i {
            1 => Err(PolicyError { policy: "numbered".into(), detail: "cuda:1 is not on this machine".into() }),
            _ => Ok((Numbered(0.0), 1, Duration::ZERO)),
        })
        .err()
        .expect("an error");
        assert!(e.to_string().contains("cuda:1"), "{e}");
        assert!(shared_batcher_stats().iter().all(|(n, _)| !n.starts_with("failing-test")));
    }

    /// Panics on the instruction "panic", as tch panics on libtorch's errors (message, then the
    /// C++ stack); says it runs on cuda:1.
    struct Fragile;
    impl BatchModel for Fragile {
        fn predict_batch(&mut self, requests: &[Request]) -> Vec<Result<Vec<Action>, String>> {
            assert!(
                requests.iter().all(|r| r.instruction != "panic"),
                "CUDA error: an illegal memory access was encountered (simulated)\nException raised from c10_cuda_check\nframe #0: c10::Error"
            );
            requests.iter().map(|_| Ok(vec![[0.0; 7]])).collect()
        }
        fn device_label(&self) -> Option<String> {
            Some("cuda:1".into())
        }
    }

    #[test]
    fn a_panicking_model_answers_with_its_message_and_keeps_serving() {
        let batcher = Batcher::start(Fragile, 4, Duration::from_millis(1));
        let mut p = BatchedPolicy::new(batcher.clone(), 1, "fragile");
        p.reset("panic", 0);
        let e = p.act(&Observation::default()).unwrap_err().to_string();
        assert!(e.contains("the model on cuda:1 failed on a batch of 1: CUDA error: an illegal memory access was encountered (simulated) ("), "{e}");
        assert!(e.contains("batch=N") && !e.contains("Exception raised") && !e.contains("frame #0"), "{e}");
        p.reset("ok", 0);
        assert!(p.act(&Observation::default()).is_ok(), "the batching thread survived the panic");
    }

    /// Runs out of memory on its first `failures` forwards, then answers.
    struct Crowded {
        failures: usize,
    }
    impl BatchModel for Crowded {
        fn predict_batch(&mut self, requests: &[Request]) -> Vec<Result<Vec<Action>, String>> {
            if self.failures > 0 {
                self.failures -= 1;
                panic!("CUDA error: out of memory (simulated)");
            }
            requests.iter().map(|_| Ok(vec![[1.0; 7]])).collect()
        }
    }

    #[test]
    fn a_forward_that_runs_out_of_memory_is_tried_again_before_its_episodes_fail() {
        // out of memory once: after a 1 s pause the same forward answers
        let batcher = Batcher::start(Crowded { failures: 1 }, 4, Duration::from_millis(1));
        let mut p = BatchedPolicy::new(batcher, 1, "crowded");
        p.reset("task", 0);
        let t0 = Instant::now();
        assert_eq!(p.act(&Observation::default()).unwrap(), [1.0; 7]);
        assert!(t0.elapsed() >= OUT_OF_MEMORY_RETRIES[0], "{:?}", t0.elapsed());
        // out of memory at every try (pauses of 1 ms here): the episode fails, naming the tries,
        // and the batcher serves on
        const SHORT: [Duration; 4] = [Duration::from_millis(1); 4];
        let batcher = Batcher::start_retrying(Crowded { failures: 5 }, 4, Duration::from_millis(1), &SHORT);
        let mut p = BatchedPolicy::new(batcher, 1, "crowded");
        p.reset("task", 0);
        let e = p.act(&Observation::default()).unwrap_err().to_string();
        assert!(e.contains("tried 5 times: CUDA error: out of memory (simulated)"), "{e}");
        p.reset("task", 1);
        assert_eq!(p.act(&Observation::default()).unwrap(), [1.0; 7]);
    }

    #[test]
    fn only_a_batching_threads_out_of_memory_panic_goes_unreported() {
        let oom: Box<dyn Any + Send> = Box::new(String::from("CUDA error: out of memory\nException raised from x"));
        let other: Box<dyn Any + Send> = Box::new("an illegal memory access was encountered");
        assert!(!panic_reported(true, oom.as_ref()));
        assert!(panic_reported(false, oom.as_ref()), "another thread's out of memory is not caught there");
        assert!(panic_reported(true, other.as_ref()), "any other panic of a forward is reported");
    }

    #[test]
    fn a_refused_request_is_that_workers_error_only() {
        let batcher = Batcher::start(Echo, 4, Duration::from_millis(1));
        let mut bad = BatchedPolicy::new(batcher.clone(), 1, "echo");
        bad.reset("fail", 0);
        assert!(bad.act(&Observation::default()).unwrap_err().to_string().contains("refused"));
        let mut good = BatchedPolicy::new(batcher, 1, "echo");
        good.reset("ok", 0);
        assert!(good.act(&Observation::default()).is_ok());
    }
}
