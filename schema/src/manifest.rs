//! The run manifest: everything that determines a run's steps, stored with the run.
//!
//! Written as `manifest.json` and `manifest.parquet` (schema [`crate::tables::manifest`]) in the
//! run directory and as Parquet key-value metadata in every part. `run_config` is a hash of the
//! fields that change the steps; resuming a run with a different configuration is refused.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunManifest {
    pub tables_version: u32,
    /// Hash of the fields that change the steps (see [`RunManifest::config_fingerprint`]).
    pub run_config: String,
    pub created_at: String,
    pub git_revision: String,
    pub pipeline_version: String,
    pub mujoco_version: String,
    pub bundle_format_version: u32,
    pub bundles_hash: String,
    pub policy: String,
    /// Checkpoint hash, unnorm key, chunking, image preprocessing, parameters (policy-defined).
    pub policy_identity: serde_json::Value,
    pub num_steps_wait: i32,
    /// Episode cap in policy steps per suite name (the run's suites).
    pub max_steps: BTreeMap<String, i32>,
    /// Which instruction text the policy is given (`pipeline run --instruction`); runs made before
    /// bundle format 3 gave the BDDL text.
    #[serde(default = "bddl_before_format_3")]
    pub instruction_source: crate::InstructionSource,
    pub stop_on_success: bool,
    pub substeps_per_step: i32,
    pub control_freq_hz: i32,
    /// The run's simulated benchmark (`libero`, `aloha_sim`): which steps table its parts hold.
    /// Runs made before tables v7 were all LIBERO. Stored as `env`, since a spec table's own
    /// `benchmark` column (LIBERO-Plus, LIBERO-PRO robustness) names the protocol of its rows.
    #[serde(default = "libero")]
    pub env: crate::Benchmark,
    /// Real-time evaluation (`pipeline run --latency-ms`): the latency model and the hold action;
    /// absent for a closed-loop run (the env waits for every answer), as in every run before
    /// tables v8.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub realtime: Option<crate::real_time::RealTime>,
    /// Which published loop the run's LIBERO episodes reproduce (the spec column `protocol`): how
    /// the env was seeded and the caps' source. Canonical in every run before tables v9.
    #[serde(default)]
    pub protocol: crate::EvalProtocol,
}

fn libero() -> crate::Benchmark {
    crate::Benchmark::Libero
}

fn bddl_before_format_3() -> crate::InstructionSource {
    crate::InstructionSource::Bddl
}

impl RunManifest {
    /// The canonical text of what changes the steps; `run_config` is its hash. Creation time and
    /// git revision are provenance, not configuration.
    pub fn config_fingerprint(&self) -> String {
        let mut config = serde_json::json!({
            "tables_version": self.tables_version,
            "mujoco_version": self.mujoco_version,
            "bundle_format_version": self.bundle_format_version,
            "bundles_hash": self.bundles_hash,
            "policy": self.policy,
            "policy_identity": self.policy_identity,
            "num_steps_wait": self.num_steps_wait,
            "max_steps": self.max_steps,
            "instruction_source": self.instruction_source,
            "stop_on_success": self.stop_on_success,
            "substeps_per_step": self.substeps_per_step,
            "control_freq_hz": self.control_freq_hz,
            "env": self.env,
        });
        // only when set: a closed-loop run's configuration reads as it did before the setting
        // existed (tables_version, in it too, still tells the layouts apart)
        if let Some(rt) = &self.realtime {
            config["realtime"] = serde_json::json!(rt);
        }
        // likewise: a canonical run's configuration reads as before the setting existed
        if self.protocol != crate::EvalProtocol::Canonical {
            config["protocol"] = serde_json::json!(self.protocol);
        }
        config.to_string()
    }

    /// Fields whose values differ between two manifests' configurations, for a resume error.
    pub fn config_differences(&self, other: &RunManifest) -> Vec<String> {
        let (a, b): (serde_json::Value, serde_json::Value) = (
            serde_json::from_str(&self.config_fingerprint()).unwrap_or_default(),
            serde_json::from_str(&other.config_fingerprint()).unwrap_or_default(),
        );
        let (Some(a), Some(b)) = (a.as_object(), b.as_object()) else {
            return vec![];
        };
        let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
        let shown = |v: Option<&serde_json::Value>| v.map_or("(none)".to_string(), |v| v.to_string());
        keys.into_iter()
            .filter(|k| a.get(*k) != b.get(*k))
            .map(|k| format!("{k}: stored {} vs now {}", shown(b.get(k)), shown(a.get(k))))
            .collect()
    }
}
