//! `pipeline tasks`: what the bundles hold (suite, task id, init states, instruction).

use anyhow::Result;
use libero_schema::Suite;
use libero_sim::bundle::BundleSet;
use std::path::Path;

#[derive(clap::Args)]
pub struct Args {
    /// Only this suite (e.g. libero_spatial, libero_goal_task).
    #[arg(long)]
    suite: Option<Suite>,
    /// Print JSON lines instead of a table.
    #[arg(long)]
    json: bool,
}

pub fn run(bundles: &Path, args: Args) -> Result<()> {
    let set = BundleSet::open(bundles)?;
    let rows = set.tasks().iter().filter(|t| args.suite.is_none_or(|s| t.suite == s.name()));
    if args.json {
        for t in rows {
            let row = serde_json::json!({"suite": t.suite, "task_id": t.task_id, "name": t.name,
                "instruction": t.instructions.published, "instruction_bddl": t.instructions.bddl,
                "instruction_filename": t.instructions.filename, "init_states": t.n_init_states});
            println!("{row}");
        }
        return Ok(());
    }
    println!(
        "{:<21} {:>4} {:>6}  instruction (the published evaluation's; `--json` gives both texts)",
        "suite", "task", "inits"
    );
    let mut n = 0;
    for t in rows {
        println!("{:<21} {:>4} {:>6}  {}", t.suite, t.task_id, t.n_init_states, t.instructions.published);
        n += 1;
    }
    println!("{n} tasks in {}", set.root().display());
    Ok(())
}
