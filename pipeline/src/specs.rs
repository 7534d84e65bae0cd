//! Spec tables: `pipeline specs` writes the canonical protocol's, and [`read_spec_file`] and
//! [`validate`] read and validate any Parquet file with the spec columns before a single episode starts.
//!
//! A spec row is one episode: `suite, task_id, init_state_id, seed` (plus any other columns,
//! carried through to the episode rows). Suite `aloha_sim` makes it an ALOHA-sim episode (task 0
//! transfer_cube, 1 insertion; the seed places the objects, `init_state_id` is the episode's
//! index); a spec table is of one benchmark. Validation names every offending row: missing columns,
//! nulls, unknown suites or tasks, init states or seeds the bundles do not have, duplicate keys,
//! extra columns whose names collide with the stored episode columns, and perturbation columns
//! ([`libero_udfs::perturbation`]) of the wrong type or out of range. An optional `protocol`
//! column ([`EvalProtocol`]: canonical, or lerobot for lerobot-eval's seeding at every reset) says
//! which published loop the rows reproduce, one per table.

use anyhow::{Context, Result, bail};
use arrow::array::{ArrayRef, AsArray, Int32Array, Int64Array, RecordBatch, StringArray};
use arrow::compute::{CastOptions, cast_with_options};
use arrow::datatypes::{DataType, Field, Int32Type, Int64Type, Schema};
use libero_schema::protocol::{SEED, TRIALS_PER_TASK};
use libero_schema::tables::{self, SPEC_COLUMNS};
use libero_schema::{EvalProtocol, Suite};
use libero_sim::bundle::BundleSet;
use libero_udfs::perturbation::EpisodePerturbation;
use libero_udfs::steps_batch::EpisodeKey;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A comma-separated suite list (an alias, so clap takes it as one value, parsed whole).
type SuiteList = Vec<Suite>;

pub const EXAMPLES: &str = "\
Examples:
  # the canonical protocol: 4 suites x 10 tasks x 50 init states, seed 7 (2,000 episodes)
  pipeline specs -o specs.parquet
  pipeline specs --suites libero_goal --tasks 0,1 --trials 5 -o small.parquet
  pipeline specs --protocol lerobot -o lerobot.parquet    # lerobot-eval's seeding and caps
  pipeline specs --benchmark aloha_sim -o aloha.parquet   # lerobot's: 2 tasks x 50 seeds from 1000";

#[derive(clap::Args)]
pub struct Args {
    /// Suites to include: LIBERO's (libero_spatial, libero_object, libero_goal, libero_10,
    /// libero_90) and LIBERO-PRO's <suite>_{swap,object,lan,task} of the first four, or libero_pro
    /// for those 16 (their bundles: ./setup.sh --suites libero_pro).
    #[arg(long, default_value = "libero_spatial,libero_object,libero_goal,libero_10", value_parser = Suite::parse_list)]
    suites: SuiteList,
    /// Trials per task; trial i runs init state i (the canonical protocol runs 50); at least 1.
    #[arg(long, default_value_t = TRIALS_PER_TASK, value_parser = clap::value_parser!(u32).range(1..))]
    trials: u32,
    /// Task ids to include (default: every task of each suite).
    #[arg(long, value_delimiter = ',')]
    tasks: Vec<u32>,
    /// Env seeds; each (task, trial) runs once per seed (default 7: openpi, vla-eval; OpenVLA: 0).
    /// Not with --protocol lerobot, whose episode i is seeded --first-seed + i.
    #[arg(long, value_delimiter = ',')]
    seeds: Vec<u64>,
    /// libero: which published loop the rows reproduce. canonical: OpenVLA's and openpi's
    /// (env.seed once per task, trial i on init state i after i+1 resets; caps 220/280/300/520/400).
    /// lerobot: lerobot-eval's (episode i of a task seeded --first-seed + i right before its one
    /// reset, on init state i; caps 280/280/300/520/400): the rows get a protocol column, and their
    /// fixture poses must be recorded first (./setup.sh --lerobot-fixtures).
    #[arg(long, default_value = "canonical")]
    protocol: EvalProtocol,
    /// Output Parquet file.
    #[arg(short, long, default_value = "specs.parquet")]
    out: PathBuf,
    /// Which benchmark's episodes: libero (the canonical protocol: tasks × trials × seeds) or
    /// libero_plus (one row per LIBERO-Plus variant, init state 0, on its base task's bundle, the
    /// perturbation in the spec's perturbation columns; --trials and --tasks do not apply).
    #[arg(long, value_enum, default_value = "libero")]
    benchmark: Benchmark,
    /// libero_plus: categories to include (Camera, Robot, Language, Noise, Layout; default: all
    /// five, Layout for the suites whose layout bundles are built, a note naming the set-up command
    /// for the others). Layout is its 696 displaced-object variants, each on its own bundle
    /// (`<suite>_plus_layout`, ./setup.sh --suites libero_plus_layout; asked for by name and not
    /// built, an error); its added distractors, Light and Background need assets only the authors'
    /// Hugging Face repository holds: asking for Light or Background is an error that says so.
    #[arg(long, value_delimiter = ',')]
    categories: Vec<crate::libero_plus::Category>,
    /// libero_plus: the instruction the policy gets: bddl (the env's BDDL text; a Language
    /// variant's rewrite) or official-filename (LIBERO-Plus's Task.language, the file name with
    /// the variant suffix, which OpenVLA-OFT's and openpi's loops fed their policies).
    #[arg(long, value_enum, default_value = "bddl")]
    instruction_mode: crate::libero_plus::InstructionMode,
    /// libero_plus: the sensor-noise code revision: lb2025 (the PyPI wheel's, and the 2025
    /// leaderboard's: glass blur over 224 px, fog's plasma cut at 256 px) or head (the image's size).
    #[arg(long, default_value = "lb2025", value_parser = |s: &str| s.parse::<libero_sim::image_noise::NoiseRevision>())]
    noise_revision: libero_sim::image_noise::NoiseRevision,
    /// libero_plus: at most N variants per suite and category, evenly spaced over it (a sample).
    #[arg(long)]
    per_category: Option<usize>,
    /// libero_plus: the authors' task_classification.json (GitHub only), whose difficulty levels
    /// then fill the difficulty column (null without it).
    #[arg(long)]
    classification: Option<PathBuf>,
    /// libero_plus: base rows per task (init states 0..N) in LIBERO-Plus's unperturbed env, whose
    /// rate every category's drop is measured from (0: none; then `generalisation` has no drops).
    #[arg(long, default_value_t = TRIALS_PER_TASK)]
    base_trials: u32,
    /// libero_pro_robustness: cases to include (visual_noise_glare, camera_view_angle,
    /// runtime_object_move, object_texture, view_occlusion, initial_pose_position_angle; default:
    /// all, view_occlusion for the tasks whose occluder scene is built, with a note naming the
    /// set-up step for the rest). object_shape is a no-op in the reference: asking for it is an
    /// error that says so.
    #[arg(long, value_delimiter = ',')]
    cases: Vec<String>,
    /// aloha_sim and --protocol lerobot: episode i of a task is seeded FIRST_SEED + i (lerobot's
    /// evaluation: 1000).
    #[arg(long, default_value_t = libero_schema::benchmark::aloha::LEROBOT_FIRST_SEED)]
    first_seed: i64,
}

/// The benchmarks `pipeline specs` writes spec tables for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Benchmark {
    Libero,
    #[value(alias = "libero_plus")]
    LiberoPlus,
    /// LIBERO-PRO's robustness cases on the 40 LIBERO tasks (--cases, --suites, --tasks, --trials,
    /// --seeds apply), with unperturbed base rows of the same (task, init state, seed).
    #[value(alias = "libero_pro_robustness")]
    LiberoProRobustness,
    /// ALOHA-sim (suite aloha_sim): --trials episodes per task (lerobot: 50), episode i seeded
    /// --first-seed + i (lerobot's 1000 + i); --tasks picks 0 transfer_cube, 1 insertion.
    #[value(alias = "aloha_sim")]
    AlohaSim,
}

pub fn run(bundles: &Path, mut args: Args) -> Result<()> {
    if args.protocol == EvalProtocol::Lerobot && args.benchmark != Benchmark::Libero {
        bail!(
            "--protocol lerobot applies to --benchmark libero (ALOHA-sim's rows are lerobot's already: episode i seeded --first-seed + i)"
        );
    }
    if args.protocol == EvalProtocol::Lerobot && !args.seeds.is_empty() {
        bail!(
            "--protocol lerobot seeds episode i of a task with --first-seed + i (lerobot-eval's 1000 + i); drop --seeds (or pass --first-seed)"
        );
    }
    if args.seeds.is_empty() {
        args.seeds = vec![SEED];
    }
    if args.benchmark == Benchmark::AlohaSim {
        return write_specs(&aloha_spec_batch(&args)?, &args.out);
    }
    if args.benchmark == Benchmark::LiberoProRobustness {
        let opts = crate::libero_pro_robustness::RobustnessOptions {
            suites: &args.suites,
            cases: (!args.cases.is_empty()).then(|| args.cases.clone()),
            tasks: &args.tasks,
            trials: args.trials,
            seeds: &args.seeds,
        };
        let batch = crate::libero_pro_robustness::spec_batch(bundles, &opts)?;
        return write_specs(&batch, &args.out);
    }
    if args.benchmark == Benchmark::LiberoPlus {
        let opts = crate::libero_plus::PlusOptions {
            suites: &args.suites,
            categories: (!args.categories.is_empty()).then(|| args.categories.clone()),
            instruction_mode: args.instruction_mode,
            noise_revision: args.noise_revision,
            seeds: &args.seeds,
            per_category: args.per_category,
            classification: args.classification.as_deref(),
            base_trials: args.base_trials,
        };
        let batch = crate::libero_plus::spec_batch(bundles, &opts)?;
        return write_specs(&batch, &args.out);
    }
    let set = BundleSet::open(bundles)?;
    let (mut suite, mut task, mut init, mut seed) = (vec![], vec![], vec![], vec![]);
    for s in &args.suites {
        let available: Vec<u32> = set.tasks().iter().filter(|t| t.suite == s.name()).map(|t| t.task_id).collect();
        if available.is_empty() {
            bail!("no task bundles for {s}; build them with ./setup.sh --suites {s}");
        }
        if args.tasks.is_empty() && available.len() < s.n_tasks() as usize {
            bail!(
                "{s} has bundles for {} of its {} tasks ({}: the set-up builds those for the tests); build the whole suite with ./setup.sh --suites {s}, or pick those with --tasks",
                available.len(),
                s.n_tasks(),
                available.iter().map(u32::to_string).collect::<Vec<_>>().join(", ")
            );
        }
        let chosen: Vec<u32> = if args.tasks.is_empty() { available.clone() } else { args.tasks.clone() };
        for t in chosen {
            let entry = set.entry(*s, t)?;
            if args.trials as usize > entry.n_init_states {
                bail!("--trials {} but {s} task {t} has {} init states", args.trials, entry.n_init_states);
            }
            match args.protocol {
                EvalProtocol::Canonical => {
                    for &sd in &args.seeds {
                        for i in 0..args.trials {
                            suite.push(s.name().to_string());
                            task.push(t as i32);
                            init.push(i as i32);
                            seed.push(sd as i64);
                        }
                    }
                }
                // lerobot-eval: episode i of the task on init state i, seeded first_seed + i
                // (restarting at first_seed for every task)
                EvalProtocol::Lerobot => {
                    for i in 0..args.trials {
                        suite.push(s.name().to_string());
                        task.push(t as i32);
                        init.push(i as i32);
                        seed.push(args.first_seed + i as i64);
                    }
                }
            }
        }
    }
    let mut fields: Vec<Field> = SPEC_COLUMNS.iter().map(|(n, t)| Field::new(*n, t.clone(), false)).collect();
    let n = suite.len();
    let mut columns: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from(suite)),
        Arc::new(Int32Array::from(task)),
        Arc::new(Int32Array::from(init)),
        Arc::new(Int64Array::from(seed)),
    ];
    // a canonical table stays the four key columns, as before the column existed
    if args.protocol != EvalProtocol::Canonical {
        fields.push(Field::new(EvalProtocol::COLUMN, DataType::Utf8, false));
        columns.push(Arc::new(StringArray::from(vec![args.protocol.name(); n])));
    }
    let batch = RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)?;
    write_specs(&batch, &args.out)
}

/// lerobot's ALOHA-sim protocol as spec rows: per task, episode i seeded `first_seed + i`.
fn aloha_spec_batch(args: &Args) -> Result<RecordBatch> {
    use libero_sim::aloha::AlohaTask;
    let tasks: Vec<AlohaTask> = if args.tasks.is_empty() {
        AlohaTask::ALL.to_vec()
    } else {
        args.tasks
            .iter()
            .map(|&t| {
                AlohaTask::from_id(t as i64).with_context(|| {
                    format!("ALOHA-sim has no task {t}; its tasks are 0 transfer_cube and 1 insertion")
                })
            })
            .collect::<Result<_>>()?
    };
    let (mut suite, mut task, mut init, mut seed) = (vec![], vec![], vec![], vec![]);
    for t in tasks {
        for i in 0..args.trials {
            suite.push(libero_schema::benchmark::ALOHA_SUITE);
            task.push(t.id());
            init.push(i as i32);
            seed.push(args.first_seed + i as i64);
        }
    }
    let schema =
        Arc::new(Schema::new(SPEC_COLUMNS.iter().map(|(n, t)| Field::new(*n, t.clone(), false)).collect::<Vec<_>>()));
    Ok(RecordBatch::try_new(
        schema,
        vec![
            Arc::new(StringArray::from(suite)),
            Arc::new(Int32Array::from(task)),
            Arc::new(Int32Array::from(init)),
            Arc::new(Int64Array::from(seed)),
        ],
    )?)
}

fn write_specs(batch: &RecordBatch, out: &Path) -> Result<()> {
    let bytes = libero_udfs::run_store::parquet_bytes(batch, None)?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::write(out, bytes).with_context(|| format!("writing {}", out.display()))?;
    println!("wrote {} episode specs to {}", batch.num_rows(), out.display());
    Ok(())
}

/// A validated spec table: the key columns in their canonical types, then the extra columns.
pub struct Specs {
    pub batch: RecordBatch,
    pub keys: Vec<EpisodeKey>,
    /// Names of the columns besides the key columns, in file order.
    pub extras: Vec<String>,
    /// The first row whose perturbation acts on what the policy sees (camera view, sensor noise),
    /// if any: meaningless for a policy that sees no camera.
    pub first_camera_row: Option<usize>,
    /// The published loop the rows reproduce (the optional column `protocol`; canonical without
    /// it), one per table: it decides the caps of the run.
    pub protocol: EvalProtocol,
}

/// The one benchmark of a spec table's rows (LIBERO for a table without rows or a suite column,
/// which validation then refuses): a run is of one benchmark, since their steps tables differ.
pub fn spec_benchmark(raw: &RecordBatch, source: &str) -> Result<libero_schema::Benchmark> {
    use arrow::array::Array;
    use libero_schema::Benchmark;
    let Some(column) = raw.column_by_name("suite") else { return Ok(Benchmark::Libero) };
    let Ok(column) = arrow::compute::cast(column, &DataType::Utf8) else { return Ok(Benchmark::Libero) };
    let suite = column.as_string::<i32>();
    let mut first: Option<(usize, Benchmark)> = None;
    for r in (0..suite.len()).filter(|&r| !suite.is_null(r)) {
        let b = Benchmark::of_suite(suite.value(r));
        match first {
            None => first = Some((r, b)),
            Some((r0, b0)) if b0 != b => bail!(
                "spec file {source} mixes benchmarks: row {r0} is {b0} (suite {:?}), row {r} is {b} (suite {:?}); a run is of one benchmark (their steps tables differ): split the table and run each. No episode was started.",
                suite.value(r0),
                suite.value(r)
            ),
            Some(_) => {}
        }
    }
    Ok(first.map(|(_, b)| b).unwrap_or(Benchmark::Libero))
}

/// Stop before any episode when a spec table has problems, naming the first 20.
fn refuse_problems(source: &str, problems: Vec<String>) -> Result<()> {
    if problems.is_empty() {
        return Ok(());
    }
    let n = problems.len();
    let shown: Vec<String> = problems.into_iter().take(20).collect();
    let more = if n > 20 { format!("\n  ... and {} more", n - 20) } else { String::new() };
    bail!("spec file {source} has {n} problem(s); no episode was started:\n  {}{more}", shown.join("\n  "))
}

/// Validate the rows of an ALOHA-sim spec (suite `aloha_sim`): `task_id` 0 (transfer_cube) or 1
/// (insertion), `seed` numpy's `RandomState` takes (0 ..= 2^32 − 1), `init_state_id` ≥ 0 (the
/// episode's index: it names the episode, the seed places the objects), no duplicate keys, and no
/// LIBERO perturbation column (they edit LIBERO scenes; ALOHA-sim has none).
fn validate_aloha(batch: RecordBatch, extras: Vec<String>, source: &str) -> Result<Specs> {
    use arrow::array::Array;
    use libero_sim::aloha::AlohaTask;
    let reserved = libero_udfs::perturbation::reserved_columns();
    let libero_only: Vec<&String> = extras.iter().filter(|c| reserved.contains(&c.as_str())).collect();
    if !libero_only.is_empty() {
        bail!(
            "spec file {source}: column(s) {libero_only:?} are LIBERO perturbation columns, and its rows are ALOHA-sim's (suite aloha_sim), which has no perturbations; drop them. No episode was started."
        );
    }
    let suite = batch.column(0).as_string::<i32>();
    let task = batch.column(1).as_primitive::<Int32Type>();
    let init = batch.column(2).as_primitive::<Int32Type>();
    let seed = batch.column(3).as_primitive::<Int64Type>();
    let mut problems = Vec::new();
    let mut keys = Vec::with_capacity(batch.num_rows());
    let mut first_row: HashMap<String, usize> = HashMap::new();
    for r in 0..batch.num_rows() {
        if suite.is_null(r) || task.is_null(r) || init.is_null(r) || seed.is_null(r) {
            problems.push(format!("row {r}: a key column is null"));
            continue;
        }
        let row = format!(
            "row {r} (suite aloha_sim, task_id {}, init_state_id {}, seed {})",
            task.value(r),
            init.value(r),
            seed.value(r)
        );
        if AlohaTask::from_id(task.value(r) as i64).is_none() {
            problems.push(format!(
                "{row}: ALOHA-sim has no task_id {}; its tasks are 0 transfer_cube and 1 insertion",
                task.value(r)
            ));
        }
        if u32::try_from(seed.value(r)).is_err() {
            problems.push(format!(
                "{row}: the seed places the objects through numpy's RandomState, which takes 0..=4294967295 (lerobot's episode i is 1000 + i)"
            ));
        }
        if init.value(r) < 0 {
            problems.push(format!("{row}: init_state_id (the episode index) must be ≥ 0"));
        }
        let key = EpisodeKey::new(suite.value(r), task.value(r), init.value(r), seed.value(r));
        if let Some(prev) = first_row.insert(key.episode_key.clone(), r) {
            problems.push(format!("{row}: duplicate episode key {} (first at row {prev})", key.episode_key));
        }
        keys.push(key);
    }
    refuse_problems(source, problems)?;
    Ok(Specs { batch, keys, extras, first_camera_row: None, protocol: EvalProtocol::Canonical })
}

/// The protocol of a spec table's rows (column `protocol`; absent or null: canonical): one for
/// the whole table, since a run's caps are its protocol's.
fn spec_protocol(raw: &RecordBatch, source: &str) -> Result<EvalProtocol> {
    use arrow::array::Array;
    let Some(column) = raw.column_by_name(EvalProtocol::COLUMN) else { return Ok(EvalProtocol::Canonical) };
    if !matches!(column.data_type(), DataType::Utf8 | DataType::LargeUtf8 | DataType::Utf8View) {
        bail!(
            "spec file {source}: column protocol has type {}, expected a string (canonical or lerobot). No episode was started.",
            column.data_type()
        );
    }
    let column = arrow::compute::cast(column, &DataType::Utf8)?;
    let values = column.as_string::<i32>();
    let mut first: Option<(usize, EvalProtocol)> = None;
    for r in 0..values.len() {
        let p = if values.is_null(r) {
            EvalProtocol::Canonical
        } else {
            values
                .value(r)
                .parse()
                .map_err(|e: String| anyhow::anyhow!("spec file {source}: row {r}: {e}. No episode was started."))?
        };
        match first {
            None => first = Some((r, p)),
            Some((r0, p0)) if p0 != p => bail!(
                "spec file {source} mixes protocols: row {r0} is {p0}, row {r} is {p}; a run is of one protocol (its caps are the run's): split the table and run each. No episode was started."
            ),
            Some(_) => {}
        }
    }
    Ok(first.map_or(EvalProtocol::Canonical, |(_, p)| p))
}

/// A spec Parquet file as one batch, unvalidated.
pub fn read_spec_file(path: &Path) -> Result<RecordBatch> {
    let file = std::fs::File::open(path).with_context(|| format!("cannot open the spec file {}", path.display()))?;
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
        .with_context(|| format!("{} is not a Parquet file", path.display()))?
        .build()?;
    let schema = arrow::record_batch::RecordBatchReader::schema(&reader);
    let batches: Vec<RecordBatch> = reader.collect::<Result<_, _>>()?;
    Ok(arrow::compute::concat_batches(&schema, &batches)?)
}

/// Validate a spec batch (see the module doc); `source` names it in errors.
pub fn validate(raw: RecordBatch, bundles: &BundleSet, source: &str) -> Result<Specs> {
    let schema = raw.schema();
    let missing: Vec<&str> =
        SPEC_COLUMNS.iter().map(|(n, _)| *n).filter(|n| schema.column_with_name(n).is_none()).collect();
    if !missing.is_empty() {
        let present: Vec<&str> = schema.fields().iter().map(|f| f.name().as_str()).collect();
        bail!(
            "spec file {source} lacks the column(s) {}; a spec table needs suite, task_id, init_state_id, seed (it has: {}). Make one with `pipeline specs`.",
            missing.join(", "),
            present.join(", ")
        );
    }
    let stored: Vec<String> = tables::episodes().fields().iter().map(|f| f.name().clone()).collect();
    let protocol = spec_protocol(&raw, source)?;
    // `protocol` is stored in the episodes' own column, not carried through as an extra
    let extras: Vec<String> = schema
        .fields()
        .iter()
        .map(|f| f.name().clone())
        .filter(|n| !SPEC_COLUMNS.iter().any(|(k, _)| k == n) && n != EvalProtocol::COLUMN)
        .collect();
    let clashes: Vec<&String> = extras.iter().filter(|n| stored.contains(n)).collect();
    if !clashes.is_empty() {
        bail!(
            "spec file {source}: extra column(s) {clashes:?} have the names of stored episode columns; rename them (extra columns are carried through to the episode rows)"
        );
    }
    let mut columns: Vec<ArrayRef> = Vec::new();
    let mut fields: Vec<Field> = Vec::new();
    for (name, dt) in SPEC_COLUMNS {
        let col = raw.column_by_name(name).expect("checked above");
        let ok_type = match dt {
            DataType::Utf8 => matches!(col.data_type(), DataType::Utf8 | DataType::LargeUtf8 | DataType::Utf8View),
            _ => col.data_type().is_integer(),
        };
        if !ok_type {
            bail!("spec file {source}: column {name} has type {}, expected {}", col.data_type(), dt);
        }
        let cast = cast_with_options(col, &dt, &CastOptions { safe: false, ..Default::default() })
            .with_context(|| format!("spec file {source}: column {name} does not fit {dt}"))?;
        columns.push(cast);
        fields.push(Field::new(name, dt, true));
    }
    // kept in the stored spec table (right after the keys) so that it says what its rows meant
    if let Ok(i) = schema.index_of(EvalProtocol::COLUMN) {
        columns.push(raw.column(i).clone());
        fields.push(schema.field(i).clone());
    }
    for name in &extras {
        let i = schema.index_of(name)?;
        columns.push(raw.column(i).clone());
        fields.push(schema.field(i).clone());
    }
    let batch = RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)?;

    if spec_benchmark(&batch, source)? == libero_schema::Benchmark::AlohaSim {
        if batch.column_by_name(EvalProtocol::COLUMN).is_some() {
            bail!(
                "spec file {source}: a protocol column names a LIBERO loop, and its rows are ALOHA-sim's (suite aloha_sim), whose only loop is lerobot's (episode i seeded --first-seed + i); drop the column. No episode was started."
            );
        }
        return validate_aloha(batch, extras, source);
    }
    let extras_batch = batch.project(&(SPEC_COLUMNS.len()..batch.num_columns()).collect::<Vec<_>>())?;
    let suite = batch.column(0).as_string::<i32>();
    let task = batch.column(1).as_primitive::<Int32Type>();
    let init = batch.column(2).as_primitive::<Int32Type>();
    let seed = batch.column(3).as_primitive::<Int64Type>();
    let mut problems: Vec<String> = Vec::new();
    let mut keys = Vec::with_capacity(batch.num_rows());
    let mut first_row: HashMap<String, usize> = HashMap::new();
    let mut needs_camera: Option<usize> = None;
    // per task: (number of init states, env seeds with fixture poses under the table's protocol,
    // problem class), or why the bundle failed
    type TaskFacts = Result<(usize, Vec<u64>, String), String>;
    let mut bundle_cache: BTreeMap<(Suite, u32), TaskFacts> = BTreeMap::new();
    for r in 0..batch.num_rows() {
        use arrow::array::Array;
        if suite.is_null(r) || task.is_null(r) || init.is_null(r) || seed.is_null(r) {
            problems.push(format!("row {r}: a key column is null"));
            continue;
        }
        let row = format!(
            "row {r} (suite {:?}, task_id {}, init_state_id {}, seed {})",
            suite.value(r),
            task.value(r),
            init.value(r),
            seed.value(r)
        );
        let s: Suite = match suite.value(r).parse() {
            Ok(s) => s,
            Err(e) => {
                problems.push(format!("{row}: {e}"));
                continue;
            }
        };
        if task.value(r) < 0 || init.value(r) < 0 || seed.value(r) < 0 {
            problems.push(format!("{row}: task_id, init_state_id and seed must be ≥ 0"));
            continue;
        }
        let t = task.value(r) as u32;
        let info = bundle_cache.entry((s, t)).or_insert_with(|| {
            let entry = bundles.entry(s, t).map_err(|e| e.to_string())?;
            let b = bundles.load(s, t).map_err(|e| e.to_string())?;
            let seeds = match protocol {
                EvalProtocol::Canonical => b.task.fixture_seeds.clone(),
                EvalProtocol::Lerobot => b.seeded_fixture_seeds(),
            };
            Ok((entry.n_init_states, seeds, b.task.problem.clone()))
        });
        let perturbation = match EpisodePerturbation::from_row(&extras_batch, r) {
            Ok(p) => p,
            Err(e) => {
                problems.push(format!("{row}: {e}"));
                continue;
            }
        };
        match info {
            Err(e) => {
                problems.push(format!("{row}: {e}"));
                continue;
            }
            Ok((n_init, seeds, problem)) => {
                if perturbation.view.is_some()
                    && let Err(e) = libero_sim::viewpoint::nominal_agentview(problem)
                {
                    problems.push(format!("{row}: {e}"));
                }
                if init.value(r) as usize >= *n_init {
                    problems.push(format!(
                        "{row}: init_state_id out of range, the task has {n_init} init states (0..{n_init})"
                    ));
                }
                if !seeds.contains(&(seed.value(r) as u64)) {
                    problems.push(match protocol {
                        EvalProtocol::Canonical => format!(
                            "{row}: the bundles have fixture poses for seeds {seeds:?} only; add the seed at set-up (scripts/reference/build_bundles.py --seeds) or use one of those"
                        ),
                        EvalProtocol::Lerobot => format!(
                            "{row}: protocol lerobot starts from the fixture poses after env.seed(seed) and one reset, and the bundles have them for {} only; record lerobot's seeds 1000-1049 with ./setup.sh --lerobot-fixtures (other seeds or tasks: scripts/reference/seeded_fixtures.py data/bundles --tasks SUITE/NN --seeds FROM-TO in the reference venv)",
                            seed_list(seeds)
                        ),
                    });
                }
            }
        }
        if perturbation.needs_camera().is_some() {
            needs_camera.get_or_insert(r);
        }
        let variant = perturbation.variant();
        let key = EpisodeKey::with_variant(&s.name(), task.value(r), init.value(r), seed.value(r), variant.as_deref());
        if let Some(prev) = first_row.insert(key.episode_key.clone(), r) {
            problems.push(format!("{row}: duplicate episode key {} (first at row {prev})", key.episode_key));
        }
        keys.push(key);
    }
    refuse_problems(source, problems)?;
    if batch.num_rows() == 0 {
        bail!("spec file {source} has no rows");
    }
    Ok(Specs { batch, keys, extras, first_camera_row: needs_camera, protocol })
}

/// `seeds 1000..=1049`, `seeds [1000, 1002]` or `no seed`.
fn seed_list(seeds: &[u64]) -> String {
    match seeds {
        [] => "no seed".to_string(),
        [only] => format!("seed {only}"),
        s if s.windows(2).all(|w| w[1] == w[0] + 1) => format!("seeds {}..={}", s[0], s[s.len() - 1]),
        s => format!("seeds {s:?}"),
    }
}
