//! The end-to-end tests of the binary, the bundles and the reference parity, one module a concern,
//! all in one test binary (see `Cargo.toml`: one link of the DataFusion stack instead of one per
//! module); each module's file lies beside this one.
//! Modules share the process: each test writes under its own `test_dir(<module>, <case>)`.

mod aloha_run;
mod bundles;
mod cli;
mod cloud_store;
mod compaction;
mod compare;
mod cpu_fallback;
mod dataflow;
mod distributed;
mod docs;
mod doctor;
mod ensembling;
mod env;
mod expert;
mod export;
mod failure_modes;
mod generalisation;
mod lerobot_protocol;
mod libero_plus;
mod media;
mod noise;
mod notebook;
mod oft;
mod openvla;
mod paired_stats_sql;
mod parity;
mod plus_layout;
mod pro;
mod pro_occlusion;
mod pro_robustness;
mod processes;
mod python_policy;
mod readme;
mod real_time;
mod remote_policy;
mod render;
mod report;
mod rollout_object_store;
mod setup_script;
mod starvla_policy;
mod torchscript;
mod vla_eval_policy;
mod wilson_sql;
