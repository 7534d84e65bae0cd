//! The client side: `pipeline run --engine ballista://` sends the pending episodes to the cluster,
//! and the query commands open their session there.

use super::run_config::{LiberoRun, PlanOnly, config_producer, register_functions, runtime_env};
use anyhow::{Context, Result, bail};
use arrow::array::RecordBatch;
use ballista::prelude::SessionContextExt;
use ballista_core::extension::SessionConfigExt;
use ballista_core::serde::protobuf::GetJobStatusParams;
use ballista_core::serde::protobuf::scheduler_grpc_client::SchedulerGrpcClient;
use ballista_core::utils::{GrpcClientConfig, create_grpc_client_connection};
use datafusion::execution::SessionStateBuilder;
use datafusion::prelude::{ParquetReadOptions, SessionContext};
use indicatif::ProgressBar;
use libero_schema::Suite;
use libero_udfs::run_store::{RunStore, parquet_bytes};
use std::collections::{BTreeSet, HashSet};
use std::sync::Arc;

/// At most this many pending files (partitions) per run: one episode each up to here, then a few
/// consecutive episodes each; Ballista deals them to free executor slots as slots free up.
const MAX_PARTITIONS: usize = 2000;

/// Stop before anything starts when no scheduler answers at HOST:PORT.
pub async fn check_scheduler(host: &str, port: u16) -> Result<()> {
    let url = format!("http://{host}:{port}");
    let config = GrpcClientConfig { connect_timeout_seconds: 5, timeout_seconds: 10, ..Default::default() };
    let unreachable = |why: String| {
        anyhow::anyhow!(
            "no Ballista scheduler answers at {host}:{port} ({why}). Start one with `pipeline scheduler --bind {host} --port {port}` (and `pipeline executor --scheduler {host}:{port}` on each worker machine), or fix --engine."
        )
    };
    let channel = create_grpc_client_connection(url, &config).await.map_err(|e| unreachable(format!("{e}")))?;
    let mut client = SchedulerGrpcClient::new(channel);
    // Any answer, "no such job" included, is a scheduler's; only a transport failure is not.
    match client.get_job_status(GetJobStatusParams { job_id: "pipeline-reachability-check".into() }).await {
        Ok(_) => Ok(()),
        Err(status) if format!("{:?}", status.code()) == "Unavailable" => {
            Err(unreachable(status.message().to_string()))
        }
        Err(_) => Ok(()),
    }
}

/// A session on the cluster, with our functions, for the query commands.
pub async fn remote_session(host: &str, port: u16) -> Result<SessionContext> {
    check_scheduler(host, port).await?;
    let state = SessionStateBuilder::new()
        .with_config(config_producer())
        .with_default_features()
        .with_runtime_env(runtime_env()?)
        .build();
    let ctx = SessionContext::remote_with_state(&format!("df://{host}:{port}"), state).await?;
    register_functions(&ctx, Arc::new(PlanOnly));
    Ok(ctx)
}

/// What a distributed run sends with its query.
pub struct DistributedRun<'a> {
    pub host: &'a str,
    pub port: u16,
    pub store: &'a RunStore,
    pub manifest_json: String,
    pub run_config: &'a str,
    pub tasks: &'a BTreeSet<(Suite, u32)>,
    /// The part names of the pending episodes (what the progress bar counts).
    pub pending_parts: HashSet<String>,
    /// Test knob: each episode sleeps this long first (to kill an executor mid-run).
    pub episode_delay_ms: u64,
}

impl DistributedRun<'_> {
    /// Run the pending spec rows on the cluster: written as Parquet files of consecutive rows
    /// under `pending/<attempt>/`, one partition each, and `rollout(...)` over them. Returns the
    /// number of partitions.
    pub async fn run(&self, pending: &RecordBatch, extras_arg: &str, progress: &ProgressBar) -> Result<usize> {
        let store = self.store;
        if store.url().scheme() == "memory" {
            bail!(
                "a memory:// run cannot be shared with executors: use an object store (s3://, gs://) or a shared folder"
            );
        }
        let n = pending.num_rows();
        let partitions = n.clamp(1, MAX_PARTITIONS);
        let rows_per_partition = n.div_ceil(partitions);
        let attempt = format!("pending/{}-{}/", chrono::Utc::now().format("%Y%m%dT%H%M%S"), std::process::id());
        let mut written = 0;
        for (i, start) in (0..n).step_by(rows_per_partition).enumerate() {
            let rows = pending.slice(start, rows_per_partition.min(n - start));
            store.put(&format!("{attempt}part-{i:05}.parquet"), parquet_bytes(&rows, None)?).await?;
            written += 1;
        }
        let run = LiberoRun {
            location: store.url().to_string(),
            manifest: self.manifest_json.clone(),
            tasks: self.tasks.iter().map(|(s, t)| format!("{}/{t}", s.name())).collect::<Vec<_>>().join(","),
            episode_delay_ms: self.episode_delay_ms,
        };
        let mut config = config_producer()
            .with_option_extension(run)
            .with_target_partitions(written)
            .with_ballista_job_name(&format!("libero run {} ({})", store.url(), self.run_config));
        // One partition per task, so that a retry or a lost executor re-runs one episode's worth.
        config.options_mut().set("ballista.scheduler.max_partitions_per_task", "1")?;
        let state = SessionStateBuilder::new()
            .with_config(config)
            .with_default_features()
            .with_runtime_env(runtime_env()?)
            .build();
        let ctx = SessionContext::remote_with_state(&format!("df://{}:{}", self.host, self.port), state).await?;
        register_functions(&ctx, Arc::new(PlanOnly));
        ctx.register_parquet("pending", store.table_url(&attempt), ParquetReadOptions::default()).await?;
        let sql = format!("SELECT rollout(suite, task_id, init_state_id, seed{extras_arg}) AS r FROM pending");

        // The executors cannot move this process's progress bar: it follows the episode parts.
        let keys = self.pending_parts.clone();
        let watch = {
            let (store, progress) = (store.clone(), progress.clone());
            tokio::spawn(async move {
                loop {
                    if let Ok(parts) = store.part_names("episodes").await {
                        progress.set_position(parts.iter().filter(|p| keys.contains(*p)).count() as u64);
                    }
                    tokio::time::sleep(std::time::Duration::from_secs(2)).await;
                }
            })
        };
        let ran = async { ctx.sql(&sql).await?.collect().await }.await;
        watch.abort();
        // The pending files served this attempt only; a resume lists what is left anew.
        for i in 0..written {
            store.delete_if_present(&format!("{attempt}part-{i:05}.parquet")).await?;
        }
        ran.with_context(|| {
            format!("the rollout query failed on the Ballista cluster at {}:{}", self.host, self.port)
        })?;
        Ok(written)
    }
}
