//! `pipeline run SPECS --out RUN`: validate the specs, write the manifest, run every episode not
//! yet finished through the `rollout` UDF, then print the per-suite results.
//!
//! Resume: the episode part is written after the steps part, and only finished episodes have one,
//! so running the same command again on the same `--out` skips them; a different configuration
//! (policy, caps, wait steps, stop-on-success, bundles, MuJoCo) is refused, never mixed.

use crate::engine::{Engine, EngineArg};
use crate::session::{self, SuccessDefinition};
use crate::specs;
use anyhow::{Context, Result, bail};
use arrow::array::{ArrayRef, BooleanArray, Int32Array, RecordBatch, StringArray, UInt32Array};
use datafusion::datasource::MemTable;
use datafusion::prelude::SessionContext;
use indicatif::{ProgressBar, ProgressStyle};
use libero_policies::PolicySpec;
use libero_schema::benchmark::{ALOHA_SUITE, aloha as aloha_protocol};
use libero_schema::protocol::{CONTROL_FREQ_HZ, NUM_STEPS_WAIT, SUBSTEPS_PER_STEP};
use libero_schema::{Benchmark, InstructionSource, RunManifest, Suite, tables};
use libero_sim::aloha::AlohaBundle;
use libero_sim::bundle::BundleSet;
use libero_udfs::compaction;
use libero_udfs::rollout::{RolloutContext, RunProtocol, rollout_udf};
use libero_udfs::run_store::{RunStore, parquet_bytes};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub const EXAMPLES: &str = "\
Examples:
  pipeline run specs.parquet --out runs/expert --policy expert     # the positive control
  pipeline run specs.parquet --out runs/pi05 --policy openpi:ws://localhost:8000 --jobs 8
  pipeline run specs.parquet --out runs/ckpt --policy 'openvla:/path/to/ckpt?unnorm=libero_goal'";

#[derive(clap::Args)]
pub struct Args {
    /// Spec table (Parquet) with suite, task_id, init_state_id, seed; make one with `pipeline specs`.
    specs: PathBuf,
    /// Run location: a folder (created) or an object-store URL. Re-running on it resumes.
    #[arg(long)]
    out: String,
    /// Policy to evaluate, one of:
    ///   random | lift: baselines (score ≈ 0)
    ///   expert: the privileged scripted expert (positive control)
    ///   nan-at:<policy step> | expert-drop: diagnostics
    ///   torchscript:<model.pt>[?batch=N[&wait_ms=W]]: a TorchScript module, model.json
    ///     beside it
    ///   openvla:<checkpoint dir>[?unnorm=<key>][&batch=N[&wait_ms=W]]: OpenVLA in process
    ///   oft:<checkpoint dir>[?unnorm=<key>][&batch=N[&wait_ms=W]]: OpenVLA-OFT in process
    ///     (two cameras + state, 8-action chunks run open loop; the dir holds
    ///     action_head--*.pt etc.)
    ///   openpi:ws://host:port[?replan=N]: openpi's policy server (replan: actions run per
    ///     chunk, 5)
    ///   vla-eval:ws://host:port: vla-eval's model server (its HELLO says which images and
    ///     state)
    ///   starvla:ws://host:port[?unnorm=<key>][&stats=<dataset_statistics.json>][&chunk=N]
    ///     [&state=0|1]: starVLA's policy server (VLA-JEPA): the metadata tells the
    ///     generation; HEAD's servers unnormalise, the older one's normalised actions need
    ///     stats= (unnorm: the dataset key; chunk: actions run per query, default the
    ///     metadata's action_chunk_size, or 7; state: send the 8-D state, default off for
    ///     HEAD, on for the older one)
    ///   lerobot:<checkpoint dir>[?python=<interpreter>][&batch=N][&devices=D,..][&steps=N]:
    ///     a lerobot 0.6.1 checkpoint (SmolVLA, π0, π0.5, ...) in a Python process the run
    ///     starts, fed as lerobot-eval feeds it (interpreter: python= or LIBERO_EVAL_PYTHON)
    ///   python:<module>:<factory>[?python=<interpreter>][&key=value..]: any Python policy
    ///     object with describe() and act(batch), in that process (see docs: Policies)
    /// Chunked policies (torchscript, oft, openpi, starvla, lerobot, python) also take
    ///   ensemble=newest:N|average:N|ema:ALPHA:N (vla-eval's rules, the model asked every N
    ///   actions), temporal:K (ACT's temporal ensembling) or adaptive:H:ALPHA (starVLA's)
    #[arg(long, verbatim_doc_comment)]
    policy: PolicySpec,
    /// Episode cap in policy steps for every suite (default: the spec rows' protocol's, canonical
    /// 220/280/300/520/400, lerobot 280/280/300/520/400; ALOHA-sim: lerobot's 400, where
    /// gym-aloha's registration and openpi use 300); at least 1.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    max_steps: Option<u32>,
    /// Wait steps before the policy acts.
    #[arg(long, default_value_t = NUM_STEPS_WAIT)]
    wait_steps: u32,
    /// Which instruction text the policy is given: published (default: what each suite's published
    /// evaluation gives, task.language for the LIBERO suites as OpenVLA's and openpi's loops do,
    /// the BDDL (:language ...) tag for LIBERO-PRO's) or bddl (the tag everywhere, LIBERO-PRO's
    /// protocol: a base task and its _swap/_object copies then get the same text).
    #[arg(long, default_value = "published")]
    instruction: InstructionSource,
    /// Stop an episode at its first success (as the published scripts do) instead of running
    /// to the cap; last-step re-scoring is then no longer possible.
    #[arg(long)]
    stop_on_success: bool,
    /// Real-time evaluation: the env keeps its control rate (LIBERO 20 Hz, ALOHA-sim 50 Hz) while
    /// the policy computes, and the steps its answer is late for run the hold action (--hold).
    /// A number of milliseconds every model query takes (reproducible on any machine; a chunked
    /// policy's queued actions take none; refused for vla-eval:, whose server keeps the chunks), or
    /// `measured`: each policy call's own wall time here.
    /// An answer of L ms runs floor(L / step period) steps after its query. Stored per step
    /// (steps.held) and in the manifest; compare the run with its closed-loop twin.
    #[arg(long, value_name = "MS|measured", value_parser = libero_schema::real_time::parse_latency, allow_hyphen_values = true)]
    latency_ms: Option<libero_schema::real_time::Latency>,
    /// What a real-time step runs while the answer is late: stay (the arm where it is, the
    /// gripper's last command; LIBERO's default, its actions are deltas) or repeat (the last
    /// action again; ALOHA-sim's default, its actions are absolute targets). Needs --latency-ms.
    #[arg(long, value_name = "repeat|stay")]
    hold: Option<libero_schema::real_time::Hold>,
    /// Parallel episodes (default: one per core); with --processes, shared out among them.
    #[arg(long)]
    jobs: Option<usize>,
    /// Run the episodes in N processes of this binary: the policy's devices= dealt out among them
    /// (process k takes devices k, k+N, ...), each with its share of --jobs and its cameras on its
    /// own GPUs, as N one-GPU machines (one process renders every camera through one GL thread:
    /// docs: GPUs, Several GPUs). Default: one process per GPU where devices= lists several
    /// distinct GPUs and the episodes run on this machine, else 1; --processes 1 keeps them in one.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    processes: Option<u32>,
    /// At the end of a run, merge its one-episode parts into a few large files (`pipeline compact`)
    /// once there are at least this many (0: never). Re-scoring 2000 episodes takes 2.1 s over
    /// 4000 parts and 0.2 s compacted; compacting them takes ~9 s.
    #[arg(long, default_value_t = 500)]
    compact_at: usize,
    /// Run spec rows that perturb the camera images (camera_* columns, sensor_noise) with a policy
    /// that sees no camera (the expert, the baselines): a control, whose rate must not change.
    /// Without it such a run is refused, since the perturbation would mean nothing.
    #[arg(long)]
    allow_unseen_perturbations: bool,
    #[command(flatten)]
    engine: EngineArg,
    /// With --engine ballista:// on another machine: the --out folder is one every executor mounts
    /// at the same path (without it such a run is refused: use an object store).
    #[arg(long)]
    shared_filesystem: bool,
    /// The ALOHA-sim bundle, for a spec table of suite aloha_sim (default: data/aloha).
    #[arg(long)]
    aloha_bundle: Option<PathBuf>,
    /// Tests only: every episode sleeps this long first (to kill an executor or a process mid-run).
    #[arg(long, hide = true, default_value_t = 0)]
    test_episode_delay_ms: u64,
}

pub fn run(bundles: &Path, args: Args) -> Result<()> {
    // A scheduler that does not answer stops the run before anything is read or written.
    tokio::runtime::Runtime::new()?.block_on(args.engine.engine.check())?;
    // a process that `run --processes` started: its share of the rows and devices
    let process_share = crate::processes::Share::from_env()?;
    let local = matches!(args.engine.engine, Engine::Local);
    let processes = match (args.processes, &process_share) {
        (Some(n), _) => n as usize,
        // a process of --processes runs its share itself
        (None, Some(_)) => 1,
        (None, None) if local => crate::processes::one_per_gpu(&args.policy),
        (None, None) => 1,
    };
    let fan_out = processes > 1 && process_share.is_none();
    if processes > 1 && !local {
        bail!(
            "--processes {processes} runs this machine's processes; with --engine {} the cluster's executors run the episodes: drop one of them",
            args.engine.engine
        );
    }
    // the policy this process runs: with --processes, its share of the devices
    let policy = match &process_share {
        Some(share) => args.policy.device_share(share.k, share.n).map_err(anyhow::Error::msg)?,
        None => args.policy.clone(),
    };
    if fan_out {
        crate::processes::check(&args.policy, processes)?;
    }
    let raw = specs::read_spec_file(&args.specs)?;
    let benchmark = specs::spec_benchmark(&raw, &args.specs.display().to_string())?;
    if let Err(e) = args.policy.check_benchmark(benchmark) {
        bail!("spec file {}: {e}. No episode was started.", args.specs.display());
    }
    let (set, aloha) = match benchmark {
        Benchmark::Libero => (Arc::new(BundleSet::open(bundles)?), None),
        Benchmark::AlohaSim => {
            if !matches!(args.engine.engine, Engine::Local) {
                bail!(
                    "spec file {}: ALOHA-sim episodes run on the local engine only (the cluster's executors load LIBERO bundles); drop --engine",
                    args.specs.display()
                );
            }
            let dir = crate::bundles_location::resolve_aloha(args.aloha_bundle.as_deref());
            (Arc::new(BundleSet::none(bundles)), Some(Arc::new(AlohaBundle::open(&dir)?)))
        }
    };
    let specs = specs::validate(raw, &set, &args.specs.display().to_string())?;
    if let Some(row) = specs.first_camera_row
        && !args.policy.sees_cameras()
        && !args.allow_unseen_perturbations
    {
        bail!(
            "spec file {}: row {row} (and maybe others) perturbs the camera images (camera_* or sensor_noise columns), but the policy {} sees no camera, so the perturbation would change nothing it acts on. Run a policy that sees (openvla:, oft:, torchscript:, openpi:, vla-eval:, starvla:), drop those columns, or pass --allow-unseen-perturbations to run it as a control.",
            args.specs.display(),
            args.policy.name()
        );
    }
    if !fan_out {
        check_noise_sizes(&args.specs, &policy, &specs)?;
    }
    // A bundle file damaged since the set-up stops the run here, named, not in every episode.
    let tasks: BTreeSet<(Suite, u32)> =
        specs.keys.iter().filter_map(|k| Some((k.suite.parse().ok()?, k.task_id as u32))).collect();
    libero_sim::bundle_integrity::verify_tasks(&set, &tasks)?;
    let jobs = match &process_share {
        Some(share) => {
            Some(share.jobs(args.jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))))
        }
        None => args.jobs,
    };
    if let Some(j) = jobs {
        rayon::ThreadPoolBuilder::new().num_threads(j.max(1)).build_global().ok();
    }
    let realtime = match (args.latency_ms, args.hold) {
        (Some(latency), hold) => Some(libero_schema::real_time::RealTime {
            latency,
            hold: hold.unwrap_or(libero_schema::real_time::Hold::default_for(benchmark)),
        }),
        (None, Some(hold)) => bail!(
            "--hold {} applies to real-time runs only: add --latency-ms MS (or --latency-ms measured), or drop --hold. No episode was started.",
            hold.name()
        ),
        (None, None) => None,
    };
    if let Some(libero_schema::real_time::RealTime { latency: libero_schema::real_time::Latency::Fixed { ms }, .. }) =
        realtime
        && args.policy.chunks_kept_remotely()
    {
        bail!(
            "--latency-ms {ms} charges each model query, but {}'s server keeps its action chunks, so every step looks like a query and would be charged. Use --latency-ms measured (each call's own time: a queued action comes back at once). No episode was started.",
            args.policy.name()
        );
    }
    let max_steps: BTreeMap<Suite, u32> =
        tasks.iter().map(|(s, _)| (*s, args.max_steps.unwrap_or_else(|| specs.protocol.max_steps(s.base)))).collect();
    let aloha_max_steps = args.max_steps.unwrap_or(aloha_protocol::LEROBOT_MAX_STEPS);
    let protocol = RunProtocol {
        max_steps,
        aloha_max_steps,
        num_steps_wait: args.wait_steps,
        stop_on_success: args.stop_on_success,
        instruction_source: args.instruction,
        realtime,
        protocol: specs.protocol,
    };
    // the workers' cameras on GPUs without the model where the machine has such GPUs; a process of
    // --processes has its share of the GPUs, and renders on them as a one-GPU machine does
    match process_share {
        None => libero_sim::gl::keep_renders_off(&policy.model_cuda_devices()),
        Some(_) => libero_sim::gl::keep_renders_on(&policy.model_cuda_devices()),
    }
    libero_sim::gl_thread::GlThreads::from_env()?;
    let mut manifest = RunManifest {
        tables_version: tables::TABLES_VERSION,
        run_config: String::new(),
        created_at: now_rfc3339(),
        git_revision: env!("PIPELINE_GIT_REVISION").to_string(),
        pipeline_version: env!("CARGO_PKG_VERSION").to_string(),
        mujoco_version: libero_sim::mujoco_version(),
        bundle_format_version: libero_schema::bundle_format::BUNDLE_FORMAT_VERSION,
        bundles_hash: match &aloha {
            None => bundles_hash(&set, specs.keys.iter().map(|k| (k.suite.as_str(), k.task_id)), specs.protocol)?,
            Some(b) => format!("{:x}", Sha256::digest(b.provenance.to_string().as_bytes())),
        },
        policy: args.policy.name(),
        // a process of --processes takes its parent's, from the stored manifest: resolving it again
        // would hash the checkpoint or start a Python host once more in every process
        policy_identity: match process_share {
            None => args.policy.resolve_identity(benchmark)?,
            Some(_) => serde_json::Value::Null,
        },
        // ALOHA-sim's loops (lerobot's, openpi's) have no settling steps
        num_steps_wait: match benchmark {
            Benchmark::Libero => args.wait_steps as i32,
            Benchmark::AlohaSim => 0,
        },
        max_steps: match benchmark {
            Benchmark::Libero => protocol.max_steps.iter().map(|(s, n)| (s.name(), *n as i32)).collect(),
            Benchmark::AlohaSim => BTreeMap::from([(ALOHA_SUITE.to_string(), aloha_max_steps as i32)]),
        },
        instruction_source: args.instruction,
        stop_on_success: args.stop_on_success,
        substeps_per_step: match benchmark {
            Benchmark::Libero => SUBSTEPS_PER_STEP as i32,
            Benchmark::AlohaSim => aloha_protocol::SUBSTEPS_PER_STEP,
        },
        control_freq_hz: match benchmark {
            Benchmark::Libero => CONTROL_FREQ_HZ as i32,
            Benchmark::AlohaSim => aloha_protocol::CONTROL_FREQ_HZ,
        },
        env: benchmark,
        realtime,
        protocol: specs.protocol,
    };
    manifest.run_config = hex16(&Sha256::digest(manifest.config_fingerprint().as_bytes()));

    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async {
        let store = RunStore::connect(&args.out).await?;
        if store.url().scheme() == "file" && !args.engine.engine.is_loopback() && !args.shared_filesystem {
            bail!(
                "--out {} is a local folder, but the executors of {} may run on other machines and could not write to it. Use an object store (s3://, gs://, az://), or pass --shared-filesystem if every executor mounts this folder at the same path.",
                store.url(),
                args.engine.engine
            );
        }
        compaction::recover(&store).await?;
        if let Some(c) = compaction::live_lock(&store, "compaction.lock").await? {
            bail!("{} is being compacted by pid {} on {}; run it when that has finished", store.url(), c.pid, c.host);
        }
        let stored = store.read_manifest().await?;
        if let Some(share) = &process_share {
            let parent = stored.as_ref().with_context(|| {
                format!("process {share} of `pipeline run --processes` found no manifest in {}", store.url())
            })?;
            manifest.policy_identity = parent.policy_identity.clone();
            manifest.run_config = hex16(&Sha256::digest(manifest.config_fingerprint().as_bytes()));
            if parent.run_config != manifest.run_config {
                bail!(
                    "process {share} of `pipeline run --processes` sees another configuration than its parent wrote:\n  {}",
                    manifest.config_differences(parent).join("\n  ")
                );
            }
        }
        match stored {
            Some(stored) if stored.bundle_format_version != manifest.bundle_format_version => {
                bail!(
                    "{} holds a run made on task bundles of format {}; this build runs format {}, and {}.\nIts episodes cannot be resumed or mixed with new ones: run into a new --out (re-run the whole spec table).",
                    store.url(),
                    stored.bundle_format_version,
                    manifest.bundle_format_version,
                    libero_schema::bundle_format::format_change(stored.bundle_format_version)
                );
            }
            Some(stored) if stored.run_config != manifest.run_config => {
                bail!(
                    "{} holds a run with another configuration:\n  {}\nUse another --out, or re-run with the stored configuration to resume it.",
                    store.url(),
                    manifest.config_differences(&stored).join("\n  ")
                );
            }
            Some(stored) => manifest.created_at = stored.created_at,
            None => {}
        }
        // a process of --processes finds the manifest, the specs and the parts as its parent left them
        if process_share.is_none() {
            write_manifest(&store, &manifest).await?;
            store.put("specs.parquet", parquet_bytes(&specs.batch, None)?).await?;

            // A damaged part (cut short by a full disk, say) would count its episode as finished
            // and then fail every query: set its episode's parts aside, named, so this run re-runs it.
            for part in store.damaged_parts().await? {
                for moved in store.set_aside(&part.name).await? {
                    eprintln!("damaged part {part}: set aside {moved}; its episode runs again");
                }
            }
        }
        let finished = compaction::finished_part_names(&store).await?;
        let pending: Vec<u32> = match &process_share {
            None => (0..specs.keys.len() as u32).collect(),
            Some(share) => share.rows.clone(),
        }
        .into_iter()
        .filter(|&i| !finished.contains(&specs.keys[i as usize].part_name()))
        .collect();
        match &process_share {
            None => eprintln!(
                "run {} · policy {} · {} episodes ({} already finished, {} to run) · config {}",
                store.url(),
                manifest.policy,
                specs.keys.len(),
                specs.keys.len() - pending.len(),
                pending.len(),
                manifest.run_config
            ),
            Some(share) => {
                eprintln!(
                    "{} of the run's {} episodes are this process's ({} already finished, {} to run); policy {policy}",
                    share.rows.len(),
                    specs.keys.len(),
                    share.rows.len() - pending.len(),
                    pending.len(),
                );
                // the parent holds the writer lock, compacts and prints the results
                if !pending.is_empty() {
                    let ctx =
                        RunInputs { set: &set, aloha: aloha.as_ref(), specs: &specs, manifest: &manifest, store: &store };
                    run_pending(&args, &policy, &ctx, &protocol, &tasks, pending, Some(share)).await?;
                }
                return Ok(());
            }
        }
        if !pending.is_empty() {
            // While this runs, `pipeline compact` refuses the run (compaction::WriterLock).
            let lock = compaction::WriterLock::this_process(now_rfc3339());
            store.put("writer.json", serde_json::to_vec(&lock)?.into()).await?;
            let ran = if fan_out {
                // the Python hosts the identity started hold models this process will not use
                libero_policies::python_host::release_parked_hosts();
                crate::processes::say_how(&args.policy, processes, args.processes.is_none());
                crate::processes::run_children(&args.policy, &pending, processes, &store).await
            } else {
                let ctx = RunInputs { set: &set, aloha: aloha.as_ref(), specs: &specs, manifest: &manifest, store: &store };
                run_pending(&args, &policy, &ctx, &protocol, &tasks, pending, None).await
            };
            store.delete_if_present("writer.json").await?;
            ran?;
        }
        let parts = store.part_names("episodes").await?;
        let small = parts.iter().filter(|p| !p.starts_with(compaction::COMPACT_PREFIX)).count();
        if args.compact_at > 0 && small >= args.compact_at {
            let r = compaction::compact(&store).await?;
            eprintln!(
                "compacted {} episodes: steps/ {} -> {} files, episodes/ {} -> {} files (contents checked equal)",
                r.episodes, r.files_before[0], r.files_after[0], r.files_before[1], r.files_after[1]
            );
        }
        print_results(&args.out, &args.policy).await
    })
}

/// Spec rows whose sensor noise the reference cannot apply at the policy's camera size (lb2025
/// fog needs 256×256, lb2025 glass blur 224 or more; `SensorNoise::check_size`) stop the run here,
/// before any episode, each named with its level and the fix, instead of becoming one error row
/// per episode. The size is the policy's own (`Policy::camera_size`), so the policy is built once
/// here (only when some row has sensor noise; a batched model stays loaded for the episodes).
fn check_noise_sizes(spec_file: &Path, policy: &PolicySpec, specs: &specs::Specs) -> Result<()> {
    use libero_udfs::perturbation::{EpisodePerturbation, SENSOR_NOISE};
    if !policy.sees_cameras() || !specs.extras.iter().any(|c| c == SENSOR_NOISE) {
        return Ok(());
    }
    let schema = specs.batch.schema();
    let columns: Vec<usize> = specs.extras.iter().map(|c| schema.index_of(c)).collect::<Result<_, _>>()?;
    let extras = specs.batch.project(&columns)?;
    let mut noisy = Vec::new();
    for r in 0..extras.num_rows() {
        if let Some(noise) = EpisodePerturbation::from_row(&extras, r).map_err(anyhow::Error::msg)?.sensor_noise {
            noisy.push((r, noise));
        }
    }
    if noisy.is_empty() {
        return Ok(());
    }
    let Some(size) = policy.instantiate()?.camera_size() else { return Ok(()) };
    let bad: Vec<String> = noisy
        .iter()
        .filter_map(|(r, n)| {
            let why = n.check_size(size as usize, size as usize).err()?;
            Some(format!(
                "row {r} ({}): sensor_noise {} ({} severity {}, revision {}) on the policy's {size}x{size} camera: {why}",
                specs.keys[*r].episode_key,
                n.level,
                n.kind(),
                n.severity(),
                n.revision
            ))
        })
        .collect();
    if bad.is_empty() {
        return Ok(());
    }
    let n = bad.len();
    let shown: Vec<String> = bad.into_iter().take(10).collect();
    let more = if n > 10 { format!("\n  ... and {} more", n - 10) } else { String::new() };
    bail!(
        "spec file {}: {n} row(s) ask for sensor noise the reference cannot apply at the policy {}'s {size}x{size} camera; no episode was started:\n  {}{more}\nFix: a policy whose camera is 256x256 (as OpenVLA's and the published LIBERO-Plus loops render; lb2025 glass blur needs at least 224), sensor_noise_revision = 'head' (LIBERO-Plus after eaf6577: fog up to 256 and glass blur at the image's size), or drop those rows.",
        spec_file.display(),
        policy.name(),
        shown.join("\n  ")
    )
}

/// What a run's episodes are made from and written to.
struct RunInputs<'a> {
    set: &'a Arc<BundleSet>,
    aloha: Option<&'a Arc<AlohaBundle>>,
    specs: &'a specs::Specs,
    manifest: &'a RunManifest,
    store: &'a RunStore,
}

/// Run the `pending` spec rows with `policy` in this process through the rollout UDF, then record
/// what this invocation did. `share`: this process is one of `--processes` (no progress bar of its
/// own: the parent shows the run's).
async fn run_pending(
    args: &Args,
    policy: &PolicySpec,
    inputs: &RunInputs<'_>,
    protocol: &RunProtocol,
    tasks: &BTreeSet<(Suite, u32)>,
    pending: Vec<u32>,
    share: Option<&crate::processes::Share>,
) -> Result<()> {
    let RunInputs { set, aloha, specs, manifest, store } = *inputs;
    let progress = match share {
        None => ProgressBar::new(pending.len() as u64),
        Some(_) => ProgressBar::hidden(),
    }
    .with_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} episodes · {msg} · ETA {eta}")?
            .progress_chars("=> "),
    );
    progress.set_message("success 0/0");
    let mut ctx = RolloutContext::new(
        set.clone(),
        policy.clone(),
        protocol.clone(),
        manifest.run_config.clone(),
        serde_json::to_string(&manifest)?,
        store.clone(),
        tokio::runtime::Handle::current(),
        progress.clone(),
    );
    if let Some(b) = aloha {
        ctx = ctx.with_aloha(b.clone());
    }
    // a process of --processes runs its share of the devices; its episodes are the run's policy's
    ctx = ctx.with_policy_label(manifest.policy.clone());
    if args.test_episode_delay_ms > 0 {
        ctx = ctx.with_episode_delay(std::time::Duration::from_millis(args.test_episode_delay_ms));
    }
    let ctx = Arc::new(ctx);
    let n_pending = pending.len();
    #[cfg(feature = "distributed")]
    let pending_parts: std::collections::HashSet<String> =
        pending.iter().map(|&i| specs.keys[i as usize].part_name()).collect();
    let pending_batch = arrow::compute::take_record_batch(&specs.batch, &UInt32Array::from(pending))?;
    let started = (now_rfc3339(), std::time::Instant::now());
    let workers = match &args.engine.engine {
        Engine::Local => {
            run_rollouts(ctx.clone(), pending_batch, &specs.extras).await?;
            rayon::current_num_threads()
        }
        #[cfg(feature = "distributed")]
        Engine::Ballista { host, port } => {
            let run = crate::distributed::client::DistributedRun {
                host,
                port: *port,
                store,
                manifest_json: serde_json::to_string(&manifest)?,
                run_config: &manifest.run_config,
                tasks,
                pending_parts: pending_parts.clone(),
                episode_delay_ms: args.test_episode_delay_ms,
            };
            let partitions = run.run(&pending_batch, &extras_argument(&specs.extras), &progress).await?;
            eprintln!("ran on {} in {partitions} partitions", args.engine.engine);
            0
        }
        #[cfg(not(feature = "distributed"))]
        Engine::Ballista { .. } => unreachable!("Engine::check refuses it"),
    };
    progress.finish();
    let record = SessionRecord {
        started_at: started.0,
        wall_s: started.1.elapsed().as_secs_f64(),
        episodes: n_pending,
        tasks: tasks.len(),
        engine: args.engine.engine.to_string(),
        workers,
        task_compiles: ctx.task_compiles(),
        peak_rss_bytes: peak_rss_bytes(),
        host: compaction::hostname(),
        render_devices: libero_sim::gl::render_devices_used(),
        // a cluster's executors ran the model and the renders, not this process
        model_gpus: match args.engine.engine {
            Engine::Local => policy.model_cuda_devices().iter().map(|&d| d as i64).collect(),
            _ => Vec::new(),
        },
        cuda_visible_devices: std::env::var("CUDA_VISIBLE_DEVICES").ok(),
    };
    // a cluster's run counts no workers here (its executors' slots ran the episodes)
    let ran_on =
        if record.workers == 0 { "the cluster's executors".to_string() } else { format!("{} workers", record.workers) };
    eprintln!(
        "{} episodes in {:.1} s ({:.2} episodes/s on {ran_on}); peak RSS {:.2} GB; task models compiled: {} for {} tasks",
        record.episodes,
        record.wall_s,
        record.episodes as f64 / record.wall_s,
        record.peak_rss_bytes.unwrap_or(0) as f64 / 1e9,
        record.task_compiles,
        record.tasks
    );
    if let Some(renders) = record.renders() {
        eprintln!("cameras rendered on: {renders}");
    }
    let name = format!("sessions/{}-{}.json", record.started_at.replace(':', ""), std::process::id());
    store.put(&name, serde_json::to_vec_pretty(&record)?.into()).await?;
    // whether the batched policy's forwards were full (?batch=N and --jobs)
    for (name, stats) in libero_policies::batching::shared_batcher_stats() {
        eprintln!("batched policy {name}: {}", stats.summary());
    }
    Ok(())
}

/// What one `pipeline run` invocation did, stored as `RUN/sessions/<start>-<pid>.json` (a run may
/// take several, resumed after a kill): the throughput and memory figures `pipeline bench run`
/// reports, kept with the run they describe.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct SessionRecord {
    pub started_at: String,
    pub wall_s: f64,
    /// Episodes this invocation ran (the pending ones).
    pub episodes: usize,
    /// Distinct tasks of the spec table.
    pub tasks: usize,
    /// Where the episodes ran: `local`, or `ballista://host:port`.
    #[serde(default = "local_engine")]
    pub engine: String,
    /// This process's episode workers (0 when the episodes ran on a cluster's executors).
    pub workers: usize,
    pub task_compiles: u64,
    /// The process's peak resident set (Linux VmHWM), the whole run included.
    pub peak_rss_bytes: Option<u64>,
    pub host: String,
    /// The devices this invocation's cameras rendered on; empty where its episodes ran on a
    /// cluster's executors (they keep no record) and in records made before this field. The parent
    /// of `--processes` writes no record; each of its processes writes its own.
    #[serde(default)]
    pub render_devices: Vec<libero_sim::gl::RenderDevice>,
    /// The CUDA devices the policy's `devices=` names for its model, as that list numbers them.
    /// Empty where the policy does not say (a model on the CPU, `torchscript:` on its default
    /// device, `python:` without `devices=`, a server's model) or the engine was a cluster.
    #[serde(default)]
    pub model_gpus: Vec<i64>,
    /// `CUDA_VISIBLE_DEVICES` as the process saw it: with it set, `devices=` numbers only the GPUs
    /// it lists, while EGL's CUDA device numbers all of them, so the two are not compared.
    #[serde(default)]
    pub cuda_visible_devices: Option<String>,
}

impl SessionRecord {
    /// Where the cameras rendered, in words, or `None` where nothing was recorded.
    ///
    /// Why it is said: it decides a run's speed more than anything else on the machine. On the
    /// model's GPU the renders' GPU time adds to the forwards' (about 2.6 ms a camera pair on an
    /// H200), and on Mesa's llvmpipe a GPU run's renders were 20× slower than on its GPU
    /// (`data/benchmarks/gpu-renders-h200-2026-11-29`).
    pub fn renders(&self) -> Option<String> {
        if self.render_devices.is_empty() {
            return None;
        }
        let each: Vec<String> = self.render_devices.iter().map(|d| self.render_device(d)).collect();
        Some(each.join("; "))
    }

    /// One device in words, with what is known of the model beside it.
    fn render_device(&self, d: &libero_sim::gl::RenderDevice) -> String {
        let device = d.egl_device.map_or("Mesa's surfaceless platform".to_string(), |i| format!("EGL device {i}"));
        if d.software {
            let hint = if self.model_gpus.is_empty() {
                ""
            } else {
                " while the model ran on a GPU: install the NVIDIA driver's EGL library, or set \
                 MUJOCO_EGL_DEVICE_ID to an NVIDIA device (`pipeline doctor` lists them)"
            };
            return format!("{device}, {}'s software renderer on the CPU{hint}", d.vendor);
        }
        let cuda = d.cuda.map(|c| format!(" cuda:{c}")).unwrap_or_default();
        let model = match (d.cuda, self.model_gpus.is_empty(), &self.cuda_visible_devices) {
            (_, true, _) => String::new(),
            (_, false, Some(visible)) => {
                format!(", the model's GPU or not (not compared: CUDA_VISIBLE_DEVICES={visible})")
            }
            (Some(c), false, None) if self.model_gpus.contains(&c) => {
                ", the model's GPU: renders and forwards share it, time-sliced".to_string()
            }
            (Some(_), false, None) => ", a GPU without the model".to_string(),
            (None, false, None) => ", the model's GPU or not (the driver names no CUDA device)".to_string(),
        };
        format!("{device}, {}{cuda}{model}", d.vendor)
    }
}

fn local_engine() -> String {
    "local".into()
}

/// Peak resident set size of this process so far (Linux `VmHWM`), in bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// The dataflow: the pending spec rows as a table, `rollout(...)` over them.
async fn run_rollouts(ctx: Arc<RolloutContext>, pending: RecordBatch, extras: &[String]) -> Result<()> {
    let session = SessionContext::new();
    session.register_udf(rollout_udf(ctx));
    // One partition, one batch: the UDF parallelises the rows itself.
    let table = MemTable::try_new(pending.schema(), vec![vec![pending]])?;
    session.register_table("pending", Arc::new(table))?;
    let sql =
        format!("SELECT rollout(suite, task_id, init_state_id, seed{}) AS r FROM pending", extras_argument(extras));
    session.sql(&sql).await?.collect().await.context("the rollout query failed")?;
    Ok(())
}

/// `rollout`'s fifth argument: the spec's other columns as a struct (none: empty).
fn extras_argument(extras: &[String]) -> String {
    if extras.is_empty() {
        return String::new();
    }
    let pairs: Vec<String> =
        extras.iter().map(|c| format!("'{}', \"{}\"", c.replace('\'', "''"), c.replace('"', "\"\""))).collect();
    format!(", named_struct({})", pairs.join(", "))
}

async fn write_manifest(store: &RunStore, m: &RunManifest) -> Result<()> {
    store.put("manifest.json", serde_json::to_vec_pretty(m)?.into()).await?;
    let s = |v: &str| Arc::new(StringArray::from(vec![v.to_string()])) as ArrayRef;
    let i = |v: i32| Arc::new(Int32Array::from(vec![v])) as ArrayRef;
    let u = |v: u32| Arc::new(UInt32Array::from(vec![v])) as ArrayRef;
    let batch = RecordBatch::try_new(
        tables::manifest(),
        vec![
            u(m.tables_version),
            s(&m.run_config),
            s(&m.created_at),
            s(&m.git_revision),
            s(&m.pipeline_version),
            s(&m.mujoco_version),
            u(m.bundle_format_version),
            s(&m.bundles_hash),
            s(&m.policy),
            s(&m.policy_identity.to_string()),
            i(m.num_steps_wait),
            s(&serde_json::to_string(&m.max_steps)?),
            Arc::new(BooleanArray::from(vec![m.stop_on_success])),
            i(m.substeps_per_step),
            i(m.control_freq_hz),
            s(m.instruction_source.name()),
            s(m.env.name()),
            Arc::new(StringArray::from(vec![m.realtime.map(|rt| serde_json::to_string(&rt)).transpose()?])),
            s(m.protocol.name()),
        ],
    )?;
    store.put("manifest.parquet", parquet_bytes(&batch, Some(&serde_json::to_string(m)?))?).await
}

/// After a run: the per-suite table (default scoring) and the baseline check.
async fn print_results(location: &str, policy: &PolicySpec) -> Result<()> {
    let (ctx, store) = session::open(location, SuccessDefinition::AnyStep, None).await?;
    let batches = session::queries::run(&ctx, session::queries::RESULTS).await?;
    println!("{}", arrow::util::pretty::pretty_format_batches(&batches)?);
    crate::results::warn_on_baseline(policy, &batches);
    crate::results::note_perturbed(&ctx).await?;
    if let Some(manifest) = store.read_manifest().await? {
        crate::results::print_real_time(&ctx, location, &manifest).await?;
    }
    if crate::generalisation::has_plus_rows(&ctx).await? {
        let (_, summary) = crate::generalisation::tables(&ctx).await?;
        println!("LIBERO-Plus by category (pipeline generalisation --run {location} for every cell):");
        println!("{}", arrow::util::pretty::pretty_format_batches(&summary[..summary.len().min(1)])?);
    }
    Ok(())
}

/// The identity of the bundles a run uses: sha256 over the index rows and provenance of the tasks
/// its spec table names. Provenance holds the hashes of every input and output file of a bundle
/// (scene, init states, fixture poses, task.json, assets), so equal identities mean equal scenes.
/// Build timings and `checks` are left out: they describe a build, they do not change it (a
/// rebuild or a later `verify_bundles.py` keeps the identity); other tasks built later (e.g.
/// `--suites libero_90`) do not change a run's identity either.
pub fn bundles_hash<'a>(
    set: &BundleSet,
    tasks: impl IntoIterator<Item = (&'a str, i32)>,
    protocol: libero_schema::EvalProtocol,
) -> Result<String> {
    let used: BTreeSet<(&str, i32)> = tasks.into_iter().collect();
    let mut h = Sha256::new();
    for t in set.tasks().iter().filter(|t| used.contains(&(t.suite.as_str(), t.task_id as i32))) {
        let p = set.root().join(&t.path).join("provenance.json");
        let text = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
        let mut prov: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("{} is not JSON", p.display()))?;
        if let Some(o) = prov.as_object_mut() {
            o.remove("checks");
            o.remove("built_seconds");
            // lerobot's seeded fixture poses (added later by seeded_fixtures.py) are part of what a
            // lerobot-protocol run uses, not a canonical one's: recording them keeps the latter's
            // identity (and its resume)
            match o.get_mut(libero_sim::bundle::SEEDED_RECORD).and_then(|r| r.as_object_mut()) {
                Some(record) if protocol.seeds_every_reset() => {
                    record.remove("checks");
                    record.remove("built_seconds");
                }
                _ => {
                    o.remove(libero_sim::bundle::SEEDED_RECORD);
                }
            }
        }
        h.update(format!("{}/{}\n{}\n", t.suite, t.task_id, prov).as_bytes());
    }
    Ok(format!("{:x}", h.finalize()))
}

fn hex16(d: &[u8]) -> String {
    d.iter().take(8).map(|b| format!("{b:02x}")).collect()
}

/// UTC now as RFC 3339 (seconds).
fn now_rfc3339() -> String {
    chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Secs, true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use libero_sim::gl::RenderDevice;

    fn record(render_devices: Vec<RenderDevice>, model_gpus: Vec<i64>) -> SessionRecord {
        SessionRecord {
            started_at: "2026-11-29T00:00:00Z".into(),
            wall_s: 1.0,
            episodes: 1,
            tasks: 1,
            engine: local_engine(),
            workers: 1,
            task_compiles: 1,
            peak_rss_bytes: None,
            host: "h".into(),
            render_devices,
            model_gpus,
            cuda_visible_devices: None,
        }
    }

    fn nvidia(egl: usize, cuda: i64) -> RenderDevice {
        RenderDevice { egl_device: Some(egl), vendor: "NVIDIA".into(), software: false, cuda: Some(cuda) }
    }

    #[test]
    fn a_record_says_whether_the_cameras_shared_the_models_gpu_or_ran_on_the_cpu() {
        let said = |devices, models| record(devices, models).renders().unwrap();
        assert_eq!(
            said(vec![nvidia(0, 0)], vec![0]),
            "EGL device 0, NVIDIA cuda:0, the model's GPU: renders and forwards share it, time-sliced"
        );
        assert_eq!(said(vec![nvidia(1, 1)], vec![0]), "EGL device 1, NVIDIA cuda:1, a GPU without the model");
        // a policy that does not name its devices: nothing is claimed about the model
        assert_eq!(said(vec![nvidia(0, 0)], vec![]), "EGL device 0, NVIDIA cuda:0");
        let mut hidden = record(vec![nvidia(1, 1)], vec![0]);
        hidden.cuda_visible_devices = Some("1".into());
        assert_eq!(
            hidden.renders().unwrap(),
            "EGL device 1, NVIDIA cuda:1, the model's GPU or not (not compared: CUDA_VISIBLE_DEVICES=1)"
        );
        let mesa = || RenderDevice { egl_device: Some(1), vendor: "Mesa Project".into(), software: true, cuda: None };
        assert_eq!(said(vec![mesa()], vec![]), "EGL device 1, Mesa Project's software renderer on the CPU");
        let beside_a_gpu_model = said(vec![mesa()], vec![0]);
        assert!(
            beside_a_gpu_model.contains("while the model ran on a GPU")
                && beside_a_gpu_model.contains("MUJOCO_EGL_DEVICE_ID"),
            "{beside_a_gpu_model}"
        );
        assert_eq!(said(vec![nvidia(0, 0), nvidia(1, 1)], vec![0]).matches("; ").count(), 1, "every device said");
        assert_eq!(record(vec![], vec![0]).renders(), None, "nothing recorded, nothing said");
        // a record written before the fields reads as one with nothing recorded
        let old: SessionRecord = serde_json::from_str(
            r#"{"started_at":"x","wall_s":1.0,"episodes":1,"tasks":1,"workers":1,"task_compiles":1,"peak_rss_bytes":null,"host":"h"}"#,
        )
        .unwrap();
        assert_eq!((old.render_devices.len(), old.model_gpus.len(), old.cuda_visible_devices), (0, 0, None));
    }
}
