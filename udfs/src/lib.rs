//! # libero-udfs
//!
//! The DataFusion functions of the pipeline, and the run storage they write to:
//!
//! - [`rollout`]: the `rollout(suite, task_id, init_state_id, seed [, extras])` UDF, which runs
//!   each spec row's episode (env + policy, in parallel across cores) and writes its steps and its
//!   episode row as Parquet parts to the run's object store;
//! - [`wilson`]: `wilson(success [, level])` aggregate and `wilson_lo` / `wilson_hi` scalars;
//! - [`mcnemar`], [`newcombe`]: paired comparison of two runs, `mcnemar_exact_p(b, c)` and
//!   `newcombe_paired_lo` / `newcombe_paired_hi(n11, n10, n01, n00 [, level])`;
//! - [`sample_size`]: `sample_size_two_proportions(p1, p2 [, alpha [, power]])`;
//! - [`run_store`]: the layout of a run on an object store (parts, manifest, resume, damaged
//!   parts); [`compaction`]: merging a run's parts into a few large files, crash-safe;
//! - [`steps_batch`] / [`episode`]: building the Arrow rows of one episode; [`aloha_episode`]:
//!   the same for an ALOHA-sim episode (its own steps table, the same episode row);
//! - [`goal_evidence`]: the goal's changes per episode (compact re-scoring evidence) and
//!   `goal_held_at(goal_changes, step)`;
//! - [`scene_view`] / [`policy_cameras`]: what a policy may see besides proprio: the privileged
//!   scene (scripted experts) and the two cameras (learned policies);
//! - [`real_time`]: an episode's real-time clock (`pipeline run --latency-ms`) and the hold actions.
//!
//! The only crate besides `pipeline` that joins `sim` and `policies`.

pub mod aloha_episode;
pub mod compaction;
pub mod episode;
pub mod goal_evidence;
pub mod mcnemar;
pub mod newcombe;
pub mod perturbation;
pub mod policy_cameras;
pub mod real_time;
pub mod rollout;
pub mod run_store;
pub mod sample_size;
pub mod scene_view;
pub mod steps_batch;
pub mod wilson;

use datafusion::prelude::SessionContext;

/// Register the analysis functions (`wilson`, `wilson_lo`, `wilson_hi`, `mcnemar_exact_p`,
/// `newcombe_paired_lo`, `newcombe_paired_hi`, `sample_size_two_proportions`, `goal_held_at`) on a session.
pub fn register_analysis_functions(ctx: &SessionContext) {
    ctx.register_udaf(wilson::wilson_udaf());
    ctx.register_udf(wilson::wilson_lo_udf());
    ctx.register_udf(wilson::wilson_hi_udf());
    ctx.register_udf(mcnemar::mcnemar_exact_p_udf());
    ctx.register_udf(newcombe::newcombe_paired_lo_udf());
    ctx.register_udf(newcombe::newcombe_paired_hi_udf());
    ctx.register_udf(sample_size::sample_size_two_proportions_udf());
    ctx.register_udf(goal_evidence::goal_held_at_udf());
}
