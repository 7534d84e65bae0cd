//! A LeRobotDataset in the layout lerobot 0.6.1 reads (`codebase_version` v3.0), written from
//! frames handed over one episode at a time: what `pipeline export --format lerobot` makes of a
//! run's episodes, so training code reads them directly.
//!
//! The layout is lerobot's (`lerobot/datasets/utils.py`, checked against datasets lerobot's own
//! `LeRobotDataset.create` writes):
//!
//! ```text
//! meta/info.json        fps, features (name, dtype, shape, names), totals, path templates
//! meta/stats.json       min, max, mean, std, count, q01 … q99 per feature (images per channel, in [0, 1])
//! meta/tasks.parquet    task_index, task (the task string is the pandas index: lerobot reads it so)
//! meta/episodes/chunk-000/file-000.parquet   one row per episode: length, rows, video offsets
//! data/chunk-CCC/file-000.parquet            one row per frame (the episodes of chunk CCC)
//! videos/<camera>/chunk-CCC/file-FFF.mp4     one file per episode and camera (episode = 1000·C + F)
//! ```
//!
//! Traps lerobot does not report: without the `pandas` metadata of `tasks.parquet` a frame's
//! `task` loads as the integer 0; `index` must equal the frame's row in the concatenated data
//! files; a video must hold every frame at `frame_index / fps` (constant frame rate from 0), since
//! frames are looked up by timestamp within 0.1 ms.
//!
//! The statistics are exact over every frame (lerobot's writer samples images and approximates
//! quantiles across episodes): vectors from their sorted values, images from a 256-bin histogram
//! per channel, the quantiles numpy's linear interpolation of the sorted values.

use crate::media::Mp4Writer;
use anyhow::{Context, Result, bail};
use arrow::array::{
    ArrayRef, BooleanArray, FixedSizeListArray, Float32Array, Float64Array, Int64Array, ListArray, RecordBatch,
    StringArray,
};
use arrow::buffer::OffsetBuffer;
use arrow::datatypes::{DataType, Field, Schema};
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;
use serde_json::{Value, json};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// lerobot's episodes per chunk folder and the quantiles its statistics hold.
const CHUNKS_SIZE: usize = 1000;
const QUANTILES: [(&str, f64); 5] = [("q01", 0.01), ("q10", 0.10), ("q50", 0.50), ("q90", 0.90), ("q99", 0.99)];

/// How the camera videos are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum VideoEncoding {
    /// H.264, yuv420p, crf 18, a keyframe every 2 frames (fast random access, as lerobot's own
    /// encoder settings choose): small files; pixels within a few levels of the render.
    H264,
    /// H.264 lossless in RGB (libx264rgb, qp 0): the rendered pixels exactly; files ~10× larger.
    Lossless,
}

impl VideoEncoding {
    fn ffmpeg_args(self) -> &'static [&'static str] {
        match self {
            VideoEncoding::H264 => &["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "18", "-g", "2"],
            VideoEncoding::Lossless => &["-c:v", "libx264rgb", "-qp", "0", "-g", "2"],
        }
    }

    /// (codec, pixel format) as ffprobe names them, for `info.json`.
    fn stream(self) -> (&'static str, &'static str) {
        match self {
            VideoEncoding::H264 => ("h264", "yuv420p"),
            VideoEncoding::Lossless => ("h264", "gbrp"),
        }
    }
}

/// A camera feature: `observation.images.<name>`, frames `height`×`width` RGB.
#[derive(Debug, Clone)]
pub struct Camera {
    pub key: String,
    pub width: u32,
    pub height: u32,
}

/// What every frame of the dataset holds.
#[derive(Debug, Clone)]
pub struct DatasetLayout {
    pub fps: u32,
    pub robot_type: &'static str,
    pub cameras: Vec<Camera>,
    pub state_names: Vec<String>,
    pub action_names: Vec<String>,
    /// Whether frames carry `next.reward` (ALOHA-sim's 0–4 stages).
    pub reward: bool,
    /// Whether frames carry `held`: a real-time run's hold actions, which the policy did not choose.
    pub held: bool,
    pub encoding: VideoEncoding,
}

/// One frame: the observation before a step, the action of that step, and what followed it.
pub struct Frame<'a> {
    /// RGB rows top-down, one per camera in the layout's order.
    pub images: Vec<&'a [u8]>,
    pub state: &'a [f32],
    pub action: &'a [f32],
    pub reward: Option<f32>,
    pub success: bool,
    pub held: bool,
}

/// The dataset being written under a folder of its own.
pub struct DatasetWriter {
    root: PathBuf,
    layout: DatasetLayout,
    tasks: Vec<String>,
    task_ids: HashMap<String, i64>,
    episodes: Vec<EpisodeRow>,
    frames: FrameColumns,
    /// Per camera, per channel: how many pixels took each value.
    histograms: Vec<[[u64; 256]; 3]>,
    current: Option<OpenEpisode>,
}

struct EpisodeRow {
    task: String,
    length: usize,
    from: usize,
}

struct OpenEpisode {
    task_index: i64,
    videos: Vec<Mp4Writer>,
    frames: usize,
    from: usize,
}

#[derive(Default)]
struct FrameColumns {
    state: Vec<f32>,
    action: Vec<f32>,
    reward: Vec<f32>,
    held: Vec<bool>,
    success: Vec<bool>,
    done: Vec<bool>,
    timestamp: Vec<f32>,
    frame_index: Vec<i64>,
    episode_index: Vec<i64>,
    task_index: Vec<i64>,
}

impl DatasetWriter {
    /// Start a dataset in `root`, which must not exist yet.
    pub fn create(root: &Path, layout: DatasetLayout) -> Result<Self> {
        if root.exists() {
            bail!("{} already exists", root.display());
        }
        for c in &layout.cameras {
            if layout.encoding == VideoEncoding::H264 && (c.width % 2 == 1 || c.height % 2 == 1) {
                bail!("camera {} is {}x{}: H.264 in yuv420p needs even sizes", c.key, c.width, c.height);
            }
        }
        std::fs::create_dir_all(root.join("meta")).with_context(|| format!("creating {}", root.display()))?;
        let histograms = vec![[[0u64; 256]; 3]; layout.cameras.len()];
        Ok(DatasetWriter {
            root: root.to_path_buf(),
            layout,
            tasks: vec![],
            task_ids: HashMap::new(),
            episodes: vec![],
            frames: FrameColumns::default(),
            histograms,
            current: None,
        })
    }

    /// Start the next episode, done with `task` (its instruction).
    pub fn begin_episode(&mut self, task: &str) -> Result<()> {
        assert!(self.current.is_none(), "end_episode first");
        let episode = self.episodes.len();
        let task_index = match self.task_ids.get(task) {
            Some(&i) => i,
            None => {
                self.tasks.push(task.to_string());
                self.task_ids.insert(task.to_string(), self.tasks.len() as i64 - 1);
                self.tasks.len() as i64 - 1
            }
        };
        let videos = self
            .layout
            .cameras
            .iter()
            .map(|c| {
                let path = self.root.join(video_path(&c.key, episode));
                Mp4Writer::create_encoded(&path, c.width, c.height, self.layout.fps, self.layout.encoding.ffmpeg_args())
            })
            .collect::<Result<_>>()?;
        let from = self.frames.frame_index.len();
        self.current = Some(OpenEpisode { task_index, videos, frames: 0, from });
        self.episodes.push(EpisodeRow { task: task.to_string(), length: 0, from });
        Ok(())
    }

    pub fn push(&mut self, frame: &Frame) -> Result<()> {
        let layout = &self.layout;
        let ep = self.current.as_mut().expect("begin_episode first");
        if frame.state.len() != layout.state_names.len() || frame.action.len() != layout.action_names.len() {
            bail!("a frame's state or action has the wrong width");
        }
        for ((image, video), (camera, histogram)) in
            frame.images.iter().zip(&mut ep.videos).zip(layout.cameras.iter().zip(&mut self.histograms))
        {
            video.push_rgb(image).with_context(|| format!("camera {}", camera.key))?;
            for px in image.chunks_exact(3) {
                for (c, &v) in px.iter().enumerate() {
                    histogram[c][v as usize] += 1;
                }
            }
        }
        let f = &mut self.frames;
        f.state.extend_from_slice(frame.state);
        f.action.extend_from_slice(frame.action);
        if layout.reward {
            f.reward.push(frame.reward.unwrap_or(0.0));
        }
        if layout.held {
            f.held.push(frame.held);
        }
        f.success.push(frame.success);
        f.done.push(false);
        f.timestamp.push(ep.frames as f32 / layout.fps as f32);
        f.frame_index.push(ep.frames as i64);
        f.episode_index.push(self.episodes.len() as i64 - 1);
        f.task_index.push(ep.task_index);
        ep.frames += 1;
        Ok(())
    }

    /// Close the episode's videos; its last frame is `next.done`.
    pub fn end_episode(&mut self) -> Result<()> {
        let ep = self.current.take().expect("begin_episode first");
        if ep.frames == 0 {
            bail!("an episode without frames");
        }
        for v in ep.videos {
            let written = v.finish()?;
            if written != ep.frames as u64 {
                bail!("a video holds {written} frames, its episode {}", ep.frames);
            }
        }
        *self.frames.done.last_mut().expect("frames") = true;
        let row = self.episodes.last_mut().expect("begun");
        (row.length, row.from) = (ep.frames, ep.from);
        Ok(())
    }

    /// Write the frames, the episodes, the tasks, the statistics and `info.json`; `extra_meta` goes
    /// to `meta/<name>` beside them. Returns (episodes, frames).
    pub fn finish(self, extra_meta: &[(&str, Value)]) -> Result<(usize, usize)> {
        assert!(self.current.is_none(), "end_episode first");
        if self.episodes.is_empty() {
            bail!("no episode to write");
        }
        let n = self.frames.frame_index.len();
        // data: the episodes of each chunk in one file, frames in episode order
        let data = self.frame_batch()?;
        for (chunk, episodes) in self.episodes.chunks(CHUNKS_SIZE).enumerate() {
            let (from, to) = (episodes[0].from, episodes.last().map(|e| e.from + e.length).expect("a chunk"));
            write_parquet(&self.root.join(data_path(chunk)), &data.slice(from, to - from), None)?;
        }
        write_parquet(&self.root.join("meta/episodes/chunk-000/file-000.parquet"), &self.episodes_batch()?, None)?;
        write_parquet(&self.root.join("meta/tasks.parquet"), &tasks_batch(&self.tasks)?, None)?;
        std::fs::write(self.root.join("meta/stats.json"), serde_json::to_vec_pretty(&self.stats())?)?;
        std::fs::write(self.root.join("meta/info.json"), serde_json::to_vec_pretty(&self.info(n))?)?;
        for (name, value) in extra_meta {
            std::fs::write(self.root.join("meta").join(name), serde_json::to_vec_pretty(value)?)?;
        }
        Ok((self.episodes.len(), n))
    }

    fn frame_batch(&self) -> Result<RecordBatch> {
        let f = &self.frames;
        let l = &self.layout;
        let mut fields = vec![
            Field::new("observation.state", fixed_f32_type(l.state_names.len()), true),
            Field::new("action", fixed_f32_type(l.action_names.len()), true),
        ];
        let mut columns: Vec<ArrayRef> =
            vec![fixed_f32(f.state.clone(), l.state_names.len())?, fixed_f32(f.action.clone(), l.action_names.len())?];
        if l.reward {
            fields.push(Field::new("next.reward", DataType::Float32, true));
            columns.push(Arc::new(Float32Array::from(f.reward.clone())));
        }
        if l.held {
            fields.push(Field::new("held", DataType::Boolean, true));
            columns.push(Arc::new(BooleanArray::from(f.held.clone())));
        }
        fields.extend([
            Field::new("next.success", DataType::Boolean, true),
            Field::new("next.done", DataType::Boolean, true),
            Field::new("timestamp", DataType::Float32, true),
            Field::new("frame_index", DataType::Int64, true),
            Field::new("episode_index", DataType::Int64, true),
            Field::new("index", DataType::Int64, true),
            Field::new("task_index", DataType::Int64, true),
        ]);
        columns.extend::<[ArrayRef; 7]>([
            Arc::new(BooleanArray::from(f.success.clone())),
            Arc::new(BooleanArray::from(f.done.clone())),
            Arc::new(Float32Array::from(f.timestamp.clone())),
            Arc::new(Int64Array::from(f.frame_index.clone())),
            Arc::new(Int64Array::from(f.episode_index.clone())),
            Arc::new(Int64Array::from_iter_values(0..f.frame_index.len() as i64)),
            Arc::new(Int64Array::from(f.task_index.clone())),
        ]);
        Ok(RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)?)
    }

    fn episodes_batch(&self) -> Result<RecordBatch> {
        let eps = &self.episodes;
        let ints = |v: Vec<i64>| Arc::new(Int64Array::from(v)) as ArrayRef;
        let floats = |v: Vec<f64>| Arc::new(Float64Array::from(v)) as ArrayRef;
        let item = Arc::new(Field::new("item", DataType::Utf8, true));
        let tasks = ListArray::try_new(
            item.clone(),
            OffsetBuffer::from_lengths(eps.iter().map(|_| 1)),
            Arc::new(StringArray::from_iter_values(eps.iter().map(|e| e.task.as_str()))),
            None,
        )?;
        let mut fields = vec![
            Field::new("episode_index", DataType::Int64, true),
            Field::new("tasks", DataType::List(item), true),
            Field::new("length", DataType::Int64, true),
            Field::new("data/chunk_index", DataType::Int64, true),
            Field::new("data/file_index", DataType::Int64, true),
            Field::new("dataset_from_index", DataType::Int64, true),
            Field::new("dataset_to_index", DataType::Int64, true),
        ];
        let mut columns: Vec<ArrayRef> = vec![
            ints((0..eps.len() as i64).collect()),
            Arc::new(tasks),
            ints(eps.iter().map(|e| e.length as i64).collect()),
            ints((0..eps.len()).map(|e| (e / CHUNKS_SIZE) as i64).collect()),
            ints(vec![0; eps.len()]),
            ints(eps.iter().map(|e| e.from as i64).collect()),
            ints(eps.iter().map(|e| (e.from + e.length) as i64).collect()),
        ];
        for c in &self.layout.cameras {
            for (name, column) in [
                ("chunk_index", ints((0..eps.len()).map(|e| (e / CHUNKS_SIZE) as i64).collect())),
                ("file_index", ints((0..eps.len()).map(|e| (e % CHUNKS_SIZE) as i64).collect())),
                ("from_timestamp", floats(vec![0.0; eps.len()])),
                ("to_timestamp", floats(eps.iter().map(|e| e.length as f64 / self.layout.fps as f64).collect())),
            ] {
                let dt = column.data_type().clone();
                fields.push(Field::new(format!("videos/{}/{name}", c.key), dt, true));
                columns.push(column);
            }
        }
        fields.push(Field::new("meta/episodes/chunk_index", DataType::Int64, true));
        fields.push(Field::new("meta/episodes/file_index", DataType::Int64, true));
        columns.push(ints(vec![0; eps.len()]));
        columns.push(ints(vec![0; eps.len()]));
        Ok(RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)?)
    }

    fn info(&self, frames: usize) -> Value {
        let l = &self.layout;
        let (codec, pix_fmt) = l.encoding.stream();
        let mut features = serde_json::Map::new();
        for c in &l.cameras {
            features.insert(
                c.key.clone(),
                json!({
                    "dtype": "video",
                    "shape": [c.height, c.width, 3],
                    "names": ["height", "width", "channels"],
                    "info": {
                        "video.height": c.height, "video.width": c.width, "video.codec": codec,
                        "video.pix_fmt": pix_fmt, "video.fps": l.fps, "video.channels": 3,
                        "has_audio": false, "is_depth_map": false
                    }
                }),
            );
        }
        features.insert(
            "observation.state".into(),
            json!({"dtype": "float32", "shape": [l.state_names.len()], "names": l.state_names}),
        );
        features.insert(
            "action".into(),
            json!({"dtype": "float32", "shape": [l.action_names.len()], "names": l.action_names}),
        );
        if l.reward {
            features.insert("next.reward".into(), json!({"dtype": "float32", "shape": [1], "names": null}));
        }
        let flags = ["next.success", "next.done"].into_iter().chain(l.held.then_some("held"));
        for b in flags {
            features.insert(b.into(), json!({"dtype": "bool", "shape": [1], "names": null}));
        }
        features.insert("timestamp".into(), json!({"dtype": "float32", "shape": [1], "names": null}));
        for i in ["frame_index", "episode_index", "index", "task_index"] {
            features.insert(i.into(), json!({"dtype": "int64", "shape": [1], "names": null}));
        }
        json!({
            "codebase_version": "v3.0",
            "robot_type": l.robot_type,
            "total_episodes": self.episodes.len(),
            "total_frames": frames,
            "total_tasks": self.tasks.len(),
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": 100,
            "video_files_size_in_mb": 200,
            "fps": l.fps,
            "splits": {"train": format!("0:{}", self.episodes.len())},
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": (!l.cameras.is_empty()).then_some("videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"),
            "features": features,
        })
    }

    fn stats(&self) -> Value {
        let f = &self.frames;
        let l = &self.layout;
        let n = f.frame_index.len();
        let mut out = BTreeMap::new();
        out.insert("observation.state".to_string(), vector_stats(&f.state, l.state_names.len()));
        out.insert("action".to_string(), vector_stats(&f.action, l.action_names.len()));
        if l.reward {
            out.insert("next.reward".to_string(), vector_stats(&f.reward, 1));
        }
        let as_01 = |v: &[bool]| v.iter().map(|&b| b as u8 as f32).collect::<Vec<_>>();
        out.insert("next.success".to_string(), vector_stats(&as_01(&f.success), 1));
        out.insert("next.done".to_string(), vector_stats(&as_01(&f.done), 1));
        if l.held {
            out.insert("held".to_string(), vector_stats(&as_01(&f.held), 1));
        }
        out.insert("timestamp".to_string(), vector_stats(&f.timestamp, 1));
        let as_f32 = |v: &[i64]| v.iter().map(|&x| x as f32).collect::<Vec<_>>();
        out.insert("frame_index".to_string(), vector_stats(&as_f32(&f.frame_index), 1));
        out.insert("episode_index".to_string(), vector_stats(&as_f32(&f.episode_index), 1));
        out.insert("index".to_string(), vector_stats(&(0..n).map(|i| i as f32).collect::<Vec<_>>(), 1));
        out.insert("task_index".to_string(), vector_stats(&as_f32(&f.task_index), 1));
        for (c, h) in l.cameras.iter().zip(&self.histograms) {
            out.insert(c.key.clone(), image_stats(h, n));
        }
        json!(out)
    }
}

/// Deletes a half-written dataset unless [`PartialDir::keep`] is called: an export that fails
/// leaves nothing behind.
pub struct PartialDir(Option<PathBuf>);

impl PartialDir {
    pub fn new(path: PathBuf) -> Self {
        PartialDir(Some(path))
    }
    pub fn keep(mut self) {
        self.0 = None;
    }
}

impl Drop for PartialDir {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            let _ = std::fs::remove_dir_all(p);
        }
    }
}

fn video_path(key: &str, episode: usize) -> String {
    format!("videos/{key}/chunk-{:03}/file-{:03}.mp4", episode / CHUNKS_SIZE, episode % CHUNKS_SIZE)
}

fn data_path(chunk: usize) -> String {
    format!("data/chunk-{chunk:03}/file-000.parquet")
}

fn fixed_f32_type(n: usize) -> DataType {
    DataType::FixedSizeList(Arc::new(Field::new("element", DataType::Float32, true)), n as i32)
}

fn fixed_f32(values: Vec<f32>, n: usize) -> Result<ArrayRef> {
    Ok(Arc::new(FixedSizeListArray::try_new(
        Arc::new(Field::new("element", DataType::Float32, true)),
        n as i32,
        Arc::new(Float32Array::from(values)),
        None,
    )?))
}

/// `tasks.parquet`'s rows, with the pandas metadata in the Arrow schema (pyarrow reads a file's
/// schema metadata from the Arrow schema stored in it, not from other key-value entries).
fn tasks_batch(tasks: &[String]) -> Result<RecordBatch> {
    Ok(RecordBatch::try_new(
        Arc::new(Schema::new_with_metadata(
            vec![Field::new("task_index", DataType::Int64, true), Field::new("task", DataType::Utf8, true)],
            HashMap::from([pandas_task_index()]),
        )),
        vec![
            Arc::new(Int64Array::from_iter_values(0..tasks.len() as i64)),
            Arc::new(StringArray::from_iter_values(tasks.iter())),
        ],
    )?)
}

/// The `pandas` schema metadata that makes `task` the index of `tasks.parquet` when lerobot reads
/// it with `pd.read_parquet` (it then looks a task up by `tasks.iloc[i].name`).
fn pandas_task_index() -> (String, String) {
    let meta = json!({
        "index_columns": ["task"],
        "column_indexes": [{"name": null, "field_name": null, "pandas_type": "unicode", "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64", "metadata": null},
            {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": null}
        ],
        "attributes": {},
        "creator": {"library": "libero-eval", "version": env!("CARGO_PKG_VERSION")},
        "pandas_version": "2.3.3"
    });
    ("pandas".to_string(), meta.to_string())
}

fn write_parquet(path: &Path, batch: &RecordBatch, kv: Option<(String, String)>) -> Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let props = WriterProperties::builder()
        .set_compression(Compression::ZSTD(ZstdLevel::try_new(3)?))
        .set_key_value_metadata(kv.map(|(k, v)| vec![parquet::file::metadata::KeyValue::new(k, v)]))
        .build();
    let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut w = ArrowWriter::try_new(file, batch.schema(), Some(props))?;
    w.write(batch)?;
    w.close()?;
    Ok(())
}

/// numpy's default (linear) quantile `q` of ascending `sorted` values.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * q;
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// Per-dimension statistics of `values` (`dim` per frame), shapes `[dim]`, count `[frames]`.
fn vector_stats(values: &[f32], dim: usize) -> Value {
    let frames = values.len() / dim;
    let mut stats: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    for d in 0..dim {
        let mut v: Vec<f64> = values.iter().skip(d).step_by(dim).map(|&x| x as f64).collect();
        v.sort_by(f64::total_cmp);
        let mean = v.iter().sum::<f64>() / frames as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / frames as f64;
        stats.entry("min").or_default().push(v[0]);
        stats.entry("max").or_default().push(v[frames - 1]);
        stats.entry("mean").or_default().push(mean);
        stats.entry("std").or_default().push(var.sqrt());
        for (name, q) in QUANTILES {
            stats.entry(name).or_default().push(quantile(&v, q));
        }
    }
    let mut out = json!(stats);
    out["count"] = json!([frames]);
    out
}

/// Per-channel statistics of a camera's pixels in [0, 1], shapes `[3][1][1]` (lerobot's), exact
/// from the histogram: the quantiles interpolate the sorted pixel values as numpy would.
fn image_stats(histogram: &[[u64; 256]; 3], frames: usize) -> Value {
    let mut stats: BTreeMap<&str, Vec<Value>> = BTreeMap::new();
    for channel in histogram {
        let n: u64 = channel.iter().sum();
        // the k-th smallest pixel value (0-based)
        let nth = |k: u64| -> f64 {
            let mut seen = 0;
            for (v, &c) in channel.iter().enumerate() {
                seen += c;
                if seen > k {
                    return v as f64;
                }
            }
            255.0
        };
        let mean = channel.iter().enumerate().map(|(v, &c)| v as f64 * c as f64).sum::<f64>() / n as f64;
        let var =
            channel.iter().enumerate().map(|(v, &c)| (v as f64 - mean).powi(2) * c as f64).sum::<f64>() / n as f64;
        let q = |q: f64| {
            let h = (n - 1) as f64 * q;
            let lo = h.floor() as u64;
            let (a, b) = (nth(lo), nth((lo + 1).min(n - 1)));
            a + (h - lo as f64) * (b - a)
        };
        let wrap = |v: f64| json!([[v / 255.0]]);
        stats.entry("min").or_default().push(wrap(nth(0)));
        stats.entry("max").or_default().push(wrap(nth(n - 1)));
        stats.entry("mean").or_default().push(wrap(mean));
        stats.entry("std").or_default().push(wrap(var.sqrt()));
        for (name, qq) in QUANTILES {
            stats.entry(name).or_default().push(wrap(q(qq)));
        }
    }
    let mut out = json!(stats);
    out["count"] = json!([frames]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn episodes_past_a_thousand_go_to_the_next_chunk() {
        assert_eq!(video_path("observation.images.top", 999), "videos/observation.images.top/chunk-000/file-999.mp4");
        assert_eq!(video_path("observation.images.top", 1000), "videos/observation.images.top/chunk-001/file-000.mp4");
        assert_eq!(data_path(1), "data/chunk-001/file-000.parquet");
    }

    #[test]
    fn quantiles_interpolate_as_numpy_does() {
        // numpy.quantile([1, 2, 3, 4], [0.1, 0.5, 0.99]) = [1.3, 2.5, 3.97]
        let v = [1.0, 2.0, 3.0, 4.0];
        for (q, want) in [(0.1, 1.3), (0.5, 2.5), (0.99, 3.97)] {
            assert!((quantile(&v, q) - want).abs() < 1e-12, "{q}");
        }
    }

    #[test]
    fn image_statistics_from_the_histogram_equal_those_of_the_pixels() {
        let pixels: Vec<u8> = (0..300u32).map(|i| ((i * 37) % 256) as u8).collect();
        let mut h = [[0u64; 256]; 3];
        for px in pixels.chunks_exact(3) {
            for (c, &v) in px.iter().enumerate() {
                h[c][v as usize] += 1;
            }
        }
        let s = image_stats(&h, 1);
        for c in 0..3 {
            let mut v: Vec<f64> = pixels.iter().skip(c).step_by(3).map(|&x| x as f64 / 255.0).collect();
            v.sort_by(f64::total_cmp);
            for (name, q) in QUANTILES {
                let got = s[name][c][0][0].as_f64().unwrap();
                assert!((got - quantile(&v, q)).abs() < 1e-12, "{name} channel {c}");
            }
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            assert!((s["mean"][c][0][0].as_f64().unwrap() - mean).abs() < 1e-12);
            assert_eq!(s["min"][c][0][0].as_f64().unwrap(), v[0]);
        }
    }
}
