//! Compacting a run: its thousands of one-episode parts merged into a few large Parquet files per
//! table, atomically, resumably and idempotently, with nothing lost.
//!
//! The compacted files live beside the parts they replace (`steps/compact-<gen>-<k>.parquet`,
//! `episodes/compact-<gen>-<k>.parquet`), so every reader (DataFusion, pyarrow, polars, duckdb
//! globbing `episodes/*.parquet`) reads a compacted run as before, and a later resume adds
//! one-episode parts beside them. The steps of one compaction:
//!
//! 1. refuse while a `pipeline run` is writing the run ([`WriterLock`]); take `compaction.lock`;
//! 2. finish or undo an earlier compaction that was killed ([`recover`]);
//! 3. pick the finished episodes (both parts present, neither damaged) and write their rows into
//!    `staging/` (invisible to readers), at most [`EPISODES_PER_FILE`] episodes per file;
//! 4. **commit**: write `compaction-<gen>.json`, the journal listing the new files and the parts
//!    they replace (one atomic put);
//! 5. apply the journal: move the staged files into the table folders, delete the replaced parts,
//!    delete the journal.
//!
//! A kill before the commit leaves only staged files, which the next compaction deletes; a kill
//! after it leaves a journal, which the next command that opens the run (run, compact, any query)
//! applies. Row counts and a content hash of each table (order-independent: the sum of a hash of
//! every row) are compared before and after, and the compaction fails loudly if they differ.

use crate::run_store::RunStore;
use anyhow::{Context, Result, bail};
use arrow::array::{AsArray, RecordBatch};
use arrow::datatypes::{Int32Type, Int64Type};
use arrow::row::{RowConverter, SortField};
use bytes::Bytes;
use parquet::arrow::ArrowWriter;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeSet;

/// Episodes per compacted file: ~300 step rows each, so a steps file holds ~150k rows (~60 MB).
pub const EPISODES_PER_FILE: usize = 500;
const TABLES: [&str; 2] = ["steps", "episodes"];
/// File-name prefix of compacted files in `steps/` and `episodes/`.
pub const COMPACT_PREFIX: &str = "compact-";

/// The commit record of one compaction.
#[derive(Debug, Serialize, Deserialize)]
struct Journal {
    generation: String,
    /// Staged file name -> its place in the table folder, per table.
    files: Vec<(String, String)>,
    /// The one-episode part names the new files replace (in both tables).
    replaced: Vec<String>,
}

/// Row count and content hash of a run's table: what compaction must keep.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TableDigest {
    pub rows: u64,
    pub hash: u128,
}

/// What a compaction did.
#[derive(Debug)]
pub struct CompactionReport {
    pub episodes: usize,
    pub files_before: [usize; 2],
    pub files_after: [usize; 2],
    pub digests: [TableDigest; 2],
}

/// `RUN/writer.json`: a `pipeline run` is writing this run. Removed when the run ends; one left
/// by a killed run names a process that no longer exists and is ignored.
#[derive(Debug, Serialize, Deserialize)]
pub struct WriterLock {
    pub pid: u32,
    pub host: String,
    pub started_at: String,
}

impl WriterLock {
    pub fn this_process(started_at: String) -> Self {
        WriterLock { pid: std::process::id(), host: hostname(), started_at }
    }

    /// Whether the process that wrote it may still be running (another host: assume so).
    pub fn is_live(&self) -> bool {
        self.host != hostname() || std::path::Path::new(&format!("/proc/{}", self.pid)).exists()
    }
}

/// This machine's host name (what locks and run session records name).
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default().trim().to_string()
}

/// A live lock file of another process (`writer.json` or `compaction.lock`), if any.
pub async fn live_lock(store: &RunStore, name: &str) -> Result<Option<WriterLock>> {
    let Some(bytes) = store.get(name).await? else { return Ok(None) };
    let lock: WriterLock =
        serde_json::from_slice(&bytes).with_context(|| format!("{}{name} is not a lock file", store.url()))?;
    Ok((lock.is_live() && lock.pid != std::process::id()).then_some(lock))
}

/// Finish (or undo) a compaction that was killed: apply a committed journal, delete staged files
/// without one. Idempotent; every command that opens a run calls it.
pub async fn recover(store: &RunStore) -> Result<()> {
    for name in store.top_level_files().await? {
        if name.starts_with("compaction-") && name.ends_with(".json") {
            let bytes = store.get(&name).await?.unwrap_or_default();
            let journal: Journal = serde_json::from_slice(&bytes).with_context(|| name.clone())?;
            apply(store, &name, &journal).await?;
        }
    }
    Ok(())
}

/// Move the staged files into place, delete the parts they replace, delete the journal. Each
/// step tolerates having been done already.
async fn apply(store: &RunStore, journal_name: &str, journal: &Journal) -> Result<()> {
    for (staged, target) in &journal.files {
        store.rename_if_present(&format!("staging/{staged}"), target).await?;
    }
    for part in &journal.replaced {
        for table in TABLES {
            store.delete_if_present(&format!("{table}/{part}")).await?;
        }
    }
    store.delete_if_present(journal_name).await?;
    Ok(())
}

/// Compact `store`'s run. Refuses while a run is writing it or another compaction runs.
pub async fn compact(store: &RunStore) -> Result<CompactionReport> {
    if store.read_manifest().await?.is_none() {
        bail!("{} holds no run (no manifest.json)", store.url());
    }
    if let Some(w) = live_lock(store, "writer.json").await? {
        bail!(
            "{} is being written by `pipeline run` (pid {} on {}, since {}); compact it when that run has \
             ended (a run killed on another host leaves writer.json behind: delete it if no run is writing)",
            store.url(),
            w.pid,
            w.host,
            w.started_at
        );
    }
    if let Some(c) = live_lock(store, "compaction.lock").await? {
        bail!("{} is being compacted by pid {} on {}; wait for it", store.url(), c.pid, c.host);
    }
    let lock = WriterLock::this_process(unix_seconds());
    recover(store).await?;
    store.put("compaction.lock", serde_json::to_vec(&lock)?.into()).await?;
    let result = compact_locked(store).await;
    store.delete_if_present("compaction.lock").await?;
    result
}

async fn compact_locked(store: &RunStore) -> Result<CompactionReport> {
    for staged in store.file_names("staging").await? {
        store.delete_if_present(&format!("staging/{staged}")).await?;
    }
    let damaged: BTreeSet<String> = store.damaged_parts().await?.into_iter().map(|d| d.name).collect();
    let steps_parts = store.part_names("steps").await?;
    let mut episodes: Vec<String> = store
        .part_names("episodes")
        .await?
        .into_iter()
        .filter(|p| !p.starts_with(COMPACT_PREFIX) && steps_parts.contains(p) && !damaged.contains(p))
        .collect();
    episodes.sort();
    let files_before = [store.part_names("steps").await?.len(), store.part_names("episodes").await?.len()];
    let digests_before = [digest(store, "steps").await?, digest(store, "episodes").await?];
    if episodes.is_empty() {
        return Ok(CompactionReport { episodes: 0, files_before, files_after: files_before, digests: digests_before });
    }
    let generation = format!("{}-{}", unix_seconds().replace([':', '-'], ""), std::process::id());
    let mut files = Vec::new();
    for (k, chunk) in episodes.chunks(EPISODES_PER_FILE).enumerate() {
        for table in TABLES {
            let staged = format!("{table}-{generation}-{k:04}.parquet");
            let bytes = merged(store, table, chunk).await?;
            store.put(&format!("staging/{staged}"), bytes).await?;
            files.push((staged, format!("{table}/{COMPACT_PREFIX}{generation}-{k:04}.parquet")));
        }
    }
    fault_point("staged");
    let journal = Journal { generation: generation.clone(), files, replaced: episodes.clone() };
    let journal_name = format!("compaction-{generation}.json");
    store.put(&journal_name, serde_json::to_vec_pretty(&journal)?.into()).await?;
    fault_point("committed");
    apply(store, &journal_name, &journal).await?;
    let digests = [digest(store, "steps").await?, digest(store, "episodes").await?];
    if digests != digests_before {
        bail!(
            "compaction of {} changed the tables' contents: before {digests_before:?}, after {digests:?}; \
             the replaced parts are gone, the compacted files are in steps/ and episodes/ ({generation})",
            store.url()
        );
    }
    let files_after = [store.part_names("steps").await?.len(), store.part_names("episodes").await?.len()];
    Ok(CompactionReport { episodes: episodes.len(), files_before, files_after, digests })
}

/// Part names (`EpisodeKey::part_name`) of the finished episodes: the one-episode parts of
/// `episodes/`, and the episodes inside its compacted files. What a resume skips.
pub async fn finished_part_names(store: &RunStore) -> Result<std::collections::HashSet<String>> {
    let mut out = std::collections::HashSet::new();
    for part in store.part_names("episodes").await? {
        if !part.starts_with(COMPACT_PREFIX) {
            out.insert(part);
            continue;
        }
        let bytes = store.get(&format!("episodes/{part}")).await?.unwrap_or_default();
        let builder = ParquetRecordBatchReaderBuilder::try_new(bytes).with_context(|| format!("episodes/{part}"))?;
        let mask = {
            let schema = builder.parquet_schema();
            let mut columns: Vec<usize> = ["suite", "task_id", "init_state_id", "seed"]
                .iter()
                .map(|n| {
                    let found = schema.columns().iter().position(|c| c.name() == *n);
                    found.with_context(|| format!("episodes/{part} has no {n} column"))
                })
                .collect::<Result<_>>()?;
            // runs before tables v6 have no variant_hash column: all their episodes are unperturbed
            columns.extend(schema.columns().iter().position(|c| c.name() == "variant_hash"));
            parquet::arrow::ProjectionMask::leaves(schema, columns)
        };
        for batch in builder.with_projection(mask).build()? {
            let batch = batch?;
            let suite = batch.column_by_name("suite").context("suite")?.as_string::<i32>();
            let task = batch.column_by_name("task_id").context("task_id")?.as_primitive::<Int32Type>();
            let init = batch.column_by_name("init_state_id").context("init_state_id")?.as_primitive::<Int32Type>();
            let seed = batch.column_by_name("seed").context("seed")?.as_primitive::<Int64Type>();
            let variant = batch.column_by_name("variant_hash").map(|c| c.as_string::<i32>().clone());
            for i in 0..batch.num_rows() {
                let variant = variant.as_ref().filter(|v| arrow::array::Array::is_valid(v, i)).map(|v| v.value(i));
                let key = crate::steps_batch::EpisodeKey::with_variant(
                    suite.value(i),
                    task.value(i),
                    init.value(i),
                    seed.value(i),
                    variant,
                );
                out.insert(key.part_name());
            }
        }
    }
    Ok(out)
}

/// The rows of `parts` of one table as one Parquet file (zstd; the run manifest kept).
async fn merged(store: &RunStore, table: &str, parts: &[String]) -> Result<Bytes> {
    let mut writer: Option<ArrowWriter<Vec<u8>>> = None;
    for part in parts {
        let bytes = store.get(&format!("{table}/{part}")).await?.with_context(|| format!("{table}/{part} vanished"))?;
        let builder = ParquetRecordBatchReaderBuilder::try_new(bytes).with_context(|| format!("{table}/{part}"))?;
        if writer.is_none() {
            let kv = builder.metadata().file_metadata().key_value_metadata().cloned();
            let props = WriterProperties::builder()
                .set_compression(Compression::ZSTD(ZstdLevel::try_new(3)?))
                .set_key_value_metadata(kv)
                .build();
            writer = Some(ArrowWriter::try_new(Vec::new(), builder.schema().clone(), Some(props))?);
        }
        let w = writer.as_mut().expect("just made");
        for batch in builder.build()? {
            w.write(&batch?).with_context(|| format!("{table}/{part}: another schema than the parts before it"))?;
        }
    }
    Ok(Bytes::from(writer.context("no parts")?.into_inner()?))
}

/// Row count and order-independent content hash of every file of a table: the wrapping sum of
/// the sha256 (first 16 bytes) of each row in Arrow's row format.
pub async fn digest(store: &RunStore, table: &str) -> Result<TableDigest> {
    let mut d = TableDigest { rows: 0, hash: 0 };
    for part in store.part_names(table).await? {
        let bytes = store.get(&format!("{table}/{part}")).await?.unwrap_or_default();
        let reader =
            ParquetRecordBatchReaderBuilder::try_new(bytes).with_context(|| format!("{table}/{part}"))?.build()?;
        for batch in reader {
            add_rows(&mut d, &batch?)?;
        }
    }
    Ok(d)
}

fn add_rows(d: &mut TableDigest, batch: &RecordBatch) -> Result<()> {
    let fields = batch.schema().fields().iter().map(|f| SortField::new(f.data_type().clone())).collect();
    let rows = RowConverter::new(fields)?.convert_columns(batch.columns())?;
    for row in rows.iter() {
        let h = Sha256::digest(row.as_ref());
        d.hash = d.hash.wrapping_add(u128::from_le_bytes(h[..16].try_into().expect("16 bytes")));
        d.rows += 1;
    }
    Ok(())
}

/// Test hook: `LIBERO_FAULT=compact:<stage>` aborts the process at that stage, as a SIGKILL would.
fn fault_point(stage: &str) {
    if std::env::var("LIBERO_FAULT").is_ok_and(|v| v == format!("compact:{stage}")) {
        eprintln!("LIBERO_FAULT: aborting at compact:{stage}");
        std::process::abort();
    }
}

/// Seconds since the Unix epoch, as text: compaction generations and lock times.
fn unix_seconds() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    format!("{secs}")
}
