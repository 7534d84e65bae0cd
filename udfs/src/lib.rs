//! # libero-udfs
//!
//! The DataFusion functions of the pipeline, and the run storage they write to:
//!
//! - [`rollout`]: the `rollout(suite, task_id, init_state_id, seed [, extras])` UDF, which runs
//!   each spec row's episode (env + policy, in parallel across cores) and writes its steps and its
//!   episode row as Parquet parts to the run's object store;
//! - [`wilson`]: `wilson(success [, level])` aggregate and `wilson_lo` / `wilson_hi` scalars;
//! - [`run_store`]: the layout of a run on an object store (parts, manifest, resume);
//! - [`steps_batch`] / [`episode`]: building the Arrow rows of one episode.
//!
//! The only crate besides `pipeline` that joins `sim` and `policies`.

pub mod episode;
pub mod rollout;
pub mod run_store;
pub mod scene_view;
pub mod steps_batch;
pub mod wilson;

use datafusion::prelude::SessionContext;

/// Register the analysis functions (`wilson`, `wilson_lo`, `wilson_hi`) on a session.
pub fn register_analysis_functions(ctx: &SessionContext) {
    ctx.register_udaf(wilson::wilson_udaf());
    ctx.register_udf(wilson::wilson_lo_udf());
    ctx.register_udf(wilson::wilson_hi_udf());
}
