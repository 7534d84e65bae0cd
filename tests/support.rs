//! Shared helpers of the end-to-end tests: where the repository, bundles, golden data and the
//! reference venv are. Tests fail with a set-up hint (never skip) when something is missing.

use libero_sim::bundle::BundleSet;
use libero_sim::npy::{self, Array2};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

pub fn bundles() -> BundleSet {
    BundleSet::open(repo_root().join("data/bundles")).unwrap_or_else(|e| panic!("{e}\nrun ./setup.sh --tests"))
}

pub fn golden_dir() -> PathBuf {
    let d = repo_root().join("data/golden");
    assert!(d.exists(), "no golden data at {}: run ./setup.sh --tests", d.display());
    d
}

pub fn reference_python() -> PathBuf {
    let p = repo_root().join(".venv/bin/python");
    assert!(p.exists(), "no reference venv at {}: run ./setup.sh --tests", p.display());
    p
}

pub fn read_npy(path: &Path) -> Array2 {
    npy::read_f64_2d(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The `pipeline` binary under test: `LIBERO_PIPELINE_BIN` when set (a copy, safe from another
/// build replacing the shared target's binary mid-test), else the one cargo built for these tests.
pub fn pipeline_bin() -> PathBuf {
    if let Some(bin) = std::env::var_os("LIBERO_PIPELINE_BIN") {
        return PathBuf::from(bin);
    }
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| repo_root().join("target"));
    let profile = if cfg!(debug_assertions) { "debug" } else { "release" };
    target.join(profile).join("pipeline")
}

/// Read an RGB PNG as a frame in the given orientation (PNGs carry none).
pub fn read_png(path: &Path, orientation: libero_sim::render::Orientation) -> libero_sim::render::Frame {
    let file = std::fs::File::open(path).unwrap_or_else(|e| {
        panic!(
            "cannot open the reference frame {} ({e}): the tests' set-up renders them into data/frames; run ./test.sh \
             (or ./setup.sh --tests)",
            path.display()
        )
    });
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap_or_else(|e| panic!("{} is not a readable PNG ({e}): rerun ./setup.sh --tests", path.display()));
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    buf.truncate(info.buffer_size());
    libero_sim::render::Frame { width: info.width, height: info.height, rgb: buf, orientation }
}

/// Run the `pipeline` binary from the repository root.
pub fn pipeline(args: &[&str]) -> Output {
    pipeline_with_env(args, &[])
}

/// [`pipeline`] with these environment variables set.
pub fn pipeline_with_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut command = Command::new(pipeline_bin());
    command.args(args).current_dir(repo_root()).envs(env.iter().copied());
    command.output().expect("run pipeline")
}

/// The stdout of a `pipeline` call that must succeed (else both streams, in the panic).
pub fn ok(out: Output) -> String {
    assert!(
        out.status.success(),
        "pipeline failed:\nstdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `pipeline run SPECS --out RUN --policy POLICY EXTRA..`, which must succeed with no error rows;
/// its stderr, and the stored policy steps' `columns` (SQL over `steps`) in episode and step order.
pub fn run_policy_steps(
    specs: &Path,
    run: &Path,
    policy: &str,
    extra: &[&str],
    columns: &str,
) -> (String, Vec<Vec<String>>) {
    run_policy_steps_with_env(specs, run, policy, extra, columns, &[])
}

/// [`run_policy_steps`] with these environment variables set for the run.
pub fn run_policy_steps_with_env(
    specs: &Path,
    run: &Path,
    policy: &str,
    extra: &[&str],
    columns: &str,
    env: &[(&str, &str)],
) -> (String, Vec<Vec<String>>) {
    let mut args = vec!["run", specs.to_str().unwrap(), "--out", run.to_str().unwrap(), "--policy", policy];
    args.extend_from_slice(extra);
    let out = pipeline_with_env(&args, env);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{policy}: {stderr}");
    let errors = sql_rows(run, "SELECT count(*) FROM episodes WHERE error_kind IS NOT NULL", &[]);
    assert_eq!(errors, [["0"]], "{policy}: error rows");
    let query = format!("SELECT {columns} FROM steps WHERE policy_step IS NOT NULL ORDER BY episode_key, step");
    (stderr, sql_rows(run, &query, &[]))
}

/// Tasks 0 and 1 of libero_spatial (instructions of different lengths), 2 trials each, run twice
/// under `policy` (`<kind>:<dir>?<options>`): one episode per forward, then `&batch=4&wait_ms=2000`,
/// 4 workers, `max_steps` each. The forwards wait up to 2 s for each other: with the default 20 ms
/// the episodes on a loaded 2-core CI box drifted apart and every forward held one (CI, session 8).
/// The batched run must report a forward that held several episodes and store its batch size in
/// the identity. Returns (single, batched) rows of `episode_key, policy_step, action`.
pub fn single_and_batched_steps(d: &Path, policy: &str, max_steps: u32) -> (Vec<Vec<String>>, Vec<Vec<String>>) {
    let specs = d.join("specs.parquet");
    let s = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0,1", "--trials", "2", "-o", s]));
    let kind = policy.split(':').next().unwrap();
    let max_steps = max_steps.to_string();
    let actions = |name: &str, options: &str| -> Vec<Vec<String>> {
        let policy = format!("{policy}{options}");
        let extra = ["--max-steps", &max_steps, "--jobs", "4"];
        let (stderr, rows) =
            run_policy_steps(&specs, &d.join(name), &policy, &extra, "episode_key, policy_step, action");
        if !options.is_empty() {
            // the run reports its forwards; at least one must have held several episodes
            let prefix = format!("batched policy {kind}:");
            let line = stderr.lines().find(|l| l.starts_with(&prefix)).unwrap_or_else(|| panic!("{stderr}"));
            let after = line.rsplit("at most ").next().unwrap();
            let most: usize = after.split(';').next().unwrap().trim().parse().unwrap();
            assert!(after.contains("ms per forward"), "the forwards' time is missing: {line}");
            assert!(most > 1, "no forward held more than one episode: {line}");
            eprintln!("{line}");
        }
        rows
    };
    let single = actions("single", "");
    let batched = actions("batched", "&batch=4&wait_ms=2000");
    assert_eq!(single.len(), batched.len());
    let identity = sql_rows(&d.join("batched"), "SELECT policy_identity FROM manifest", &[]).concat().join(",");
    assert!(identity.contains("max_episodes_per_forward"), "{identity}");
    (single, batched)
}

/// A fresh, empty folder for one test of one test file (`group`), unique to this process.
pub fn test_dir(group: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("libero-{group}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `pipeline sql` over a run as CSV rows (header dropped; no quoted commas in the values asked for).
pub fn sql_rows(run: &Path, query: &str, extra: &[&str]) -> Vec<Vec<String>> {
    let mut args = vec!["sql", query, "--run", run.to_str().unwrap(), "--csv"];
    args.extend_from_slice(extra);
    let text = ok(pipeline(&args));
    text.lines().skip(1).map(|l| l.split(',').map(str::to_string).collect()).collect()
}

/// Write one constructed episode (its steps batch and its one-row episode batch) into a run
/// folder, as the rollout would: `steps/<part>` and `episodes/<part>`.
pub fn write_episode_parts(
    dir: &Path,
    key: &libero_udfs::steps_batch::EpisodeKey,
    steps: libero_udfs::steps_batch::StepsBatchBuilder,
    episode: &arrow::array::RecordBatch,
) {
    for (sub, batch) in [("steps", steps.finish().unwrap()), ("episodes", episode.clone())] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
        let bytes = libero_udfs::run_store::parquet_bytes(&batch, None).unwrap();
        std::fs::write(dir.join(sub).join(key.part_name()), bytes).unwrap();
    }
}

/// The `manifest.json` of a constructed run (no simulation behind it: bundles and MuJoCo are
/// named as such).
pub fn write_constructed_manifest(dir: &Path, policy: &str, num_steps_wait: u32) {
    let manifest = libero_schema::RunManifest {
        tables_version: libero_schema::tables::TABLES_VERSION,
        run_config: policy.into(),
        created_at: "2026-01-01T00:00:00Z".into(),
        git_revision: "test".into(),
        pipeline_version: "0".into(),
        mujoco_version: "3.3.7".into(),
        bundle_format_version: libero_schema::bundle_format::BUNDLE_FORMAT_VERSION,
        bundles_hash: "none (constructed run)".into(),
        policy: policy.into(),
        policy_identity: serde_json::json!({"kind": "constructed"}),
        num_steps_wait: num_steps_wait as i32,
        max_steps: Default::default(),
        instruction_source: Default::default(),
        stop_on_success: false,
        substeps_per_step: 25,
        control_freq_hz: 20,
        env: libero_schema::Benchmark::Libero,
        realtime: None,
        protocol: Default::default(),
    };
    std::fs::write(dir.join("manifest.json"), serde_json::to_vec(&manifest).unwrap()).unwrap();
}

/// The compact goal evidence of a real run (`episodes.goal_changes`) against its step rows, the
/// ground truth: the goal it gives at every stored policy step equals the stored one, and the
/// `scored` view from the evidence (`queries/score.sql`) equals the one from the steps
/// (`queries/score_from_steps.sql`, put in place of score.sql through `LIBERO_QUERIES`) under
/// both definitions, with and without a shorter cap.
pub fn assert_goal_evidence_matches_steps(run: &Path, cap: u32) {
    let wrong = sql_rows(
        run,
        "SELECT count(*) FROM steps s JOIN episodes e ON s.episode_key = e.episode_key \
         WHERE s.policy_step IS NOT NULL AND goal_held_at(e.goal_changes, s.policy_step) <> s.goal",
        &[],
    );
    assert_eq!(wrong[0][0], "0", "policy steps where goal_changes gives another goal than the step row");
    let counts = sql_rows(
        run,
        "SELECT (SELECT count(*) FROM steps WHERE policy_step IS NOT NULL), (SELECT sum(n_policy_steps) FROM episodes)",
        &[],
    );
    assert_eq!(counts[0][0], counts[0][1], "policy step rows vs n_policy_steps");

    let from_steps = test_dir("queries-from-steps", &format!("{}", run.display()).replace('/', "_"));
    for f in std::fs::read_dir(repo_root().join("queries")).unwrap() {
        let f = f.unwrap();
        std::fs::copy(f.path(), from_steps.join(f.file_name())).unwrap();
    }
    std::fs::copy(repo_root().join("queries/score_from_steps.sql"), from_steps.join("score.sql")).unwrap();
    let query = "SELECT episode_key, scored_success, errored, episode_length_cap FROM scored ORDER BY episode_key";
    let cap = cap.to_string();
    for extra in
        [vec![], vec!["--success", "last-step"], vec!["--cap", &cap], vec!["--success", "last-step", "--cap", &cap]]
    {
        let mut args = vec!["sql", query, "--run", run.to_str().unwrap(), "--csv"];
        args.extend_from_slice(&extra);
        let evidence = ok(pipeline(&args));
        let steps = ok(Command::new(pipeline_bin())
            .args(&args)
            .current_dir(repo_root())
            .env("LIBERO_QUERIES", &from_steps)
            .output()
            .expect("run pipeline"));
        assert_eq!(evidence, steps, "scored from goal_changes vs from the steps, {extra:?}");
        assert!(evidence.lines().count() > 1, "no episodes scored");
    }
    let _ = std::fs::remove_dir_all(&from_steps);
}

/// The LIBERO-PRO tasks the set-up builds for the tests (bundles, golden data, reference
/// frames): one per PRO suite, spread over the task indices. Keep equal to `PRO_TEST_TASKS` in
/// setup.sh.
pub const PRO_TEST_TASKS: [(&str, u32); 16] = [
    ("libero_spatial_swap", 0),
    ("libero_spatial_object", 1),
    ("libero_spatial_lan", 2),
    ("libero_spatial_task", 3),
    ("libero_object_swap", 3),
    ("libero_object_object", 4),
    ("libero_object_lan", 5),
    ("libero_object_task", 6),
    ("libero_goal_swap", 6),
    ("libero_goal_object", 7),
    ("libero_goal_lan", 8),
    ("libero_goal_task", 9),
    ("libero_10_swap", 9),
    ("libero_10_object", 0),
    ("libero_10_lan", 1),
    ("libero_10_task", 2),
];

/// A protocol test's Python server (a toy, or a package's own server with a dummy model): it
/// prints `listening on PORT` once it accepts connections and logs what it decoded and sent as
/// one JSON object per line (`{"event": ...}`) to `log`. Killed when dropped.
pub struct LoggedServer {
    child: Child,
    pub port: u16,
    log: PathBuf,
}

impl LoggedServer {
    /// `python script --port PORT --log LOG ARGS...` (port 0: the server picks one and says it).
    pub fn start(python: &Path, script: &str, port: u16, log: PathBuf, args: &[&str]) -> LoggedServer {
        let mut child = Command::new(python)
            .arg(repo_root().join(script))
            .args(["--port", &port.to_string(), "--log", log.to_str().unwrap()])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("start {script}: {e}"));
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
        let port = line
            .trim()
            .strip_prefix("listening on ")
            .and_then(|p| p.parse().ok())
            .unwrap_or_else(|| panic!("{script} said {line:?}"));
        LoggedServer { child, port, log }
    }

    pub fn url(&self) -> String {
        format!("ws://127.0.0.1:{}", self.port)
    }

    /// The logged events of one kind, in order.
    pub fn events(&self, kind: &str) -> Vec<serde_json::Value> {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        text.lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
            .filter(|e| e["event"] == kind)
            .collect()
    }
}

impl Drop for LoggedServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `pipeline specs` for libero_spatial task 0, `trials` episodes, written to `dir/specs.parquet`.
pub fn spatial_task0_specs(dir: &Path, trials: &str) -> PathBuf {
    let specs = dir.join("specs.parquet");
    let out = specs.to_str().unwrap();
    ok(pipeline(&["specs", "--suites", "libero_spatial", "--tasks", "0", "--trials", trials, "-o", out]));
    specs
}
