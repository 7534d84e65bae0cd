//! `pipeline bench perturbation`: what each perturbation adds to an episode's wall time.
//!
//! One task, one env, the policy's camera (agentview only, at a policy's size), the same actions:
//! an episode is a reset, then per policy step a render of what the policy sees and an env step.
//! It runs unperturbed, then with each hook: the camera viewpoint and the robot init pose (edits at
//! reset) and the sensor noise of each of the five kinds at its costliest severity (per frame), then
//! LIBERO-PRO's robustness cases with their shipped values. The policy's own time is left out, so
//! the overhead is measured against the cheapest episode there is; the goal is ≤ 5%. The
//! median and the minimum over the repeats are printed (the minimum resists a busy machine).
//!
//! `--camera-category` times instead every view of the suite's LIBERO-Plus Camera variants against
//! the nominal Plus view: a view's cost is its picture's (Mesa's 4× multisampled rasteriser pays
//! for the edges in sight), so one view says little and the category's weighted mean is the figure.

use crate::bench::bench_action;
use anyhow::Result;
use libero_schema::Suite;
use libero_sim::bundle::BundleSet;
use libero_sim::dark_noise::DarkNoise;
use libero_sim::env::{Appearance, EpisodeEdits, InitialPose, LiberoEnv, Lighting, ObjectShift, RuntimeMove};
use libero_sim::image_noise::{NoiseRevision, SeededDraws, SensorNoise};
use libero_sim::viewpoint::{self, CameraPose, ViewParams};
use libero_udfs::policy_cameras::PolicyCameras;
use std::path::Path;
use std::time::Instant;

pub const EXAMPLES: &str = "\
Examples:
  pipeline bench perturbation
  pipeline bench perturbation --suite libero_goal --only noise --repeats 5
  pipeline bench perturbation --camera-category --every 4 --steps 20";

#[derive(clap::Args)]
pub struct PerturbationArgs {
    /// The suite of the task timed.
    #[arg(long, default_value = "libero_spatial")]
    suite: Suite,
    /// The task timed (its id in --suite).
    #[arg(long, default_value_t = 0)]
    task: u32,
    /// Policy steps per episode (after the reset).
    #[arg(long, default_value_t = 60)]
    steps: u32,
    /// The policy camera's size (OpenVLA's 256, the published loops' render size; lb2025 fog needs
    /// exactly 256, lb2025 glass blur at least 224).
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Interleaved repetitions; the median is printed.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Time only the cases whose name contains one of these (comma-separated), beside the
    /// unperturbed one.
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// Instead of one case per hook, time every distinct view of the suite's LIBERO-Plus Camera
    /// variants against the nominal Plus view, and print the distribution of the overhead (each
    /// view weighted by its number of variants, as the category's episodes are).
    #[arg(long)]
    camera_category: bool,
    /// With --camera-category: time every Nth view only (in the order of their parameters).
    #[arg(long, default_value_t = 1)]
    every: usize,
}

/// One configuration: its name, the env edits, and the noise on every frame.
struct Case {
    name: String,
    edits: EpisodeEdits,
    noise: Option<SensorNoise>,
    /// LIBERO-PRO's dark noise on every frame (its field drawn once per episode).
    dark: Option<DarkNoise>,
}

pub fn run(bundles: &Path, args: PerturbationArgs) -> Result<()> {
    let set = BundleSet::open(bundles)?;
    let bundle = set.load(args.suite, args.task)?;
    let mut env = LiberoEnv::new(&bundle)?;
    let mut cameras = PolicyCameras::new(&mut env, args.size)?;
    let view =
        ViewParams { azimuth_deg: 30.0, elevation_deg: 15.0, distance_pct: 150.0, pan_deg: 4.0, tilt_deg: 356.0 };
    let pose = viewpoint::plus_agentview(viewpoint::nominal_agentview(&bundle.task.problem)?, &view);
    let c = &bundle.task.controller;
    let q: [f64; 7] = std::array::from_fn(|i| c.initial_joint[i] + if i % 2 == 0 { 0.05 } else { -0.05 });
    let mut cases = vec![
        Case { name: "none".into(), edits: EpisodeEdits::default(), noise: None, dark: None },
        Case {
            name: "camera viewpoint".into(),
            edits: EpisodeEdits { agentview: Some(pose), ..Default::default() },
            noise: None,
            dark: None,
        },
        Case {
            name: "robot init pose".into(),
            edits: EpisodeEdits { robot_init_qpos: Some(q), ..Default::default() },
            noise: None,
            dark: None,
        },
    ];
    // each kind at its costliest severity (motion, Gaussian, fog and glass blur grow with it; zoom
    // blur peaks at severity 7, whose 41 zoom factors are the most)
    for level in [10, 20, 27, 40, 50] {
        let noise = SensorNoise::new(level, NoiseRevision::Lb2025).map_err(anyhow::Error::msg)?;
        cases.push(Case {
            name: format!("noise {level} ({})", noise.kind()),
            edits: EpisodeEdits::default(),
            noise: Some(noise),
            dark: None,
        });
    }
    // LIBERO-PRO's robustness cases, shipped values (data/libero_pro_robustness.json)
    let dark_light = Lighting { ambient: Some(0.02), diffuse: Some(0.16), specular: Some(0.01) };
    let shift = |delta_xy: [f64; 2]| ObjectShift {
        object: bundle.task.goal.iter().find(|p| p.len() == 3).map(|p| p[1].clone()).unwrap_or_default(),
        delta_xy,
        min_delta_norm: 0.18,
    };
    let pro = |name: &str, edits: EpisodeEdits, dark: Option<DarkNoise>| Case {
        name: format!("PRO {name}"),
        edits,
        noise: None,
        dark,
    };
    cases.extend([
        pro(
            "lighting + dark noise",
            EpisodeEdits { lighting: Some(dark_light), ..Default::default() },
            Some(DarkNoise { brightness: 0.68, std: 12.0 }),
        ),
        pro(
            "camera (raw pose)",
            EpisodeEdits {
                agentview_raw: Some(CameraPose {
                    pos: [0.48, 0.24, 1.62],
                    quat: [0.6099232, 0.3594558, 0.3594558, 0.6099232],
                }),
                ..Default::default()
            },
            None,
        ),
        pro(
            "appearance",
            EpisodeEdits {
                appearance: Some(Appearance {
                    objects: bundle.task.goal.iter().find(|p| p.len() == 3).map(|p| p[2].clone()).into_iter().collect(),
                    rgba: [0.72, 0.63, 0.5, 1.0],
                }),
                ..Default::default()
            },
            None,
        ),
        pro(
            "initial pose",
            EpisodeEdits {
                initial_pose: Some(InitialPose { shift: shift([0.17, -0.06]), yaw: Some(std::f64::consts::FRAC_PI_4) }),
                ..Default::default()
            },
            None,
        ),
        pro(
            "runtime move",
            EpisodeEdits {
                runtime_move: Some(RuntimeMove {
                    shift: shift([0.17, 0.06]),
                    trigger_distance: 0.09,
                    fallback_step: 20,
                }),
                ..Default::default()
            },
            None,
        ),
    ]);
    // the views of the suite's Camera variants, with how many variants each has
    let mut weights: Vec<f64> = vec![1.0; cases.len()];
    if args.camera_category {
        let catalogue = crate::libero_plus::Catalogue::open(bundles)?;
        let mut views: std::collections::BTreeMap<[i32; 5], usize> = Default::default();
        for e in catalogue.variants.get(&args.suite.name()).into_iter().flatten() {
            if let Ok((_, crate::libero_plus::Perturbation::Camera { view })) = crate::libero_plus::parse_name(&e.name)
            {
                *views.entry(view).or_default() += 1;
            }
        }
        anyhow::ensure!(!views.is_empty(), "no LIBERO-Plus Camera variants of {} in the variant table", args.suite);
        let nominal = viewpoint::nominal_agentview(&bundle.task.problem)?;
        let case = |name: String, v: [i32; 5]| {
            let [h, e, d, r, t] = v.map(f64::from);
            let view = ViewParams { azimuth_deg: h, elevation_deg: e, distance_pct: d, pan_deg: r, tilt_deg: t };
            Case {
                name,
                edits: EpisodeEdits {
                    agentview: Some(viewpoint::plus_agentview(nominal, &view)),
                    ..Default::default()
                },
                noise: None,
                dark: None,
            }
        };
        cases = vec![case("none (nominal Plus view)".into(), [0, 0, 100, 0, 0])];
        weights = vec![0.0];
        for (v, n) in views.iter().step_by(args.every.max(1)) {
            cases.push(case(format!("view {v:?}"), *v));
            weights.push(*n as f64);
        }
    }
    if !args.only.is_empty() {
        let keep: Vec<bool> = cases
            .iter()
            .enumerate()
            .map(|(i, c)| i == 0 || args.only.iter().any(|o| c.name.contains(o.as_str())))
            .collect();
        let mut k = keep.iter();
        cases.retain(|_| *k.next().unwrap());
        let mut k = keep.iter();
        weights.retain(|_| *k.next().unwrap());
    }
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); cases.len()];
    for _ in 0..args.repeats {
        for (i, case) in cases.iter().enumerate() {
            let t0 = Instant::now();
            env.set_episode_edits(case.edits.clone())?;
            env.reset(0, 0)?;
            let mut dark_field: Option<Vec<f64>> = None;
            for t in 0..args.steps {
                let mut images = cameras.capture(&mut env, false)?;
                if let Some(noise) = &case.noise {
                    let a = &mut images.agentview;
                    noise
                        .apply(&mut a.rgb, a.width as usize, a.height as usize, &mut SeededDraws::new(t as u64))
                        .map_err(anyhow::Error::msg)?;
                }
                if let Some(dark) = &case.dark {
                    let a = &mut images.agentview;
                    let field = dark_field.get_or_insert_with(|| dark.field(7, a.rgb.len()));
                    dark.apply(&mut a.rgb, field).map_err(anyhow::Error::msg)?;
                }
                std::hint::black_box(&images);
                env.step(bench_action(t))?;
            }
            times[i].push(t0.elapsed().as_secs_f64() * 1e3 / args.steps as f64);
        }
    }
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    let (base, base_min) = (median(&times[0]), min(&times[0]));
    println!(
        "{} task {}, {} policy steps per episode, agentview {}x{}, median of {} (reset + render + env step; no policy):",
        args.suite, args.task, args.steps, args.size, args.size, args.repeats
    );
    if args.camera_category {
        return print_camera_category(&cases, &times, &weights, base, base_min);
    }
    println!("{:<28} {:>12} {:>10} {:>12} {:>10}", "perturbation", "ms per step", "overhead", "min ms", "overhead");
    for (case, t) in cases.iter().zip(&times) {
        let (m, lo) = (median(t), min(t));
        println!(
            "{:<28} {:>12.2} {:>9.1}% {:>12.2} {:>9.1}%",
            case.name,
            m,
            100.0 * (m - base) / base,
            lo,
            100.0 * (lo - base_min) / base_min
        );
    }
    Ok(())
}

/// The overhead of a suite's Camera variants against the nominal view: its weighted mean (what
/// the category adds to its episodes), the quantiles over views, and the five costliest views.
fn print_camera_category(cases: &[Case], times: &[Vec<f64>], weights: &[f64], base: f64, base_min: f64) -> Result<()> {
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    // (overhead of the median, overhead of the minimum, weight, name)
    let mut rows: Vec<(f64, f64, f64, &str)> = cases
        .iter()
        .zip(times)
        .zip(weights)
        .skip(1)
        .map(|((c, t), w)| {
            (100.0 * (median(t) - base) / base, 100.0 * (min(t) - base_min) / base_min, *w, c.name.as_str())
        })
        .collect();
    anyhow::ensure!(!rows.is_empty(), "no view left to time: --only matched none of the suite's Camera views");
    let total: f64 = rows.iter().map(|r| r.2).sum();
    let mean = |f: fn(&(f64, f64, f64, &str)) -> f64| rows.iter().map(|r| f(r) * r.2).sum::<f64>() / total;
    println!("nominal Plus view: {base:.2} ms per step (min {base_min:.2})");
    println!(
        "{} views ({} variants): overhead weighted by variants, mean {:+.1}% (of the minima {:+.1}%)",
        rows.len(),
        total,
        mean(|r| r.0),
        mean(|r| r.1)
    );
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    let q = |p: f64| rows[((rows.len() - 1) as f64 * p).round() as usize].0;
    println!(
        "over views: min {:+.1}%, p25 {:+.1}%, median {:+.1}%, p75 {:+.1}%, p90 {:+.1}%, max {:+.1}%",
        q(0.0),
        q(0.25),
        q(0.5),
        q(0.75),
        q(0.9),
        q(1.0)
    );
    let over = rows.iter().filter(|r| r.0 > 5.0).map(|r| r.2 as usize).sum::<usize>();
    println!("variants whose view adds more than 5%: {over} of {total}");
    println!("costliest views (H, V, S, R, E):");
    for r in rows.iter().rev().take(5) {
        println!("  {:<32} {:+.1}% (min {:+.1}%), {} variants", r.3, r.0, r.1, r.2);
    }
    Ok(())
}
