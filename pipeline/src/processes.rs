//! `pipeline run --processes N`: a run's pending episodes dealt to N processes of this binary, each
//! with its share of the policy's `devices=`, of `--jobs`, and its own GL thread on its own GPU.
//!
//! Why: a process renders all its cameras through one GL thread, because the NVIDIA driver
//! serialises a process's GL contexts whichever GPUs they are on (`libero_sim::gl_thread`). A
//! process with model replicas on four H200s rendered through that one thread at 347.7 ms a step
//! and ran 2.69× one GPU (issue 46). N processes are a one-GPU machine N times over: each has its
//! model and its renders on its own GPU, and its own workers.
//!
//! How: the parent (the `pipeline run` the user started) writes the manifest and the spec table as
//! any run does, then starts N children with the same arguments and `--process-share k/N`. Child k
//! runs the spec rows whose index is k modulo N (every task's trials dealt out in turn) that are not
//! finished, with [`PolicySpec::device_share`]'s devices, and writes its episodes' parts and its
//! session record into the same run, as a resumed run would. The parent shows the whole run's
//! progress from the finished parts, passes each child's messages on with its number, and, when
//! all have ended, compacts and prints the results. A child that fails (a GPU lost, say) leaves its
//! unfinished episodes pending; the others go on, and the parent then stops naming that child's
//! devices and the command that resumes the run.

use anyhow::{Context, Result, bail};
use libero_policies::PolicySpec;
use libero_udfs::compaction;
use libero_udfs::run_store::RunStore;
use std::io::BufRead;
use std::process::{Command, Stdio};

/// Which of a run's processes this one is (`--process-share k/N`, set by the parent).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Share {
    pub k: usize,
    pub n: usize,
}

impl std::str::FromStr for Share {
    type Err = String;
    fn from_str(s: &str) -> Result<Share, String> {
        let parsed = s.split_once('/').and_then(|(k, n)| Some((k.parse().ok()?, n.parse().ok()?)));
        match parsed {
            Some((k, n)) if k < n => Ok(Share { k, n }),
            _ => Err(format!("{s:?} is not a process share: K/N with K < N (set by `pipeline run --processes N`)")),
        }
    }
}

impl std::fmt::Display for Share {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

impl Share {
    /// Whether spec row `index` is this process's: every N-th row from the K-th, so that each
    /// process gets its turn of every task's trials (the rows are in task order).
    pub fn owns(self, index: u32) -> bool {
        index as usize % self.n == self.k
    }

    /// This process's rollout workers: `total` (the user's --jobs, or the machine's cores) shared
    /// out, rounding up.
    pub fn jobs(self, total: usize) -> usize {
        total.div_ceil(self.n).max(1)
    }
}

/// Each process's policy, checked before any process starts (a device list shorter than N stops
/// the run here, naming it).
pub fn policies(policy: &PolicySpec, n: usize) -> Result<Vec<PolicySpec>> {
    (0..n).map(|k| policy.device_share(k, n).map_err(anyhow::Error::msg)).collect()
}

/// Start the N children with this process's arguments and `--process-share k/N`, relay their
/// messages prefixed with their number, show the run's progress from the finished parts in
/// `store`, and wait for all. An error naming every child that failed, its devices and the
/// command that resumes the run.
pub async fn run_children(policy: &PolicySpec, n: usize, pending: usize, store: &RunStore) -> Result<()> {
    let shares = policies(policy, n)?;
    let exe = std::env::current_exe().context("this binary's path, to start the run's processes")?;
    let args: Vec<std::ffi::OsString> = std::env::args_os().skip(1).collect();
    let before = compaction::finished_part_names(store).await?.len();
    let mut children = Vec::new();
    for (k, share) in shares.iter().enumerate() {
        let share_arg = Share { k, n }.to_string();
        let mut child = Command::new(&exe)
            .args(&args)
            .args(["--process-share", &share_arg])
            .stdout(Stdio::inherit())
            .stderr(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting process {share_arg} of the run"))?;
        let stderr = child.stderr.take().expect("piped stderr");
        let label = format!("[process {share_arg}]");
        let relay = std::thread::spawn(move || {
            for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("{label} {line}");
            }
        });
        eprintln!("process {share_arg}: pid {}, policy {share}", child.id());
        children.push((k, share, child, relay));
    }
    let progress = indicatif::ProgressBar::new(pending as u64).with_style(
        indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} episodes in {msg} · ETA {eta}",
        )?
        .progress_chars("=> "),
    );
    progress.set_message(format!("{n} processes"));
    let mut statuses: Vec<Option<std::process::ExitStatus>> = vec![None; n];
    while statuses.iter().any(Option::is_none) {
        for (k, _, child, _) in children.iter_mut() {
            if statuses[*k].is_none() {
                statuses[*k] = child.try_wait()?;
            }
        }
        if let Ok(now) = compaction::finished_part_names(store).await {
            progress.set_position(now.len().saturating_sub(before) as u64);
        }
        tokio::task::block_in_place(|| std::thread::sleep(std::time::Duration::from_millis(500)));
    }
    progress.finish();
    let mut failed = Vec::new();
    for (k, share, _, relay) in children {
        let _ = relay.join();
        let status = statuses[k].expect("every child has ended");
        if !status.success() {
            failed.push(format!("process {k}/{n} ({share}) ended with {status}"));
        }
    }
    if !failed.is_empty() {
        bail!(
            "{}.\nThe episodes those processes had not finished are still pending; the other processes' are stored. Run the same command again to resume them.",
            failed.join("; ")
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_parse_and_deal_every_row_to_one_process() {
        let shares: Vec<Share> = (0..3).map(|k| format!("{k}/3").parse().unwrap()).collect();
        for i in 0..30u32 {
            assert_eq!(shares.iter().filter(|s| s.owns(i)).count(), 1, "row {i}");
        }
        assert_eq!(shares[1].to_string(), "1/3");
        assert!("3/3".parse::<Share>().is_err());
        assert!("x".parse::<Share>().unwrap_err().contains("K/N"));
        assert_eq!(shares[0].jobs(16), 6);
        assert_eq!(Share { k: 0, n: 4 }.jobs(2), 1);
    }
}
