//! Runs and queries on Apache Ballista: `pipeline scheduler`, `pipeline executor` and
//! `--engine ballista://host:port` on `run`, `sql`, `results`, `failures` and `report`.
//!
//! The dataflow is the local one: `SELECT rollout(...) FROM pending` and the `queries/*.sql`.
//! Ballista plans it on our scheduler and runs its partitions on our executors, which carry the
//! same functions (`rollout` and the analysis functions). What the engine does not give, the run
//! keeps itself, as it does locally: one atomic part per episode, and a `rollout` on an executor
//! returns an episode whose part exists instead of running it again ([`RolloutContext::
//! skipping_stored_episodes`]), so Ballista's task re-runs (a retry, a lost executor's tasks) and a
//! re-run of `pipeline run` lose and duplicate nothing.
//!
//! - [`run_config`]: the `libero.*` configuration keys that carry a run from the client through
//!   the scheduler to each task, and the session state every node builds (functions, object stores);
//! - [`scheduler`] / [`executor`]: the two server commands; the executor checks a run's manifest
//!   against its own build, MuJoCo and bundles before it runs any episode of it;
//! - [`client`]: `pipeline run --engine ballista://`: the pending rows as many Parquet files, one
//!   partition each, and the query; the remote session of the query commands.
//!
//! [`RolloutContext::skipping_stored_episodes`]: libero_udfs::rollout::RolloutContext::skipping_stored_episodes

pub mod client;
pub mod executor;
pub mod run_config;
pub mod scheduler;
