//! A run's storage on an `object_store` location: where every part lives, atomic writes, and
//! what is already finished (for resume).
//!
//! ```text
//! <run>/manifest.json, manifest.parquet    the run manifest
//! <run>/specs.parquet                      the spec table as given (every column)
//! <run>/steps/<episode>.parquet            one part per episode, one row per env step
//! <run>/episodes/<episode>.parquet         one part per episode, one row; written last, so its
//!                                          presence marks the episode finished
//! <run>/sessions/<start>-<pid>.json        what each `pipeline run` invocation did (episodes,
//!                                          wall time, peak RSS): `pipeline bench run` reads them
//! <run>/damaged/{steps,episodes}/<episode>.parquet
//!                                          parts found damaged (e.g. cut short by a full disk),
//!                                          set aside by a resume, which re-runs their episodes
//! ```
//!
//! A location is a local path (the default), `file://`, `memory://` (tests), `s3://` (AWS or any
//! S3-compatible server through `AWS_ENDPOINT`), `gs://` or `az://`. Every `put` of `object_store` is
//! atomic (local files are written to a temporary name and renamed), so a killed run leaves no
//! half-written part, at most a steps part without its episode part, which a resume rewrites.

use arrow::array::RecordBatch;
use bytes::Bytes;
use futures::{StreamExt, TryStreamExt};
use libero_schema::RunManifest;
use libero_schema::tables::MANIFEST_METADATA_KEY;
use object_store::path::Path as StorePath;
use object_store::{ObjectStore, ObjectStoreExt, PutPayload};
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use std::collections::HashSet;
use std::sync::Arc;
use url::Url;

#[derive(Debug, Clone)]
pub struct RunStore {
    store: Arc<dyn ObjectStore>,
    /// The run's root inside the store.
    root: StorePath,
    /// The run's root as a URL with a trailing slash (what DataFusion tables are registered on).
    url: Url,
    /// The store's base URL (scheme + authority), for registering it with DataFusion.
    base: Url,
}

impl RunStore {
    /// Open a run location: a local path (created if missing) or an object-store URL.
    pub fn open(location: &str) -> anyhow::Result<Self> {
        let url = match Url::parse(location) {
            Ok(u) if u.scheme().len() > 1 => u,
            _ => {
                let p = std::path::Path::new(location);
                std::fs::create_dir_all(p)
                    .map_err(|e| anyhow::anyhow!("cannot create the run folder {location}: {e}"))?;
                let abs = std::fs::canonicalize(p)?;
                Url::from_directory_path(&abs).map_err(|_| anyhow::anyhow!("not a usable path: {}", abs.display()))?
            }
        };
        let mut url = url;
        if !url.path().ends_with('/') {
            url.set_path(&format!("{}/", url.path()));
        }
        // Credentials and options of cloud stores come from the environment: the AWS_*, GOOGLE_*
        // and AZURE_* variables only (object_store also reads bare names such as `endpoint` or
        // `token`, which other tools' variables must not set by accident).
        let options = std::env::vars().filter(|(k, _)| ["AWS_", "GOOGLE_", "AZURE_"].iter().any(|p| k.starts_with(p)));
        let (store, root) = object_store::parse_url_opts(&url, options).map_err(|e| {
            anyhow::anyhow!(
                "cannot open the run location {location}: {e}. Use a local path, file://, memory://, s3://, gs:// or az:// \
                 (credentials and endpoints from AWS_*, GOOGLE_*, AZURE_* variables)"
            )
        })?;
        let base = Url::parse(&format!("{}://{}", url.scheme(), url.authority()))?;
        Ok(RunStore { store: Arc::from(store), root, url, base })
    }

    /// [`Self::open`], then, for a remote store, one listing of the run's prefix, so that a missing
    /// bucket, wrong credentials or an unreachable endpoint stop the command with what to fix, not
    /// as a missing file later (object_store reports a missing bucket as a missing object).
    pub async fn connect(location: &str) -> anyhow::Result<Self> {
        let store = Self::open(location)?;
        if ["file", "memory"].contains(&store.url.scheme()) {
            return Ok(store);
        }
        if let Err(e) = store.store.list_with_delimiter(Some(&store.root)).await {
            let bucket = store.url.host_str().unwrap_or_default();
            let endpoint = std::env::var("AWS_ENDPOINT").or_else(|_| std::env::var("AWS_ENDPOINT_URL"));
            let at = endpoint.map(|e| format!(" at {e}")).unwrap_or_default();
            let text = e.to_string();
            anyhow::bail!(
                "cannot reach the run location {location}: {}\n{text}",
                if text.contains("NoSuchBucket") || text.contains("NoSuchContainer") {
                    format!("the bucket {bucket:?} does not exist{at}; create it, or fix the URL")
                } else {
                    "check the URL, the credentials and the endpoint (AWS_* / GOOGLE_* / AZURE_* variables)".into()
                }
            );
        }
        Ok(store)
    }

    pub fn url(&self) -> &Url {
        &self.url
    }

    pub fn base_url(&self) -> &Url {
        &self.base
    }

    pub fn object_store(&self) -> Arc<dyn ObjectStore> {
        self.store.clone()
    }

    fn path(&self, rel: &str) -> StorePath {
        rel.split('/').fold(self.root.clone(), |p, part| p.join(part))
    }

    /// URL of a table folder (`steps/`, `episodes/`) or file inside the run.
    pub fn table_url(&self, rel: &str) -> String {
        format!("{}{}", self.url, rel)
    }

    pub async fn put(&self, rel: &str, bytes: Bytes) -> anyhow::Result<()> {
        self.store
            .put(&self.path(rel), PutPayload::from_bytes(bytes))
            .await
            .map_err(|e| anyhow::anyhow!("writing {rel} to {}: {e}", self.url))?;
        Ok(())
    }

    /// The bytes of a file in the run, `None` if it does not exist.
    pub async fn get(&self, rel: &str) -> anyhow::Result<Option<Bytes>> {
        match self.store.get(&self.path(rel)).await {
            Ok(r) => Ok(Some(r.bytes().await?)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(anyhow::anyhow!("reading {rel} from {}: {e}", self.url)),
        }
    }

    /// File names (not paths) of the parts under `steps/` or `episodes/`.
    pub async fn part_names(&self, table: &str) -> anyhow::Result<HashSet<String>> {
        Ok(self.file_names(table).await?.into_iter().filter(|n| n.ends_with(".parquet")).collect())
    }

    /// File names (not paths) under a folder of the run (`steps`, `episodes`, `sessions`).
    pub async fn file_names(&self, folder: &str) -> anyhow::Result<Vec<String>> {
        let prefix = self.path(folder);
        let metas: Vec<_> = self.store.list(Some(&prefix)).try_collect().await?;
        Ok(metas.into_iter().filter_map(|m| m.location.filename().map(str::to_string)).collect())
    }

    /// Names of the files directly in the run's folder (manifest, journals, locks).
    pub async fn top_level_files(&self) -> anyhow::Result<Vec<String>> {
        let listing = self.store.list_with_delimiter(Some(&self.root)).await?;
        Ok(listing.objects.into_iter().filter_map(|m| m.location.filename().map(str::to_string)).collect())
    }

    /// Rename a file of the run; a source already gone is fine (an earlier attempt moved it).
    pub async fn rename_if_present(&self, from: &str, to: &str) -> anyhow::Result<()> {
        match self.store.rename(&self.path(from), &self.path(to)).await {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(anyhow::anyhow!("moving {from} to {to} in {}: {e}", self.url)),
        }
    }

    /// Delete a file of the run; one already gone is fine.
    pub async fn delete_if_present(&self, rel: &str) -> anyhow::Result<()> {
        match self.store.delete(&self.path(rel)).await {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(anyhow::anyhow!("deleting {rel} in {}: {e}", self.url)),
        }
    }

    /// Parts of `steps/` and `episodes/` that are not whole Parquet files: too short, or without
    /// the `PAR1` magic at both ends, or with a footer longer than the file. That is what a part
    /// cut short (full disk, interrupted copy) or overwritten looks like; two small reads per
    /// part, so every command that opens a run can afford it.
    pub async fn damaged_parts(&self) -> anyhow::Result<Vec<DamagedPart>> {
        let mut out = Vec::new();
        for table in ["steps", "episodes"] {
            let metas: Vec<_> = self.store.list(Some(&self.path(table))).try_collect().await?;
            let checks = metas.into_iter().filter(|m| m.location.as_ref().ends_with(".parquet")).map(|m| async move {
                let name = m.location.filename().unwrap_or_default().to_string();
                let why = self.parquet_damage(&m.location, m.size).await;
                why.map(|why| DamagedPart { table, name, why })
            });
            let found: Vec<Option<DamagedPart>> = futures::stream::iter(checks).buffer_unordered(32).collect().await;
            out.extend(found.into_iter().flatten());
        }
        out.sort_by(|a, b| (a.table, &a.name).cmp(&(b.table, &b.name)));
        Ok(out)
    }

    async fn parquet_damage(&self, location: &StorePath, size: u64) -> Option<String> {
        if size < 12 {
            return Some(format!("{size} bytes, shorter than any Parquet file"));
        }
        let (head, tail) =
            match (self.store.get_range(location, 0..4).await, self.store.get_range(location, size - 8..size).await) {
                (Ok(h), Ok(t)) => (h, t),
                (Err(e), _) | (_, Err(e)) => return Some(format!("unreadable: {e}")),
            };
        if head.as_ref() != b"PAR1" || &tail[4..] != b"PAR1" {
            return Some(format!("{size} bytes without the Parquet magic at both ends (cut short?)"));
        }
        let footer = u32::from_le_bytes(tail[..4].try_into().expect("4 bytes")) as u64;
        if footer + 12 > size {
            return Some(format!("footer of {footer} bytes in a file of {size}"));
        }
        None
    }

    /// Move an episode's parts (both tables, whichever exist) to `damaged/`, so a resume runs the
    /// episode again; nothing is deleted. Returns the parts moved.
    pub async fn set_aside(&self, part_name: &str) -> anyhow::Result<Vec<String>> {
        let mut moved = Vec::new();
        for table in ["steps", "episodes"] {
            let from = self.path(&format!("{table}/{part_name}"));
            let to = self.path(&format!("damaged/{table}/{part_name}"));
            match self.store.rename(&from, &to).await {
                Ok(()) => moved.push(format!("{table}/{part_name} -> damaged/{table}/{part_name}")),
                Err(object_store::Error::NotFound { .. }) => {}
                Err(e) => anyhow::bail!("setting aside {table}/{part_name} in {}: {e}", self.url),
            }
        }
        Ok(moved)
    }

    pub async fn read_manifest(&self) -> anyhow::Result<Option<RunManifest>> {
        match self.get("manifest.json").await? {
            None => Ok(None),
            Some(b) => Ok(Some(serde_json::from_slice(&b).map_err(|e| {
                anyhow::anyhow!("{}manifest.json is not a run manifest ({e}); use a new output location", self.url)
            })?)),
        }
    }
}

/// A part that is not a whole Parquet file ([`RunStore::damaged_parts`]).
#[derive(Debug, Clone)]
pub struct DamagedPart {
    pub table: &'static str,
    pub name: String,
    pub why: String,
}

impl std::fmt::Display for DamagedPart {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{} ({})", self.table, self.name, self.why)
    }
}

/// Encode a batch as a Parquet file (zstd), with the run manifest in the key-value metadata.
pub fn parquet_bytes(batch: &RecordBatch, manifest_json: Option<&str>) -> anyhow::Result<Bytes> {
    let kv = manifest_json.map(|m| vec![KeyValue::new(MANIFEST_METADATA_KEY.to_string(), m.to_string())]);
    let props = WriterProperties::builder()
        .set_compression(Compression::ZSTD(ZstdLevel::try_new(3)?))
        .set_key_value_metadata(kv)
        .build();
    let mut buf = Vec::new();
    let mut w = ArrowWriter::try_new(&mut buf, batch.schema(), Some(props))?;
    w.write(batch)?;
    w.close()?;
    Ok(Bytes::from(buf))
}
