//! `pipeline smoke`: one picture per suite to look at before trusting anything else.
//!
//! Task 0, init state 0 of each suite, rendered as the policy's cameras see the scene (reference
//! quality, the published look), upright for a person: agentview | eye-in-hand, with the suite,
//! task and instruction as a caption. Written to `<out>/<suite>.png`.

use crate::media::{PanelArgs, render_panel, write_png};
use anyhow::Result;
use libero_schema::Suite;
use libero_sim::bundle::BundleSet;
use libero_sim::env::LiberoEnv;
use libero_sim::gl::GlContext;
use std::path::{Path, PathBuf};
use std::rc::Rc;

pub const EXAMPLES: &str = "\
Examples:
  pipeline smoke                                        # outputs/smoke/<suite>.png
  pipeline smoke --suites libero_goal_swap --task 3 --init-state 1 --out outputs/look";

#[derive(clap::Args)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "outputs/smoke")]
    out: PathBuf,
    /// Suites to picture, one PNG each.
    #[arg(long, value_delimiter = ',', default_value = "libero_spatial,libero_object,libero_goal,libero_10")]
    suites: Vec<Suite>,
    /// Task within each suite.
    #[arg(long, default_value_t = 0)]
    task: u32,
    /// Init state.
    #[arg(long, default_value_t = 0)]
    init_state: usize,
    /// Env seed (fixture poses); the canonical protocol's by default.
    #[arg(long, default_value_t = libero_schema::protocol::SEED)]
    seed: u64,
    #[command(flatten)]
    panel: PanelArgs,
}

pub fn run(bundles: &Path, args: Args) -> Result<()> {
    let set = BundleSet::open(bundles)?;
    let gl = Rc::new(GlContext::new()?);
    let layout = args.panel.layout();
    let options = args.panel.options(&layout);
    for suite in &args.suites {
        let bundle = set.load(*suite, args.task)?;
        let mut env = LiberoEnv::new(&bundle)?;
        env.reset(args.init_state, args.seed)?;
        let mut renderer = env.renderer(gl.clone(), options)?;
        let caption = format!(
            "{} task {}, init {}, seed {} (look {})\n{}",
            suite.name(),
            args.task,
            args.init_state,
            args.seed,
            args.panel.look.name(),
            bundle.task.instruction(Default::default()).0
        );
        let panel = render_panel(&mut env, &mut renderer, &layout, &caption)?;
        let path = args.out.join(format!("{}.png", suite.name()));
        write_png(&path, &panel)?;
        println!("{}  ({}x{}, {})", path.display(), panel.width, panel.height, gl.vendor());
    }
    Ok(())
}
