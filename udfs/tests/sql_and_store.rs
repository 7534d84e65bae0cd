//! The functions in SQL against independently computed values, and the rollout writing to an
//! object store: one test binary, because each binary links its own copy of DataFusion's query
//! stack (~3 min of a 2-core CI machine apiece).

mod paired_stats_sql;
mod rollout_object_store;
mod wilson_sql;
