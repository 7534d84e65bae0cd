//! `pipeline run --processes N`: a run's pending episodes dealt to N processes of this binary, each
//! with its share of the policy's `devices=`, of `--jobs`, and its own GL thread on its own GPU.
//!
//! Why: a process renders all its cameras through one GL thread, because the NVIDIA driver
//! serialises a process's GL contexts whichever GPUs they are on (`libero_sim::gl_thread`). So a
//! process with model replicas on several GPUs renders all their frames through that one thread.
//! N processes are N one-GPU machines: each has its model and its renders on its own GPU, and its
//! own workers.
//!
//! How: the parent (the `pipeline run` the user started) writes the manifest and the spec table as
//! any run does, deals its pending rows out in turn (so that each process gets its turn of every
//! task's trials), writes each child's rows to a file, and starts N children with its own arguments
//! and [`SHARE_VARIABLE`] naming the child's share, the parent and the file. A child runs those rows
//! with [`PolicySpec::device_share`]'s devices, and writes its episodes' parts and its session
//! record into the same run, as a resumed run would. The parent shows the run's progress from the
//! stored parts, passes each child's messages on with its number, and, when all have ended,
//! compacts and prints the results. A child that fails (a GPU lost, say) leaves its unfinished
//! episodes pending. The others go on, and the parent then stops, quoting the failed child's last
//! lines. If the parent itself ends, its children are stopped.

use anyhow::{Context, Result, bail};
use libero_policies::PolicySpec;
use libero_udfs::compaction::COMPACT_PREFIX;
use libero_udfs::run_store::RunStore;
use std::collections::VecDeque;
use std::io::BufRead;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};

/// The variable through which the parent tells a child its share: `K/N:PARENT_PID:ROWS_FILE`.
pub const SHARE_VARIABLE: &str = "LIBERO_PROCESS_SHARE";

/// Lines of a failed child's messages quoted in the parent's error.
const TAIL_LINES: usize = 6;

/// Which of a run's processes this one is, and the spec rows it runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Share {
    pub k: usize,
    pub n: usize,
    /// Indices into the spec table, dealt to this process by the parent.
    pub rows: Vec<u32>,
}

impl std::fmt::Display for Share {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

impl Share {
    /// The share the parent gave this process ([`SHARE_VARIABLE`]), or `None` for a run started by
    /// a user. Set by anyone but this process's parent, it is refused: it would run part of a run
    /// and print nothing.
    pub fn from_env() -> Result<Option<Share>> {
        let Ok(text) = std::env::var(SHARE_VARIABLE) else { return Ok(None) };
        let bad = || {
            anyhow::anyhow!(
                "{SHARE_VARIABLE}={text:?} is set only by `pipeline run --processes` for its own processes: unset it"
            )
        };
        let mut parts = text.splitn(3, ':');
        let (share, parent, file) =
            (parts.next().ok_or_else(bad)?, parts.next().ok_or_else(bad)?, parts.next().ok_or_else(bad)?);
        let (k, n) = share.split_once('/').ok_or_else(bad)?;
        let (k, n): (usize, usize) = (k.parse().map_err(|_| bad())?, n.parse().map_err(|_| bad())?);
        let parent: u32 = parent.parse().map_err(|_| bad())?;
        if k >= n || std::os::unix::process::parent_id() != parent {
            return Err(bad());
        }
        let listed =
            std::fs::read_to_string(file).with_context(|| format!("{SHARE_VARIABLE}: the rows file {file}"))?;
        let rows = listed.split_whitespace().map(str::parse).collect::<Result<Vec<u32>, _>>().map_err(|_| bad())?;
        Ok(Some(Share { k, n, rows }))
    }

    /// This process's rollout workers: `total` (the user's --jobs, or the machine's cores) shared
    /// out, rounding up.
    pub fn jobs(&self, total: usize) -> usize {
        total.div_ceil(self.n).max(1)
    }
}

/// The pending rows dealt out in turn: process k gets `pending[k]`, `pending[k + n]`, ... The rows
/// are in task order, so each process gets its turn of every task, and a resume deals what is
/// left of every process's share afresh.
pub fn deal(pending: &[u32], n: usize) -> Vec<Vec<u32>> {
    (0..n).map(|k| pending.iter().copied().skip(k).step_by(n).collect()).collect()
}

/// The processes a run takes when the user does not say: one per GPU where the policy's
/// `devices=` lists two or more distinct CUDA devices and nothing else, else 1. Why the default:
/// on two H200s a process per GPU ran 1.956× and 1.986× one GPU's rate, one process 1.849× (its
/// one GL thread renders both GPUs' cameras; `data/benchmarks/gpu-two-h200-processes-2026-11-29`).
/// A list with the CPU in it, or one GPU twice (replicas sharing a device), stays in one process:
/// neither has a second GPU to render on.
pub fn one_per_gpu(policy: &PolicySpec) -> usize {
    // as many distinct GPUs as listed devices: no CPU in the list, no GPU twice
    let distinct: std::collections::BTreeSet<usize> = policy.model_cuda_devices().into_iter().collect();
    let listed = policy.model_devices_listed();
    if listed >= 2 && distinct.len() == listed { listed } else { 1 }
}

/// Said on stderr as the processes start: why N processes where the user did not ask for them
/// (`by_default`), and, where the policy's model is on GPUs, that a set `MUJOCO_EGL_DEVICE_ID`
/// sends every process's cameras to one device (which may be meant, as with Mesa's software
/// device, but costs the split its point).
pub fn say_how(policy: &PolicySpec, n: usize, by_default: bool) {
    if by_default {
        eprintln!(
            "{n} processes, one per GPU the policy lists: each runs its share of the episodes with its model and its cameras on its own GPU (--processes 1 runs them all in this process)"
        );
    }
    if let Ok(device) = std::env::var("MUJOCO_EGL_DEVICE_ID")
        && !policy.model_cuda_devices().is_empty()
    {
        eprintln!(
            "MUJOCO_EGL_DEVICE_ID={device} is set, so all {n} processes render their cameras on EGL device {device}, not each on its own GPU: unset it for that"
        );
    }
}

/// Each process's policy ([`PolicySpec::device_share`]): a device list shorter than N, or a model
/// policy without one, is an error naming it.
pub fn policies(policy: &PolicySpec, n: usize) -> Result<Vec<PolicySpec>> {
    (0..n).map(|k| policy.device_share(k, n).map_err(anyhow::Error::msg)).collect()
}

/// [`policies`], checked before anything is written, and devices that do not divide into N equal
/// shares said on stderr: some processes then serve more GPUs with the same workers.
pub fn check(policy: &PolicySpec, n: usize) -> Result<()> {
    let counts: Vec<usize> = policies(policy, n)?.iter().map(PolicySpec::model_devices_listed).collect();
    if counts.iter().any(|&c| c != counts[0]) {
        eprintln!(
            "--processes {n}: the policy's devices do not divide evenly, so the processes hold {counts:?} devices each, with the same number of workers"
        );
    }
    Ok(())
}

/// The children of one `pipeline run --processes`: stopped and reaped if the parent returns
/// before they have ended (an error while starting them, say), so that none writes on into a
/// run nobody watches.
struct Children(Vec<Running>);

/// One started child: its number, its policy share, the process, its last lines and the thread
/// that relays its messages.
struct Running {
    k: usize,
    share: PolicySpec,
    child: Child,
    tail: Arc<Mutex<VecDeque<String>>>,
    relay: std::thread::JoinHandle<()>,
}

impl Drop for Children {
    fn drop(&mut self) {
        for Running { child, .. } in self.0.iter_mut() {
            if matches!(child.try_wait(), Ok(None)) {
                let _ = child.kill();
                let _ = child.wait();
            }
        }
    }
}

/// Start the N children with this process's arguments and [`SHARE_VARIABLE`], relay their
/// messages prefixed with their number, show the run's progress from the parts in `store`, and
/// wait for all. An error naming every child that failed, with its devices and its last lines.
pub async fn run_children(policy: &PolicySpec, pending: &[u32], n: usize, store: &RunStore) -> Result<()> {
    let shares = policies(policy, n)?;
    let exe = std::env::current_exe().context("this binary's path, to start the run's processes")?;
    let args: Vec<std::ffi::OsString> = std::env::args_os().skip(1).collect();
    let before = new_parts(store).await?;
    let rows = deal(pending, n);
    let files: Vec<PathBuf> = (0..n)
        .map(|k| std::env::temp_dir().join(format!("libero-run-{}-process-{k}-of-{n}.rows", std::process::id())))
        .collect();
    let mut children = Children(Vec::new());
    for (k, share) in shares.iter().enumerate() {
        let listed: Vec<String> = rows[k].iter().map(u32::to_string).collect();
        std::fs::write(&files[k], listed.join("\n")).with_context(|| format!("writing {}", files[k].display()))?;
        let value = format!("{k}/{n}:{}:{}", std::process::id(), files[k].display());
        let mut command = Command::new(&exe);
        command.args(&args).env(SHARE_VARIABLE, value).stdout(Stdio::inherit()).stderr(Stdio::piped());
        // SAFETY: prctl is async-signal-safe; it only asks the kernel to signal the child when this
        // process ends, so that a parent killed outright leaves no child running.
        unsafe {
            use std::os::unix::process::CommandExt;
            command.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
                Ok(())
            });
        }
        let mut child = command.spawn().with_context(|| format!("starting process {k}/{n} of the run"))?;
        let stderr = child.stderr.take().expect("piped stderr");
        let tail = Arc::new(Mutex::new(VecDeque::new()));
        let relay = {
            let (label, tail) = (format!("[process {k}/{n}]"), tail.clone());
            // raw lines, decoded leniently: a line that is not UTF-8 (a driver's, a Python
            // library's) must not end the relay, which would close the child's stderr under it
            std::thread::spawn(move || {
                let mut reader = std::io::BufReader::new(stderr);
                let mut line = Vec::new();
                while reader.read_until(b'\n', &mut line).is_ok_and(|n| n > 0) {
                    let text = String::from_utf8_lossy(&line).trim_end().to_string();
                    eprintln!("{label} {text}");
                    let mut tail = tail.lock().expect("tail");
                    if tail.len() == TAIL_LINES {
                        tail.pop_front();
                    }
                    tail.push_back(text);
                    line.clear();
                }
            })
        };
        eprintln!("process {k}/{n}: pid {}, {} episodes, policy {share}", child.id(), rows[k].len());
        children.0.push(Running { k, share: share.clone(), child, tail, relay });
    }
    let progress = indicatif::ProgressBar::new(pending.len() as u64).with_style(
        indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} episodes in {msg} · ETA {eta}",
        )?
        .progress_chars("=> "),
    );
    progress.set_message(format!("{n} processes"));
    let mut statuses: Vec<Option<std::process::ExitStatus>> = vec![None; n];
    while statuses.iter().any(Option::is_none) {
        for Running { k, child, .. } in children.0.iter_mut() {
            if statuses[*k].is_none() {
                statuses[*k] = child.try_wait().with_context(|| format!("waiting for process {k}/{n}"))?;
            }
        }
        if let Ok(now) = new_parts(store).await {
            progress.set_position(now.saturating_sub(before) as u64);
        }
        if statuses.iter().any(Option::is_none) {
            tokio::task::block_in_place(|| std::thread::sleep(std::time::Duration::from_secs(2)));
        }
    }
    progress.finish();
    let mut failed = Vec::new();
    for Running { k, share, tail, relay, .. } in std::mem::take(&mut children.0) {
        let _ = relay.join();
        let _ = std::fs::remove_file(&files[k]);
        let status = statuses[k].expect("every child has ended");
        if !status.success() {
            let tail = tail.lock().expect("tail").iter().map(|l| format!("    {l}")).collect::<Vec<_>>().join("\n");
            failed.push(format!("process {k}/{n} ({share}) ended with {status}; its last lines:\n{tail}"));
        }
    }
    if !failed.is_empty() {
        bail!(
            "{}\nThe episodes those processes had not finished are still pending; the other processes' are stored. If the cause has passed (a lost GPU, a killed process), run the same command again to run them.",
            failed.join("\n")
        );
    }
    Ok(())
}

/// The run's one-episode parts (compacted files hold episodes from before this invocation, and
/// reading them would cost a download each time).
async fn new_parts(store: &RunStore) -> Result<usize> {
    Ok(store.part_names("episodes").await?.iter().filter(|p| !p.starts_with(COMPACT_PREFIX)).count())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pending_rows_are_dealt_out_in_turn_each_to_one_process() {
        let pending: Vec<u32> = vec![0, 1, 2, 5, 6, 9, 10];
        let dealt = deal(&pending, 3);
        assert_eq!(dealt, vec![vec![0, 5, 10], vec![1, 6], vec![2, 9]]);
        let mut all: Vec<u32> = dealt.concat();
        all.sort();
        assert_eq!(all, pending);
        assert_eq!(deal(&[4], 2), vec![vec![4], vec![]]);
        let share = Share { k: 0, n: 4, rows: vec![] };
        assert_eq!(share.jobs(16), 4);
        assert_eq!(share.jobs(2), 1);
        assert_eq!(Share { k: 1, n: 3, rows: vec![] }.to_string(), "1/3");
    }

    #[test]
    fn a_run_takes_a_process_per_gpu_only_where_the_policy_lists_several_distinct_gpus() {
        let processes = |policy: &str| one_per_gpu(&policy.parse::<PolicySpec>().expect(policy));
        assert_eq!(processes("openvla:/ckpt?batch=64&devices=cuda:0,cuda:1"), 2);
        assert_eq!(processes("oft:/ckpt?batch=64&devices=cuda:0,cuda:1,cuda:2,cuda:3"), 4);
        assert_eq!(processes("python:sees:make?devices=cuda:1,cuda:0"), 2);
        // one GPU, replicas sharing a GPU, the CPU in the list, no list, no model: one process
        assert_eq!(processes("openvla:/ckpt?devices=cuda:0"), 1);
        assert_eq!(processes("openvla:/ckpt?batch=64&devices=cuda:0,cuda:0"), 1);
        assert_eq!(processes("openvla:/ckpt?batch=64&devices=cuda:0,cpu"), 1);
        assert_eq!(processes("python:sees:make?devices=cpu,cpu"), 1);
        assert_eq!(processes("openvla:/ckpt"), 1);
        assert_eq!(processes("random"), 1);
    }
}
