//! The rollout UDF writing to an object-store URL (`memory:///`, in-process) instead of a local
//! folder, and DataFusion reading the parts back through the same store: the path `s3://`-style
//! locations take. Real episodes on the real environment (bundles from ./setup.sh).

use arrow::array::{AsArray, RecordBatch};
use arrow::datatypes::Int64Type;
use datafusion::datasource::file_format::parquet::ParquetFormat;
use datafusion::datasource::listing::{ListingOptions, ListingTable, ListingTableConfig, ListingTableUrl};
use datafusion::prelude::SessionContext;
use indicatif::ProgressBar;
use libero_policies::PolicySpec;
use libero_schema::{Suite, tables};
use libero_udfs::rollout::{RolloutContext, RunProtocol, rollout_udf};
use libero_udfs::run_store::RunStore;
use std::collections::BTreeMap;
use std::sync::Arc;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn episodes_written_to_an_object_store_url_are_listed_and_queryable() {
    let bundles = Arc::new(libero_e2e::bundles());
    let store = RunStore::open("memory:///run-under-test/").unwrap();
    assert_eq!(store.base_url().scheme(), "memory");
    let max_steps = BTreeMap::from([(Suite::LIBERO_OBJECT, 5)]);
    let ctx = Arc::new(RolloutContext::new(
        bundles,
        PolicySpec::Lift,
        RunProtocol {
            max_steps,
            aloha_max_steps: 400,
            num_steps_wait: 2,
            stop_on_success: false,
            instruction_source: Default::default(),
            realtime: None,
            protocol: Default::default(),
        },
        "test".into(),
        "{}".into(),
        store.clone(),
        tokio::runtime::Handle::current(),
        ProgressBar::hidden(),
    ));
    let session = SessionContext::new();
    session.register_udf(rollout_udf(ctx));
    session.register_object_store(store.base_url(), store.object_store());
    let sql = "SELECT rollout(suite, task_id, init_state_id, seed)['episode_key'] AS k FROM \
               (VALUES ('libero_object', 0, 0, 7), ('libero_object', 0, 1, 7)) t(suite, task_id, init_state_id, seed) \
               ORDER BY k";
    let out: Vec<RecordBatch> = session.sql(sql).await.unwrap().collect().await.unwrap();
    let keys: Vec<&str> = out[0].column(0).as_string::<i32>().iter().map(Option::unwrap).collect();
    assert_eq!(keys, ["libero_object/0/0/7", "libero_object/0/1/7"]);

    let names = store.part_names("episodes").await.unwrap();
    assert_eq!(names.len(), 2, "{names:?}");
    assert_eq!(store.part_names("steps").await.unwrap(), names);

    let url = ListingTableUrl::parse(store.table_url("steps/")).unwrap();
    let options = ListingOptions::new(Arc::new(ParquetFormat::default())).with_file_extension(".parquet");
    let config = ListingTableConfig::new(url).with_listing_options(options).with_schema(tables::steps());
    session.register_table("steps", Arc::new(ListingTable::try_new(config).unwrap())).unwrap();
    let counts = session.sql("SELECT count(*), count(policy_step) FROM steps").await.unwrap().collect().await.unwrap();
    assert_eq!(counts[0].column(0).as_primitive::<Int64Type>().value(0), 2 * (2 + 5));
    assert_eq!(counts[0].column(1).as_primitive::<Int64Type>().value(0), 2 * 5);
}
