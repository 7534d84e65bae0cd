//! Camera pairs/s of the Rust renderer on this machine's EGL (e.g. the NVIDIA GPU machine), with
//! no dependency beyond MuJoCo and libEGL, so it can be carried where the full binary cannot.
//!
//! usage: bench_render BUNDLES FRAMES SIZE SUITE[,SUITE..]   (task 0 of each suite)
//!
//! With `DUMP_DIR` set, also writes the reference-quality frames of both looks there as raw RGB
//! (`<suite>__<look>__<camera>.rgb`, reference orientation) to compare GL stacks.

use libero_sim::bundle::BundleSet;
use libero_sim::env::LiberoEnv;
use libero_sim::gl::GlContext;
use libero_sim::render::{Look, Quality, RenderOptions};
use std::rc::Rc;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, bundles, frames, size, suites] = &args[..] else {
        return Err("usage: bench_render BUNDLES FRAMES SIZE SUITE[,SUITE..]".into());
    };
    let (frames, size): (u32, u32) = (frames.parse()?, size.parse()?);
    let set = BundleSet::open(bundles)?;
    let gl = Rc::new(GlContext::new()?);
    println!("GL vendor {:?}, device {:?}, {size}x{size}, {frames} pairs", gl.vendor(), gl.device());
    for suite in suites.split(',') {
        let bundle = set.load(suite.parse()?, 0)?;
        let mut env = LiberoEnv::new(&bundle)?;
        env.reset(0, 0)?;
        if let Ok(dir) = std::env::var("DUMP_DIR") {
            for look in [Look::Mujoco323, Look::Mujoco337] {
                let mut r = env.renderer(gl.clone(), RenderOptions { look, ..Default::default() })?;
                for cam in ["agentview", "robot0_eye_in_hand"] {
                    let f = env.render(&mut r, cam, size, size)?;
                    std::fs::write(format!("{dir}/{suite}__{}__{cam}.rgb", look.name()), &f.rgb)?;
                }
            }
        }
        for quality in [Quality::Reference, Quality::Preview] {
            let t0 = Instant::now();
            let mut r = env.renderer(gl.clone(), RenderOptions { quality, ..Default::default() })?;
            let setup = t0.elapsed().as_secs_f64();
            let mut checksum = 0u64;
            for cam in ["agentview", "robot0_eye_in_hand"] {
                env.render(&mut r, cam, size, size)?;
            }
            let t0 = Instant::now();
            for _ in 0..frames {
                for cam in ["agentview", "robot0_eye_in_hand"] {
                    checksum += env.render(&mut r, cam, size, size)?.rgb.iter().map(|&v| v as u64).sum::<u64>();
                }
            }
            let rate = frames as f64 / t0.elapsed().as_secs_f64();
            println!(
                "{suite:<15} {quality:?}: {rate:8.1} pairs/s ({:.2} ms/pair), context {setup:.2} s, mean {:.1}",
                1000.0 / rate,
                checksum as f64 / (frames as f64 * 2.0 * (size * size * 3) as f64)
            );
        }
    }
    Ok(())
}
