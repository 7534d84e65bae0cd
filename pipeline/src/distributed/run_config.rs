//! What every node of a Ballista cluster shares: the `libero.*` configuration keys that carry a
//! run to the tasks, and the session state (our functions, object stores) each node plans with.
//!
//! Ballista sends a session's configuration with every task, but only keys that the receiving
//! node's config producer knows survive (others are dropped without a word), so the client, the
//! scheduler and the executors all build their configuration with [`config_producer`]. Likewise
//! the client's `remote_with_state` replaces the session's scalar functions with Ballista's own,
//! so our functions are registered on a remote session after it is made ([`register_functions`]).

use ballista_core::extension::SessionConfigExt;
use datafusion::common::{DataFusionError, Result};
use datafusion::execution::SessionState;
use datafusion::execution::SessionStateBuilder;
use datafusion::execution::cache::cache_manager::CacheManagerConfig;
use datafusion::execution::object_store::{DefaultObjectStoreRegistry, ObjectStoreRegistry};
use datafusion::execution::runtime_env::{RuntimeEnv, RuntimeEnvBuilder};
use datafusion::prelude::{SessionConfig, SessionContext};
use libero_udfs::rollout::{RunResolver, resolved_rollout_udf};
use object_store::ObjectStore;
use std::sync::Arc;
use url::Url;

/// The run a distributed `rollout` belongs to (keys `libero.*`), set by `pipeline run` and read by
/// the executors' `rollout` from each task's configuration.
#[derive(Debug, Clone, Default)]
pub struct LiberoRun {
    /// The run location (an object-store URL, or a file:// folder every node mounts).
    pub location: String,
    /// The run manifest as JSON: policy, protocol, build, MuJoCo and bundles the run is made with.
    pub manifest: String,
    /// The tasks of the run's spec table, `suite/task_id` comma-separated: the bundles hash covers these.
    pub tasks: String,
    /// Sleep this long before each episode (tests that kill an executor mid-run only).
    pub episode_delay_ms: u64,
}

impl datafusion::config::ConfigExtension for LiberoRun {
    const PREFIX: &'static str = "libero";
}

/// Written by hand, not with `extensions_options!`: that macro lists its entries without the
/// prefix (`location`, not `libero.location`), and Ballista sends a session's configuration as
/// its entries, so a receiving node could not tell them apart and dropped them all.
impl datafusion::config::ExtensionOptions for LiberoRun {
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn cloned(&self) -> Box<dyn datafusion::config::ExtensionOptions> {
        Box::new(self.clone())
    }

    fn set(&mut self, key: &str, value: &str) -> Result<()> {
        match key {
            "location" => self.location = value.to_string(),
            "manifest" => self.manifest = value.to_string(),
            "tasks" => self.tasks = value.to_string(),
            "episode_delay_ms" => {
                self.episode_delay_ms = value.parse().map_err(|_| {
                    DataFusionError::Configuration(format!("libero.episode_delay_ms: {value:?} is not a number"))
                })?
            }
            _ => return Err(DataFusionError::Configuration(format!("no configuration key libero.{key}"))),
        }
        Ok(())
    }

    fn entries(&self) -> Vec<datafusion::config::ConfigEntry> {
        let entry = |key: &str, value: String, description: &'static str| datafusion::config::ConfigEntry {
            key: format!("{}.{key}", <Self as datafusion::config::ConfigExtension>::PREFIX),
            value: Some(value),
            description,
        };
        vec![
            entry("location", self.location.clone(), "the run location"),
            entry("manifest", self.manifest.clone(), "the run manifest as JSON"),
            entry("tasks", self.tasks.clone(), "the run's tasks, suite/task_id comma-separated"),
            entry("episode_delay_ms", self.episode_delay_ms.to_string(), "sleep before each episode (tests)"),
        ]
    }
}

/// The configuration every node starts from: Ballista's, with the `libero.*` keys known.
pub fn config_producer() -> SessionConfig {
    SessionConfig::new_with_ballista().with_information_schema(true).with_option_extension(LiberoRun::default())
}

/// Whether a session runs on Ballista (its configuration knows the `libero.*` keys).
pub fn is_distributed(ctx: &SessionContext) -> bool {
    ctx.state().config().options().extensions.get::<LiberoRun>().is_some()
}

/// The runtime every node reads and lists run locations with: object stores made on first use
/// from the URL and the AWS_* / GOOGLE_* / AZURE_* variables (as `RunStore` opens them), and no
/// cache of file listings, which would keep a long-lived scheduler from seeing new episode parts.
pub fn runtime_env() -> Result<Arc<RuntimeEnv>> {
    RuntimeEnvBuilder::new()
        .with_object_store_registry(Arc::new(RunStoreRegistry::default()))
        .with_cache_manager(CacheManagerConfig::default().with_list_files_cache_limit(0))
        .build_arc()
}

/// The session state a node plans and runs with: DataFusion's defaults, our analysis functions,
/// and `rollout` resolving its run with `resolver`.
pub fn session_state(config: SessionConfig, resolver: Arc<dyn RunResolver>) -> Result<SessionState> {
    let state =
        SessionStateBuilder::new().with_config(config).with_default_features().with_runtime_env(runtime_env()?).build();
    let ctx = SessionContext::new_with_state(state);
    register_functions(&ctx, resolver);
    Ok(ctx.state())
}

/// Register our functions on a session (after `remote_with_state`, which would drop them).
pub fn register_functions(ctx: &SessionContext, resolver: Arc<dyn RunResolver>) {
    libero_udfs::register_analysis_functions(ctx);
    ctx.register_udf(resolved_rollout_udf(resolver));
}

/// The `rollout` of nodes that plan but never run episodes (the scheduler, the client).
#[derive(Debug)]
pub struct PlanOnly;

impl RunResolver for PlanOnly {
    fn resolve(
        &self,
        _config: &datafusion::config::ConfigOptions,
    ) -> Result<Arc<libero_udfs::rollout::RolloutContext>> {
        Err(DataFusionError::Execution(
            "rollout() ran on a node that only plans (a scheduler or a client); episodes run on `pipeline executor`s"
                .into(),
        ))
    }
}

/// Object stores by URL: registered ones, else made from the URL and the environment.
#[derive(Debug, Default)]
struct RunStoreRegistry {
    registered: DefaultObjectStoreRegistry,
}

impl ObjectStoreRegistry for RunStoreRegistry {
    fn register_store(&self, url: &Url, store: Arc<dyn ObjectStore>) -> Option<Arc<dyn ObjectStore>> {
        self.registered.register_store(url, store)
    }

    fn deregister_store(&self, url: &Url) -> Result<Arc<dyn ObjectStore>> {
        self.registered.deregister_store(url)
    }

    fn get_store(&self, url: &Url) -> Result<Arc<dyn ObjectStore>> {
        if let Ok(store) = self.registered.get_store(url) {
            return Ok(store);
        }
        let store = libero_udfs::run_store::RunStore::open(url.as_str())
            .map_err(|e| DataFusionError::Execution(format!("{e:#}")))?
            .object_store();
        let base = Url::parse(&format!("{}://{}", url.scheme(), url.authority()))
            .map_err(|e| DataFusionError::Execution(e.to_string()))?;
        self.registered.register_store(&base, store.clone());
        Ok(store)
    }
}
