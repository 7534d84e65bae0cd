//! `pipeline bench ...`: benchmarks that print figures (speed goals live here, not in tests).
//!
//! `bench sim` runs, in one process and on the same tasks and actions:
//! the Rust env in both step modes, raw MuJoCo (`mj_step` × 25 per env step replaying the controls
//! the Rust env computed: the same physics without the controller, the limit), and the Python reference env (`scripts/reference/bench_reference.py` in the
//! reference venv), and prints env steps per second side by side.

use anyhow::{Context, Result, bail};
use libero_schema::Suite;
use libero_sim::bundle::BundleSet;
use libero_sim::env::{LiberoEnv, StepMode};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

pub const EXAMPLES: &str = "\
Examples:
  pipeline bench sim --python none          # Rust env and raw MuJoCo only
  pipeline bench run --run runs/pi05";

#[derive(clap::Subcommand)]
pub enum Bench {
    /// Env steps/s: Rust env vs the Python reference vs raw MuJoCo (no rendering).
    ///
    /// Per suite (task 0), the env steps per second of the Rust env in both step modes, of raw
    /// MuJoCo replaying the same controls (the limit) and of the Python reference env (the
    /// reference venv's --python), the median of --repeats interleaved measurements, printed.
    #[command(after_help = SIM_EXAMPLES)]
    Sim(SimArgs),
    /// Camera frames/s (agentview + eye-in-hand): this renderer vs the Python reference.
    ///
    /// Per suite (task 0), camera pairs rendered per second from one state, by this renderer and
    /// by the Python reference's; with --threads, several threads rendering at once as a run's
    /// workers do. Printed.
    #[command(after_help = RENDER_EXAMPLES)]
    Render(RenderArgs),
    /// A stored run's figures: episodes/s, peak RSS, files per table, re-scoring time.
    ///
    /// The episodes/s, peak RSS and render devices of each invocation that ran episodes, the files
    /// per table, and the wall time of re-scoring it (results under each definition, report). Reads the
    /// run's sessions/*.json and step timings (where a policy step's time goes, the projected
    /// wall time of the canonical protocol), then times `pipeline results` and `pipeline report`
    /// on it, each a fresh process (median of --repeats). Printed.
    #[command(after_help = crate::bench_run::EXAMPLES)]
    Run(crate::bench_run::RunArgs),
    /// What each perturbation adds to an episode's wall time (reset + render + step).
    ///
    /// One task and the same actions, unperturbed and then under each hook (camera viewpoint,
    /// robot init pose, sensor noise of each kind) and LIBERO-PRO robustness case, without the
    /// policy's own time; the median and minimum overhead over --repeats are printed.
    /// --camera-category times every view of LIBERO-Plus's Camera variants instead.
    #[command(after_help = crate::bench_perturbation::EXAMPLES)]
    Perturbation(crate::bench_perturbation::PerturbationArgs),
}

const SIM_EXAMPLES: &str = "\
Examples:
  pipeline bench sim                                  # needs the reference venv (.venv)
  pipeline bench sim --suites libero_goal --steps 1000 --python none";

const RENDER_EXAMPLES: &str = "\
Examples:
  pipeline bench render --python none
  pipeline bench render --threads 4 --frames 50 --python none
  pipeline bench render --threads 32 --frames 150 --camera agentview --python none";

#[derive(clap::Args)]
pub struct RenderArgs {
    /// Camera pairs (with `--camera`, that camera's frames) rendered per measurement.
    #[arg(long, default_value_t = 30)]
    frames: u32,
    /// Camera size in pixels.
    #[arg(long, default_value_t = libero_sim::render::DEFAULT_SIZE)]
    size: u32,
    /// Suites to measure (task 0 of each).
    #[arg(long, value_delimiter = ',', default_value = "libero_spatial,libero_object,libero_goal,libero_10")]
    suites: Vec<Suite>,
    /// Python of the reference venv; `none` skips the reference measurement.
    #[arg(long, default_value = ".venv/bin/python")]
    python: PathBuf,
    /// Threads rendering at once in this process, as a run's workers do (through GL threads,
    /// `libero_sim::gl_thread`: the GPU's one shared thread, or one each on the CPU or with
    /// `LIBERO_GL_THREADS=per-worker`): with more than one, each renders `--frames` agentview +
    /// wrist pairs (or `--camera`'s frames) of the first suite's task 0 at reference quality, and
    /// the spread of their ms per pair and the pairs/s of all are printed instead (compare with as
    /// many processes of one thread).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// With `--threads`: each thread makes a GL context of its own and renders on it itself
    /// (how runs rendered before the GL threads), to compare.
    #[arg(long)]
    context_per_thread: bool,
    /// Render this one camera instead of the agentview + wrist pair (through the GL threads, as
    /// `--threads` does, also with one thread): `agentview` is all OpenVLA sees, so its GPU time
    /// is what a query of OpenVLA costs a model on the same GPU. Like `--threads`, it measures the
    /// first of `--suites` and no reference (`--python` is not used).
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(crate::media::CAMERAS))]
    camera: Option<String>,
}

#[derive(clap::Args)]
pub struct SimArgs {
    /// Env steps per task (after reset).
    #[arg(long, default_value_t = 300)]
    steps: u32,
    /// Suites to measure (task 0 of each).
    #[arg(long, value_delimiter = ',', default_value = "libero_spatial,libero_object,libero_goal,libero_10")]
    suites: Vec<Suite>,
    /// Python of the reference venv; `none` skips the reference measurement.
    #[arg(long, default_value = ".venv/bin/python")]
    python: PathBuf,
    /// Interleaved repetitions per measurement; the median is printed (shared machines are noisy).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
}

pub fn run(bundles: &Path, bench: Bench) -> Result<()> {
    match bench {
        Bench::Sim(args) => sim(bundles, args),
        Bench::Render(args) => render(bundles, args),
        Bench::Run(args) => crate::bench_run::run(args),
        Bench::Perturbation(args) => crate::bench_perturbation::run(bundles, args),
    }
}

/// The benchmark's action at step t: smooth motion plus gripper toggles (same formula in Python).
pub fn bench_action(t: u32) -> [f64; 7] {
    let t = t as f64;
    [
        0.5 * (0.1 * t).sin(),
        0.5 * (0.13 * t).cos(),
        0.3 * (0.07 * t).sin(),
        0.1 * (0.05 * t).sin(),
        0.1 * (0.05 * t).cos(),
        0.1 * (0.03 * t).sin(),
        if (0.2 * t).sin() >= 0.0 { 1.0 } else { -1.0 },
    ]
}

fn sim(bundles: &Path, args: SimArgs) -> Result<()> {
    let set = BundleSet::open(bundles)?;
    println!(
        "env steps/s, {} steps after reset(init 0, seed 0), no rendering, 1 thread, median of {}",
        args.steps, args.repeats
    );
    println!(
        "{:<15} {:>12} {:>14} {:>12} {:>12} {:>10} {:>10}",
        "suite", "rust split", "rust fwd+step", "raw mujoco", "python ref", "split/raw", "split/py"
    );
    for suite in &args.suites {
        let bundle = set.load(*suite, 0)?;
        let mut env = LiberoEnv::new(&bundle)?;
        let rate = |env: &mut LiberoEnv, mode| -> Result<f64> {
            env.set_step_mode(mode);
            env.reset(0, 0)?;
            let t0 = Instant::now();
            for t in 0..args.steps {
                env.step(bench_action(t))?;
            }
            Ok(args.steps as f64 / t0.elapsed().as_secs_f64())
        };
        env.log_controls(true);
        rate(&mut env, StepMode::Split)?;
        let controls = env.log_controls(false).unwrap_or_default();
        let (mut split, mut fwd, mut raw) = (vec![], vec![], vec![]);
        for _ in 0..args.repeats.max(1) {
            split.push(rate(&mut env, StepMode::Split)?);
            fwd.push(rate(&mut env, StepMode::ForwardThenStep)?);
            raw.push(raw_mujoco_rate(&bundle, args.steps, &controls)?);
        }
        let (split, fwd, raw) = (median(split), median(fwd), median(raw));
        let py =
            if args.python.as_os_str() == "none" { None } else { Some(python_rate(&args.python, *suite, args.steps)?) };
        println!(
            "{:<15} {:>12.1} {:>14.1} {:>12.1} {:>12} {:>9.0}% {:>10}",
            suite.name(),
            split,
            fwd,
            raw,
            py.map_or("-".into(), |p| format!("{p:.1}")),
            100.0 * split / raw,
            py.map_or("-".into(), |p| format!("{:.1}x", split / p)),
        );
    }
    Ok(())
}

/// Frames/s of the two policy cameras, rendered from one state (no physics in the timed loop).
fn render(bundles: &Path, args: RenderArgs) -> Result<()> {
    use libero_sim::gl::GlContext;
    use libero_sim::render::{Quality, RenderOptions};
    let set = BundleSet::open(bundles)?;
    if args.threads > 1 || args.camera.is_some() {
        return render_threads(&set, &args);
    }
    let gl = std::rc::Rc::new(GlContext::new()?);
    println!(
        "camera pairs/s (agentview + robot0_eye_in_hand, {0}x{0}), {1} pairs, 1 thread, GL vendor {2:?}, device {3:?}",
        args.size,
        args.frames,
        gl.vendor(),
        gl.device()
    );
    println!(
        "{:<15} {:>14} {:>14} {:>14} {:>10} {:>12} {:>14}",
        "suite", "rust reference", "rust preview", "python ref", "rust/py", "ms per pair", "setup ms"
    );
    for suite in &args.suites {
        let bundle = set.load(*suite, 0)?;
        let mut env = LiberoEnv::new(&bundle)?;
        env.reset(0, 0)?;
        // the upload of the scene (meshes, textures) a new renderer makes, the reference one's
        let mut setup_ms = 0.0;
        let mut rate = |quality| -> Result<f64> {
            let options = RenderOptions { quality, ..Default::default() };
            let t0 = Instant::now();
            let mut renderer = env.renderer(gl.clone(), options)?;
            if quality == Quality::Reference {
                setup_ms = 1000.0 * t0.elapsed().as_secs_f64();
            }
            for cam in crate::media::CAMERAS {
                env.render(&mut renderer, cam, args.size, args.size)?; // warm-up
            }
            let t0 = Instant::now();
            for _ in 0..args.frames {
                for cam in crate::media::CAMERAS {
                    env.render(&mut renderer, cam, args.size, args.size)?;
                }
            }
            Ok(args.frames as f64 / t0.elapsed().as_secs_f64())
        };
        let reference = rate(Quality::Reference)?;
        let preview = rate(Quality::Preview)?;
        let py = if args.python.as_os_str() == "none" {
            None
        } else {
            Some(python_render_rate(&args.python, *suite, args.frames, args.size)?)
        };
        println!(
            "{:<15} {:>14.1} {:>14.1} {:>14} {:>10} {:>12.1} {:>14.1}",
            suite.name(),
            reference,
            preview,
            py.map_or("-".into(), |p| format!("{p:.1}")),
            py.map_or("-".into(), |p| format!("{:.2}x", reference / p)),
            1000.0 / reference,
            setup_ms,
        );
    }
    Ok(())
}

/// `bench render --threads N`: N threads of this process rendering at once, each with its own GL
/// context (on the EGL devices in turn, as a run's workers'), each its own env of one task.
fn render_threads(set: &BundleSet, args: &RenderArgs) -> Result<()> {
    use libero_sim::gl::GlContext;
    use libero_sim::gl_thread::{GlThread, GlThreads, OnGlThread};
    use libero_sim::render::{RenderOptions, SceneRenderer};
    let suite = *args.suites.first().context("--suites is empty")?;
    let bundle = set.load(suite, 0)?;
    let barrier = std::sync::Barrier::new(args.threads);
    let (frames, size) = (args.frames, args.size);
    // One thread's measurement: ms per camera pair and the EGL (device, CUDA device) it rendered on.
    let measure = |env: &mut LiberoEnv, render: &mut dyn FnMut(&mut LiberoEnv) -> Result<()>| -> Result<f64> {
        let warm_up = render(env);
        barrier.wait(); // all threads render at the same time (each passes, failed or not)
        warm_up?;
        let t0 = Instant::now();
        for _ in 0..frames {
            render(env)?;
        }
        Ok(1000.0 * t0.elapsed().as_secs_f64() / f64::from(frames))
    };
    // the cameras of one "pair": both, or the one `--camera` names
    let cameras: Vec<&str> = args.camera.as_deref().map_or(crate::media::CAMERAS.to_vec(), |c| vec![c]);
    let pair = |env: &mut LiberoEnv, renderer: &mut SceneRenderer| -> Result<Vec<Vec<u8>>> {
        cameras.iter().map(|cam| Ok(env.render(renderer, cam, size, size)?.rgb)).collect()
    };
    // Per thread: ms per pair, the device, and whether its last pair through the GL thread equals
    // the pair a context of its own renders (`None` where it renders on its own context).
    type ThreadResult = Result<(f64, String, Option<bool>, bool)>;
    let results: Vec<ThreadResult> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..args.threads)
            .map(|t| {
                let (bundle, measure, pair, barrier) = (&bundle, &measure, &pair, &barrier);
                scope.spawn(move || -> ThreadResult {
                    let mut env = LiberoEnv::new(bundle)?;
                    // a different state per thread, so a frame drawn into another thread's buffer shows
                    env.reset(t % 10, 0)?;
                    let own_pair = |env: &mut LiberoEnv| -> Result<Vec<Vec<u8>>> {
                        let gl = std::rc::Rc::new(GlContext::new()?);
                        let mut renderer = env.renderer(gl, RenderOptions::default())?;
                        pair(env, &mut renderer)
                    };
                    if args.context_per_thread {
                        let gl = std::rc::Rc::new(GlContext::new()?);
                        let device = format!("{:?}", gl.device().map(|d| (d.index, d.cuda)));
                        let mut renderer = env.renderer(gl, RenderOptions::default())?;
                        let ms = measure(&mut env, &mut |env| pair(env, &mut renderer).map(drop))?;
                        return Ok((ms, device, None, false));
                    }
                    let thread = GlThread::for_worker()?;
                    let device = format!("{:?}", thread.device().map(|d| (d.index, d.cuda)));
                    let shared = GlThreads::from_env()?.shared_on(thread.device());
                    // SAFETY: the env and the renderer are used on the GL thread while this one waits.
                    let mut renderer =
                        unsafe { OnGlThread::make(thread, |gl| env.renderer(gl.clone(), RenderOptions::default()))? };
                    let ms = measure(&mut env, &mut |env| unsafe { renderer.with(|r| pair(env, r).map(drop)) });
                    let through = ms.is_ok().then(|| unsafe { renderer.with(|r| pair(&mut env, r)) });
                    barrier.wait(); // every thread's GL-thread renders done before the own contexts
                    let (ms, through) = (ms?, through.expect("rendered when measured")?);
                    drop(renderer);
                    Ok((ms, device, Some(through == own_pair(&mut env)?), shared))
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().expect("a render thread panicked")).collect()
    });
    let mut ms = Vec::new();
    let mut devices = std::collections::BTreeMap::<String, usize>::new();
    let (mut checked, mut equal, mut shared) = (0, 0, false);
    for r in results {
        let (t, d, same, through_shared) = r?;
        shared |= through_shared;
        ms.push(t);
        *devices.entry(d).or_default() += 1;
        checked += same.is_some() as usize;
        equal += (same == Some(true)) as usize;
    }
    ms.sort_by(f64::total_cmp);
    let all: f64 = ms.iter().map(|t| 1000.0 / t).sum();
    let (threads, suite) = (args.threads, suite.name());
    let (min, median, max) = (ms[0], ms[ms.len() / 2], ms[ms.len() - 1]);
    let how = if args.context_per_thread {
        "a GL context each, on the thread itself"
    } else if shared {
        "through the process's one shared GL thread"
    } else {
        "a GL thread each"
    };
    let (rendered, unit) = match &args.camera {
        None => ("camera pairs".to_string(), "pair"),
        Some(camera) => (format!("{camera} frames (that camera alone)"), "frame"),
    };
    println!(
        "{threads} threads of one process ({how}), {frames} {rendered} each ({size}x{size}, task 0 of {suite}): \
         ms per {unit} min {min:.1}, median {median:.1}, max {max:.1}; {all:.0} {unit}s/s in all; threads per (EGL \
         device, CUDA device): {devices:?}"
    );
    if checked > 0 {
        // the same check as tests/render.rs, on whatever GPU this runs
        println!(
            "threads whose last {unit} equals, bit for bit, the {unit} a GL context of their own renders: {equal} of {checked}"
        );
        if equal < checked {
            bail!(
                "{} thread(s) got other frames through the GL thread than on a context of their own",
                checked - equal
            );
        }
    }
    Ok(())
}

fn python_render_rate(python: &Path, suite: Suite, frames: u32, size: u32) -> Result<f64> {
    let args = [&suite.name(), "0", &frames.to_string(), &size.to_string()];
    reference_figure(python, "bench_render.py", &args, "pairs_per_s")
}

/// Run `scripts/reference/<script>` in the reference venv and read `key` from the JSON line it
/// prints last.
fn reference_figure(python: &Path, script: &str, args: &[&str], key: &str) -> Result<f64> {
    let script = Path::new("scripts/reference").join(script);
    let out = Command::new(python).arg(&script).args(args).output().with_context(|| {
        format!("running {} {} (the reference venv; see ./setup.sh)", python.display(), script.display())
    })?;
    if !out.status.success() {
        bail!("{} failed: {}", script.display(), String::from_utf8_lossy(&out.stderr));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .rev()
        .find(|l| l.starts_with('{'))
        .with_context(|| format!("no JSON line from {}", script.display()))?;
    let v: serde_json::Value = serde_json::from_str(line)?;
    v[key].as_f64().with_context(|| format!("{key} missing in {}'s output", script.display()))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// 25 bare `mj_step`s per env step from the same init state, replaying the controls the Rust
/// env computed: the same physics (same contacts) without the controller, what physics alone costs.
fn raw_mujoco_rate(bundle: &libero_sim::bundle::TaskBundle, steps: u32, controls: &[f64]) -> Result<f64> {
    use libero_sim::scene;
    let mut model = scene::compile(bundle)?;
    scene::apply_fixture_poses(&mut model, bundle.fixture_poses(0, 0)?)?;
    let mut data = mujoco_rs::prelude::MjData::new(&model);
    let init = bundle.init_state(0)?;
    let (nq, nv) = (model.ffi().nq as usize, model.ffi().nv as usize);
    data.qpos_mut().copy_from_slice(&init[1..1 + nq]);
    data.qvel_mut().copy_from_slice(&init[1 + nq..1 + nq + nv]);
    data.forward();
    let substeps = bundle.task.control.substeps;
    let nu = model.ffi().nu as usize;
    anyhow::ensure!(controls.len() == (steps * substeps) as usize * nu, "control log has the wrong length");
    let t0 = Instant::now();
    for ctrl in controls.chunks_exact(nu) {
        data.ctrl_mut().copy_from_slice(ctrl);
        data.step();
    }
    Ok(steps as f64 / t0.elapsed().as_secs_f64())
}

fn python_rate(python: &Path, suite: Suite, steps: u32) -> Result<f64> {
    reference_figure(python, "bench_reference.py", &[&suite.name(), "0", &steps.to_string()], "steps_per_s")
}
