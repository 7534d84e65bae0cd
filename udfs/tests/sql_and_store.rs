//! The functions in SQL against independently computed values, and the rollout writing to an
//! object store: one test binary, because each binary links its own copy of DataFusion's query
//! stack (~3 min of a 2-core CI machine apiece).

#[path = "sql_and_store/paired_stats_sql.rs"]
mod paired_stats_sql;
#[path = "sql_and_store/rollout_object_store.rs"]
mod rollout_object_store;
#[path = "sql_and_store/wilson_sql.rs"]
mod wilson_sql;
