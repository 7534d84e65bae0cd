//! `pipeline tasks`: what the bundles hold. LIBERO's tasks (suite, task id, init states,
//! instruction) from the task bundles, then ALOHA-sim's (suite `aloha_sim`: its two tasks, which
//! have no init states: an episode's seed places the objects) from its bundle (`data/aloha`).

use anyhow::Result;
use libero_schema::Suite;
use libero_schema::benchmark::{ALOHA_SUITE, aloha as aloha_protocol};
use libero_sim::aloha::{AlohaBundle, AlohaTask};
use libero_sim::bundle::BundleSet;
use std::path::{Path, PathBuf};

pub const EXAMPLES: &str = "\
Examples:
  pipeline tasks                              # every task: LIBERO's bundles, then ALOHA-sim's
  pipeline tasks --suite libero_goal          # one suite's 10 tasks and their instructions
  pipeline tasks --suite aloha_sim --json     # ALOHA-sim's tasks as JSON lines";

#[derive(clap::Args)]
pub struct Args {
    /// Only this suite: a LIBERO one (e.g. libero_spatial, libero_goal_task) or aloha_sim.
    #[arg(long, value_parser = parse_suite)]
    suite: Option<TaskSuite>,
    /// Print JSON lines instead of a table.
    #[arg(long)]
    json: bool,
    /// The ALOHA-sim bundle (default: data/aloha, as for `pipeline run`).
    #[arg(long)]
    aloha_bundle: Option<PathBuf>,
}

/// The suite `--suite` names: one of LIBERO's (from the task bundles) or ALOHA-sim's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum TaskSuite {
    Libero(Suite),
    AlohaSim,
}

fn parse_suite(s: &str) -> Result<TaskSuite, String> {
    if s == ALOHA_SUITE {
        return Ok(TaskSuite::AlohaSim);
    }
    s.parse::<Suite>().map(TaskSuite::Libero).map_err(|e| format!("{e}; and ALOHA-sim's {ALOHA_SUITE}"))
}

/// `bundles` resolves the LIBERO bundle folder; it is only called when LIBERO's tasks are listed.
pub fn run(bundles: impl FnOnce() -> Result<PathBuf>, args: Args) -> Result<()> {
    let aloha_dir = crate::bundles_location::resolve_aloha(args.aloha_bundle.as_deref());
    let aloha = match args.suite {
        Some(TaskSuite::AlohaSim) => {
            // asked for by name: a missing or damaged bundle is the error
            let bundle = AlohaBundle::open(&aloha_dir)?;
            return print_aloha(&bundle, args.json, true);
        }
        Some(TaskSuite::Libero(_)) => None,
        None => Some(AlohaBundle::open(&aloha_dir)),
    };
    let suite = match args.suite {
        Some(TaskSuite::Libero(s)) => Some(s),
        _ => None,
    };
    print_libero(&bundles()?, suite, args.json)?;
    match aloha {
        Some(Ok(bundle)) => print_aloha(&bundle, args.json, false),
        Some(Err(e)) => {
            // listed beside LIBERO's: its absence is a note (one line), not a failure
            let note = match e {
                libero_sim::SimError::BundleMissing { .. } => format!(
                    "ALOHA-sim ({ALOHA_SUITE}): no bundle at {}; ./setup.sh --suites aloha_sim builds it (or pass --aloha-bundle)",
                    aloha_dir.display()
                ),
                other => format!("ALOHA-sim ({ALOHA_SUITE}) not listed: {other}"),
            };
            if args.json {
                eprintln!("{note}");
            } else {
                println!("{note}");
            }
            Ok(())
        }
        None => Ok(()),
    }
}

fn print_libero(bundles: &Path, suite: Option<Suite>, json: bool) -> Result<()> {
    let set = BundleSet::open(bundles)?;
    let rows = set.tasks().iter().filter(|t| suite.is_none_or(|s| t.suite == s.name()));
    if json {
        for t in rows {
            let row = serde_json::json!({"suite": t.suite, "task_id": t.task_id, "name": t.name,
                "instruction": t.instructions.published, "instruction_bddl": t.instructions.bddl,
                "instruction_filename": t.instructions.filename, "init_states": t.n_init_states});
            println!("{row}");
        }
        return Ok(());
    }
    print_header();
    let mut n = 0;
    for t in rows {
        println!("{:<21} {:>4} {:>6}  {}", t.suite, t.task_id, t.n_init_states, t.instructions.published);
        n += 1;
    }
    println!("{n} tasks in {}", set.root().display());
    Ok(())
}

fn print_header() {
    println!(
        "{:<21} {:>4} {:>6}  instruction (the published evaluation's; `--json` gives both texts)",
        "suite", "task", "inits"
    );
}

/// ALOHA-sim's tasks: no init states (the seed of an episode draws its objects' poses), the
/// instruction a language-conditioned policy is given, and lerobot's protocol (episode i of a
/// task seeded 1000 + i, 50 per task), which `pipeline specs --benchmark aloha_sim` writes;
/// `header`: the table's header line first (not when LIBERO's rows were printed above).
fn print_aloha(bundle: &AlohaBundle, json: bool, header: bool) -> Result<()> {
    let first_seed = aloha_protocol::LEROBOT_FIRST_SEED;
    let episodes = aloha_protocol::EPISODES_PER_TASK;
    if json {
        for t in AlohaTask::ALL {
            let row = serde_json::json!({"suite": ALOHA_SUITE, "task_id": t.id(), "name": t.name(),
                "instruction": t.instruction(), "init_states": null, "seeded": true,
                "first_seed": first_seed, "episodes_per_task": episodes, "gym_id": t.gym_id()});
            println!("{row}");
        }
        return Ok(());
    }
    if header {
        print_header();
    }
    for t in AlohaTask::ALL {
        println!("{:<21} {:>4} {:>6}  {} ({})", ALOHA_SUITE, t.id(), "seeded", t.instruction(), t.name());
    }
    println!(
        "{} ALOHA-sim tasks in {}: no init states, episode i seeded {first_seed} + i (lerobot's protocol, \
         {episodes} per task: pipeline specs --benchmark aloha_sim)",
        AlohaTask::ALL.len(),
        bundle.dir().display()
    );
    Ok(())
}
