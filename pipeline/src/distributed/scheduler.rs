//! `pipeline scheduler`: Ballista's scheduler, planning with our functions (it never runs an
//! episode; the executors do).

use super::run_config::{PlanOnly, config_producer, session_state};
use anyhow::{Context, Result};
use ballista_scheduler::cluster::BallistaCluster;
use ballista_scheduler::config::SchedulerConfig;
use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::Arc;

pub const EXAMPLES: &str = "\
Examples:
  pipeline scheduler --bind 0.0.0.0 --port 50050                # on one machine, SCHED
  pipeline executor --scheduler SCHED:50050 --bind 0.0.0.0 --external-host $(hostname)
  pipeline run specs.parquet --out s3://bucket/run --policy expert --engine ballista://SCHED:50050";

#[derive(clap::Args)]
pub struct Args {
    /// Address to listen on (0.0.0.0 to accept executors and clients from other machines).
    #[arg(long, default_value = "127.0.0.1")]
    bind: String,
    /// gRPC port: executors register and clients submit here (`--engine ballista://HOST:PORT`).
    #[arg(long, default_value_t = 50050)]
    port: u16,
    /// Seconds without a heartbeat after which an executor counts as lost and its tasks run
    /// elsewhere (keep it at least 3x the executors' --heartbeat-s).
    #[arg(long, default_value_t = 60)]
    executor_timeout_s: u64,
    /// How often lost executors are looked for, in seconds.
    #[arg(long, default_value_t = 5)]
    expire_interval_s: u64,
}

pub fn run(args: Args) -> Result<()> {
    let address: SocketAddr = (args.bind.as_str(), args.port)
        .to_socket_addrs()
        .with_context(|| format!("--bind {} --port {}: not an address to listen on", args.bind, args.port))?
        .next()
        .context("no address to listen on")?;
    let config = SchedulerConfig {
        bind_host: args.bind.clone(),
        bind_port: args.port,
        executor_timeout_seconds: args.executor_timeout_s,
        expire_dead_executor_interval_seconds: args.expire_interval_s,
        no_executors_grace_period_seconds: args.executor_timeout_s,
        override_config_producer: Some(Arc::new(config_producer)),
        override_session_builder: Some(Arc::new(|config| session_state(config, Arc::new(PlanOnly)))),
        ..Default::default()
    };
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async move {
        let cluster = BallistaCluster::new_from_config(&config).await?;
        eprintln!("pipeline scheduler listening on {address} (Ballista {})", ballista_core::BALLISTA_VERSION);
        ballista_scheduler::scheduler_process::start_server(cluster, address, Arc::new(config))
            .await
            .with_context(|| format!("the scheduler on {address} stopped"))
    })
}
