//! Arrow schemas of the tables a run stores, defined once and documented field by field.
//!
//! A run directory holds:
//! - `specs.parquet`: the spec table the run was started with (every column, carried through);
//! - `steps/<episode>.parquet`: one part per episode, one row per env step ([`steps`]; an
//!   ALOHA-sim run's: [`aloha_steps`]);
//! - `episodes/<episode>.parquet`: one part per episode, one row ([`episodes`]) plus the spec's
//!   extra columns; its presence marks the episode finished (written after its steps part);
//! - `manifest.json` / `manifest.parquet`: the run manifest ([`manifest`]), also stored as Parquet
//!   key-value metadata ([`MANIFEST_METADATA_KEY`]) in every part.
//!
//! Each field carries its documentation in the Arrow field metadata under [`DOC_KEY`], so the
//! book's column reference (`docs/src/tables.md`, rendered by [`crate::tables_reference`]) and
//! notebooks (`pyarrow.parquet.read_schema(...).field(...).metadata`) show it. Changing a table
//! bumps [`TABLES_VERSION`].

use arrow_schema::{DataType, Field, Fields, Schema, SchemaRef};
use std::collections::HashMap;
use std::sync::{Arc, LazyLock};

/// Version of the step/episode/manifest layout; stored in every manifest and part.
pub const TABLES_VERSION: u32 = 9;
/// Arrow field-metadata key holding a field's documentation.
pub const DOC_KEY: &str = "doc";
/// Parquet key-value metadata key holding the run manifest (JSON) in every part.
pub const MANIFEST_METADATA_KEY: &str = "libero_eval.manifest";

/// The spec columns every spec table must have, with the Arrow type they are read as.
pub const SPEC_COLUMNS: [(&str, DataType); 4] = [
    ("suite", DataType::Utf8),
    ("task_id", DataType::Int32),
    ("init_state_id", DataType::Int32),
    ("seed", DataType::Int64),
];

fn field(name: &str, data_type: DataType, nullable: bool, doc: &str) -> Field {
    Field::new(name, data_type, nullable).with_metadata(HashMap::from([(DOC_KEY.to_string(), doc.to_string())]))
}

/// `FixedSizeList<item>` of `n` non-null values.
pub fn fixed_list(item: DataType, n: i32) -> DataType {
    DataType::FixedSizeList(Arc::new(Field::new("item", item, false)), n)
}

/// `List<item>` of non-null values.
pub fn list(item: DataType) -> DataType {
    DataType::List(Arc::new(Field::new("item", item, false)))
}

/// The fields of one object pose inside `steps.object_poses`.
pub fn object_pose_fields() -> Fields {
    Fields::from(vec![
        field("name", DataType::Utf8, false, "object or fixture name, as in the BDDL"),
        field("pos", fixed_list(DataType::Float64, 3), false, "root body position (m, world frame)"),
        field("quat", fixed_list(DataType::Float64, 4), false, "root body orientation (w, x, y, z)"),
    ])
}

fn key_fields() -> Vec<Field> {
    vec![
        field(
            "episode_key",
            DataType::Utf8,
            false,
            "`suite/task_id/init_state_id/seed`, then `/v<variant>` for a perturbed episode: unique within a run, the join key of every table",
        ),
        field("suite", DataType::Utf8, false, "LIBERO suite, e.g. libero_spatial"),
        field("task_id", DataType::Int32, false, "task index within the suite (0-based, LIBERO order)"),
        field("init_state_id", DataType::Int32, false, "index into the task's init states (= trial index)"),
        field(
            "seed",
            DataType::Int64,
            false,
            "env seed: fixture poses are those of episode init_state_id after env.seed(seed) (the canonical protocol: seeded once per task), or after env.seed(seed) and one reset (protocol lerobot: seeded at every reset)",
        ),
    ]
}

/// One row per env step, wait steps included.
pub fn steps() -> SchemaRef {
    static S: LazyLock<SchemaRef> = LazyLock::new(|| {
        let mut f = key_fields();
        f.extend([
            field("step", DataType::Int32, false, "env step index from 0, wait steps included"),
            field(
                "policy_step",
                DataType::Int32,
                true,
                "policy step index from 0; null for the protocol's wait steps. The episode cap counts these",
            ),
            field("is_wait", DataType::Boolean, false, "a protocol wait step (no motion, gripper open), not a policy action"),
            field(
                "action",
                fixed_list(DataType::Float32, 7),
                false,
                "action sent to the env: delta eef pos (3), delta axis-angle (3), gripper (-1 open … +1 close); before clipping",
            ),
            field("eef_pos", fixed_list(DataType::Float64, 3), false, "end-effector (grip site) position after the step (m)"),
            field("eef_quat", fixed_list(DataType::Float64, 4), false, "end-effector orientation after the step (w, x, y, z)"),
            field("gripper_qpos", fixed_list(DataType::Float64, 2), false, "the two finger joint positions after the step (m)"),
            field("joint_pos", fixed_list(DataType::Float64, 7), false, "arm joint positions after the step (rad)"),
            field(
                "object_poses",
                list(DataType::Struct(object_pose_fields())),
                false,
                "pose of every object and fixture after the step",
            ),
            field("goal", DataType::Boolean, false, "the BDDL goal (AND of its terms) after the step, as check_success()"),
            field(
                "goal_terms",
                list(DataType::Boolean),
                false,
                "truth of each goal term after the step; names in episodes.goal_terms",
            ),
            field(
                "gripper_contacts",
                list(DataType::Utf8),
                false,
                "objects/fixtures touching a gripper geom after the step (grasp evidence for failure analysis)",
            ),
        ]);
        f.extend(step_timing_fields());
        f.push(held_field());
        Arc::new(Schema::new(f))
    });
    S.clone()
}

/// Where a step's wall time went: the same columns for every benchmark (queries/step_timing.sql).
fn step_timing_fields() -> Vec<Field> {
    vec![
        field("sim_ms", DataType::Float32, false, "wall time of the env step (ms)"),
        field(
            "policy_ms",
            DataType::Float32,
            false,
            "wall time of the policy call that produced the action (ms); 0 for wait steps",
        ),
        field(
            "render_ms",
            DataType::Float32,
            true,
            "wall time rendering the policy's cameras before this step (ms); 0 when it saw none; null in runs before tables v5",
        ),
        field(
            "queue_ms",
            DataType::Float32,
            true,
            "batched model policies: time the step's query waited for its forward to start (ms); null where the step queried no timed model (a queued chunk action, an unbatched policy)",
        ),
        field(
            "prepare_ms",
            DataType::Float32,
            true,
            "the worker's preparation of the step's model inputs before its query (image preprocessing; ms); null where the model prepares nothing apart",
        ),
        field("forward_ms", DataType::Float32, true, "the model forward that answered (ms, shared by its batch)"),
        field(
            "forward_id",
            DataType::Int64,
            true,
            "sequence number of that forward in the run process: the distinct (forward_id, forward_ms) of one invocation count its forwards",
        ),
        field("forward_batch", DataType::Int32, true, "episodes answered by that forward"),
    ]
}

/// Whether a step's action was the real-time hold: the same column for every benchmark.
fn held_field() -> Field {
    field(
        "held",
        DataType::Boolean,
        true,
        "real-time runs (manifest.realtime): the step commanded the hold action because the policy's answer had not arrived (its query's latency spans this step); false where the policy's own action ran, and in closed-loop runs; null in runs before tables v8",
    )
}

/// One row per env step of an ALOHA-sim episode (gym-aloha's joint-space tasks; no wait steps).
pub fn aloha_steps() -> SchemaRef {
    static S: LazyLock<SchemaRef> = LazyLock::new(|| {
        let mut f = key_fields();
        f.extend([
            field("step", DataType::Int32, false, "env step index from 0"),
            field("policy_step", DataType::Int32, true, "policy step index from 0 (= step: ALOHA-sim has no wait steps)"),
            field("is_wait", DataType::Boolean, false, "always false (the column is LIBERO's; kept so step queries read both)"),
            field(
                "action",
                fixed_list(DataType::Float32, 14),
                false,
                "action sent to the env: per arm (left, right) 6 absolute joint targets (rad) and a normalized gripper (0 closed … 1 open)",
            ),
            field(
                "agent_pos",
                fixed_list(DataType::Float64, 14),
                false,
                "obs[\"agent_pos\"] after the step: per arm 6 joint positions and the normalized left-finger position",
            ),
            field(
                "object_poses",
                list(DataType::Struct(object_pose_fields())),
                false,
                "pose of every free object after the step (red_box; or red_peg and blue_socket)",
            ),
            field("goal", DataType::Boolean, false, "the task is solved after the step: reward 4 (gym-aloha's is_success)"),
            field(
                "reward",
                DataType::Int32,
                false,
                "gym-aloha's reward after the step, 0-4, from the contacts: transfer_cube 1 right gripper touches the cube, 2 lifted by it, 3 left gripper touches it, 4 held by the left off the table; insertion 1 both grippers touch their objects, 2 both lifted, 3 peg touches socket, 4 peg touches the pin",
            ),
        ]);
        f.extend(step_timing_fields());
        f.push(held_field());
        Arc::new(Schema::new(f))
    });
    S.clone()
}

/// One row per episode (before the spec table's extra columns, which are appended).
pub fn episodes() -> SchemaRef {
    static S: LazyLock<SchemaRef> = LazyLock::new(|| {
        let mut f = key_fields();
        f.extend([
            field(
                "base_suite",
                DataType::Utf8,
                true,
                "the LIBERO suite the episode's suite is (libero_goal) or perturbs (libero_goal_swap -> libero_goal); derived from the suite name. Null in runs written before tables v4 (the queries derive it there)",
            ),
            field(
                "perturbation",
                DataType::Utf8,
                true,
                "perturbation of the suite, derived from its name: none, LIBERO-PRO's swap, object, lan, task, env, or LIBERO-Plus's plus_layout (a displaced-object layout variant's own scene). Null in runs written before tables v4 (the queries derive it there)",
            ),
            field(
                "variant_hash",
                DataType::Utf8,
                true,
                "the episode's perturbation variant: 12 hex digits of the sha256 of perturbation_params, part of episode_key; null for an episode whose spec row sets no perturbation column and no `variant` name (and in runs before tables v6)",
            ),
            field(
                "perturbation_params",
                DataType::Utf8,
                true,
                "what the spec row's perturbation columns set, as applied: canonical JSON (camera view, robot_init_qpos, instruction, sensor_noise, variant name); null when nothing",
            ),
            field(
                "instruction",
                DataType::Utf8,
                false,
                "the instruction the policy was given (which text: instruction_source)",
            ),
            field(
                "instruction_source",
                DataType::Utf8,
                true,
                "which text `instruction` is: filename (task.language, the published loops' for the LIBERO suites) or bddl (the BDDL (:language ...) tag, LIBERO-PRO's); `pipeline run --instruction`; task for ALOHA-sim (its task's prompt). Null before tables v4 (bddl then)",
            ),
            field(
                "start_sha256",
                DataType::Utf8,
                true,
                "sha256 of everything the episode starts from: the scene (scene.xml's hash), the fixture poses of (seed, init_state_id) and the init state row. Equal hashes start identically, so their episodes pair (queries/robustness.sql). Null before tables v4 or when the episode could not start",
            ),
            field("policy", DataType::Utf8, false, "policy name (identity in the manifest)"),
            field("run_config", DataType::Utf8, false, "hash of the run configuration (manifest.run_config)"),
            field("max_steps", DataType::Int32, false, "episode cap in policy steps used for this episode"),
            field("num_steps_wait", DataType::Int32, false, "wait steps before the policy acts"),
            field(
                "stop_on_success",
                DataType::Boolean,
                false,
                "true: stopped at the first success (published scripts); false: ran to the cap (run to horizon)",
            ),
            field("n_policy_steps", DataType::Int32, false, "policy steps executed"),
            field(
                "success",
                DataType::Boolean,
                false,
                "default success definition (any-step within max_steps, as the published scripts' first-success latch); re-score from steps with `pipeline results --success`",
            ),
            field(
                "first_success_step",
                DataType::Int32,
                true,
                "policy step at which the goal first held; null if never",
            ),
            field("final_goal", DataType::Boolean, false, "goal value at the last executed step (last-step evidence)"),
            field(
                "goal_changes",
                list(DataType::Int32),
                true,
                "policy steps at which the goal's value changed (the value before step 0 taken as false): the goal held at step p iff an odd number are <= p (`goal_held_at`). Re-scoring reads this instead of the steps (queries/score.sql); null in runs written before tables v3",
            ),
            field("goal_terms", list(DataType::Utf8), false, "BDDL text of each goal term, order of steps.goal_terms"),
            field(
                "objects_of_interest",
                list(DataType::Utf8),
                true,
                "objects the failure analysis watches (BDDL :obj_of_interest and the goal's objects, regions replaced by their owner); names as in steps.object_poses. Null in runs written before tables v2",
            ),
            field(
                "error_kind",
                DataType::Utf8,
                true,
                "null when the episode ran to its end; else sim_unstable, invalid_action, policy, bundle, render (the cameras of a policy that sees) or internal",
            ),
            field("error", DataType::Utf8, true, "the error message, null when none"),
            field("wall_s", DataType::Float64, false, "episode wall time, reset to last step (s)"),
            field("sim_s", DataType::Float64, false, "time in env steps (s)"),
            field("policy_s", DataType::Float64, false, "time in policy calls (s)"),
            field(
                "render_s",
                DataType::Float64,
                true,
                "time rendering the policy's cameras (s); null in runs before tables v5",
            ),
            field(
                "started_at",
                DataType::Float64,
                true,
                "Unix time the episode's reset began (s): with wall_s, the span a run's episodes covered; null in runs before tables v5",
            ),
            field(
                "env",
                DataType::Utf8,
                true,
                "the simulated benchmark the episode ran in, from its suite: libero (every LIBERO, LIBERO-PRO and LIBERO-Plus suite) or aloha_sim; null in runs before tables v7 (all LIBERO). (A LIBERO-Plus or LIBERO-PRO robustness spec table's own `benchmark` column, carried through, names the protocol that made its rows.)",
            ),
            field(
                "protocol",
                DataType::Utf8,
                true,
                "which published loop the episode reproduces, from the spec column protocol: canonical (env.seed(seed) once per task, then a reset per episode: OpenVLA, openpi) or lerobot (env.seed(seed) right before the episode's one reset: lerobot-eval); its cap is that protocol's. Null for ALOHA-sim (lerobot's own loop) and in runs before tables v9 (canonical)",
            ),
        ]);
        Arc::new(Schema::new(f))
    });
    S.clone()
}

/// The run manifest as a one-row table.
pub fn manifest() -> SchemaRef {
    static S: LazyLock<SchemaRef> = LazyLock::new(|| {
        Arc::new(Schema::new(vec![
            field("tables_version", DataType::UInt32, false, "layout version of the stored tables"),
            field("run_config", DataType::Utf8, false, "hash of everything below that changes the steps"),
            field("created_at", DataType::Utf8, false, "UTC time the run was first started (RFC 3339)"),
            field("git_revision", DataType::Utf8, false, "git revision of the pipeline build (`-dirty` if modified)"),
            field("pipeline_version", DataType::Utf8, false, "pipeline crate version"),
            field("mujoco_version", DataType::Utf8, false, "MuJoCo library version linked"),
            field("bundle_format_version", DataType::UInt32, false, "task bundle format version"),
            field("bundles_hash", DataType::Utf8, false, "sha256 of the bundles' index and provenance files"),
            field("policy", DataType::Utf8, false, "policy name"),
            field(
                "policy_identity",
                DataType::Utf8,
                false,
                "policy identity (JSON): checkpoint hash, unnorm key, chunking, image preprocessing, parameters",
            ),
            field("num_steps_wait", DataType::Int32, false, "wait steps before the policy acts"),
            field("max_steps", DataType::Utf8, false, "episode caps per suite in policy steps (JSON)"),
            field("stop_on_success", DataType::Boolean, false, "episodes stop at the first success"),
            field("substeps_per_step", DataType::Int32, false, "physics substeps per env step"),
            field("control_freq_hz", DataType::Int32, false, "env control rate"),
            field(
                "instruction_source",
                DataType::Utf8,
                false,
                "which instruction text the policy was given: published (the suite's published evaluation's) or bddl",
            ),
            field(
                "env",
                DataType::Utf8,
                true,
                "the simulated benchmark of the run: libero or aloha_sim (which steps table its parts hold); null in runs before tables v7 (LIBERO)",
            ),
            field(
                "realtime",
                DataType::Utf8,
                true,
                "real-time evaluation (JSON: latency fixed ms or measured, hold repeat|stay); null for a closed-loop run, where the env waits for every answer",
            ),
            field(
                "protocol",
                DataType::Utf8,
                true,
                "which published loop the run's LIBERO episodes reproduce (the spec column protocol): canonical (env.seed once per task, OpenVLA's caps) or lerobot (env.seed before every reset, lerobot-eval's caps); null before tables v9 (canonical)",
            ),
        ]))
    });
    S.clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_is_documented_and_names_are_unique() {
        for schema in [steps(), aloha_steps(), episodes(), manifest()] {
            let mut names = std::collections::HashSet::new();
            for f in schema.fields() {
                assert!(names.insert(f.name().clone()), "duplicate field {}", f.name());
                let doc = f.metadata().get(DOC_KEY).map(String::as_str).unwrap_or("");
                assert!(doc.len() > 10, "field {} has no doc", f.name());
            }
        }
        for (name, dt) in SPEC_COLUMNS {
            for schema in [steps(), aloha_steps()] {
                let f = schema.field_with_name(name).unwrap().clone();
                assert_eq!(f.data_type(), &dt, "{name}");
            }
        }
    }
}
