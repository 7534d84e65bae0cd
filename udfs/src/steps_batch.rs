//! Building the steps table of one episode as one Arrow batch ([`libero_schema::tables::steps`]).
//!
//! Values are appended into flat column buffers as the episode runs and turned into Arrow arrays
//! once at the end, so a step costs a few `Vec` pushes.

use arrow::array::{
    ArrayRef, BooleanArray, FixedSizeListArray, Float32Array, Float64Array, Int32Array, Int64Array, ListArray,
    RecordBatch, StringArray, StructArray,
};
use arrow::buffer::OffsetBuffer;
use arrow::datatypes::{DataType, Field};
use arrow::error::ArrowError;
use libero_schema::tables;
use std::sync::Arc;

/// The key columns every row of an episode repeats.
#[derive(Debug, Clone)]
pub struct EpisodeKey {
    pub episode_key: String,
    pub suite: String,
    pub task_id: i32,
    pub init_state_id: i32,
    pub seed: i64,
    /// The perturbation variant (12 hex digits, [`crate::perturbation::EpisodePerturbation::variant`]);
    /// None for an unperturbed episode.
    pub variant: Option<String>,
}

impl EpisodeKey {
    pub fn new(suite: &str, task_id: i32, init_state_id: i32, seed: i64) -> Self {
        Self::with_variant(suite, task_id, init_state_id, seed, None)
    }

    /// `suite/task_id/init_state_id/seed`, then `/v<variant>` for a perturbed episode.
    pub fn with_variant(suite: &str, task_id: i32, init_state_id: i32, seed: i64, variant: Option<&str>) -> Self {
        let tail = variant.map(|v| format!("/v{v}")).unwrap_or_default();
        EpisodeKey {
            episode_key: format!("{suite}/{task_id}/{init_state_id}/{seed}{tail}"),
            suite: suite.to_string(),
            task_id,
            init_state_id,
            seed,
            variant: variant.map(str::to_string),
        }
    }

    /// The key columns every steps table begins with, repeated for `n` rows.
    pub(crate) fn columns(&self, n: usize) -> Vec<ArrayRef> {
        vec![
            Arc::new(StringArray::from(vec![self.episode_key.as_str(); n])),
            Arc::new(StringArray::from(vec![self.suite.as_str(); n])),
            Arc::new(Int32Array::from(vec![self.task_id; n])),
            Arc::new(Int32Array::from(vec![self.init_state_id; n])),
            Arc::new(Int64Array::from(vec![self.seed; n])),
        ]
    }

    /// File name of the episode's parts: `libero_spatial-t03-i012-s7.parquet`, with `-v<variant>`
    /// before the extension for a perturbed episode.
    pub fn part_name(&self) -> String {
        let tail = self.variant.as_ref().map(|v| format!("-v{v}")).unwrap_or_default();
        format!("{}-t{:02}-i{:03}-s{}{tail}.parquet", self.suite, self.task_id, self.init_state_id, self.seed)
    }
}

/// One env step's evidence.
pub struct StepRecord<'a> {
    pub step: i32,
    pub policy_step: Option<i32>,
    pub action: [f32; 7],
    pub eef_pos: [f64; 3],
    pub eef_quat: [f64; 4],
    pub gripper_qpos: [f64; 2],
    pub joint_pos: [f64; 7],
    /// (pos, quat) per object, in the order of the builder's object names.
    pub object_poses: &'a [([f64; 3], [f64; 4])],
    pub goal: bool,
    pub goal_terms: &'a [bool],
    /// Indices into the object names.
    pub gripper_contacts: &'a [usize],
    pub sim_ms: f32,
    pub policy_ms: f32,
    pub render_ms: f32,
    /// The model timing behind `policy_ms`, where the policy reports one.
    pub timing: Option<libero_policies::ActTiming>,
    /// A real-time hold: the policy's answer had not arrived ([`crate::real_time`]).
    pub held: bool,
}

/// Column buffers for one episode's steps.
pub struct StepsBatchBuilder {
    key: EpisodeKey,
    object_names: Vec<String>,
    step: Vec<i32>,
    policy_step: Vec<Option<i32>>,
    action: Vec<f32>,
    eef_pos: Vec<f64>,
    eef_quat: Vec<f64>,
    gripper_qpos: Vec<f64>,
    joint_pos: Vec<f64>,
    object_pos: Vec<f64>,
    object_quat: Vec<f64>,
    goal: Vec<bool>,
    goal_terms: Vec<bool>,
    goal_terms_len: Vec<usize>,
    contacts: Vec<usize>,
    contacts_len: Vec<usize>,
    sim_ms: Vec<f32>,
    policy_ms: Vec<f32>,
    render_ms: Vec<f32>,
    timing: Vec<Option<libero_policies::ActTiming>>,
    held: Vec<bool>,
}

impl StepsBatchBuilder {
    pub fn new(key: EpisodeKey, object_names: Vec<String>) -> Self {
        StepsBatchBuilder {
            key,
            object_names,
            step: vec![],
            policy_step: vec![],
            action: vec![],
            eef_pos: vec![],
            eef_quat: vec![],
            gripper_qpos: vec![],
            joint_pos: vec![],
            object_pos: vec![],
            object_quat: vec![],
            goal: vec![],
            goal_terms: vec![],
            goal_terms_len: vec![],
            contacts: vec![],
            contacts_len: vec![],
            sim_ms: vec![],
            policy_ms: vec![],
            render_ms: vec![],
            timing: vec![],
            held: vec![],
        }
    }

    pub fn len(&self) -> usize {
        self.step.len()
    }

    pub fn is_empty(&self) -> bool {
        self.step.is_empty()
    }

    pub fn push(&mut self, r: &StepRecord) {
        assert_eq!(r.object_poses.len(), self.object_names.len(), "one pose per object");
        self.step.push(r.step);
        self.policy_step.push(r.policy_step);
        self.action.extend_from_slice(&r.action);
        self.eef_pos.extend_from_slice(&r.eef_pos);
        self.eef_quat.extend_from_slice(&r.eef_quat);
        self.gripper_qpos.extend_from_slice(&r.gripper_qpos);
        self.joint_pos.extend_from_slice(&r.joint_pos);
        for (p, q) in r.object_poses {
            self.object_pos.extend_from_slice(p);
            self.object_quat.extend_from_slice(q);
        }
        self.goal.push(r.goal);
        self.goal_terms.extend_from_slice(r.goal_terms);
        self.goal_terms_len.push(r.goal_terms.len());
        self.contacts.extend_from_slice(r.gripper_contacts);
        self.contacts_len.push(r.gripper_contacts.len());
        self.sim_ms.push(r.sim_ms);
        self.policy_ms.push(r.policy_ms);
        self.render_ms.push(r.render_ms);
        self.timing.push(r.timing);
        self.held.push(r.held);
    }

    pub fn finish(self) -> Result<RecordBatch, ArrowError> {
        let n = self.step.len();
        let k = &self.key;
        let poses = object_poses_column(&self.object_names, n, self.object_pos, self.object_quat)?;
        let contacts: StringArray = self.contacts.iter().map(|&i| Some(self.object_names[i].as_str())).collect();
        let mut columns = k.columns(n);
        columns.extend::<[ArrayRef; 12]>([
            Arc::new(Int32Array::from(self.step)),
            Arc::new(Int32Array::from(self.policy_step.clone())),
            Arc::new(BooleanArray::from(self.policy_step.iter().map(Option::is_none).collect::<Vec<_>>())),
            fixed_f32(self.action, 7)?,
            fixed_f64(self.eef_pos, 3)?,
            fixed_f64(self.eef_quat, 4)?,
            fixed_f64(self.gripper_qpos, 2)?,
            fixed_f64(self.joint_pos, 7)?,
            poses,
            Arc::new(BooleanArray::from(self.goal)),
            list(DataType::Boolean, Arc::new(BooleanArray::from(self.goal_terms)), self.goal_terms_len)?,
            list(DataType::Utf8, Arc::new(contacts), self.contacts_len)?,
        ]);
        columns.extend(timing_columns(self.sim_ms, self.policy_ms, self.render_ms, &self.timing));
        columns.push(Arc::new(BooleanArray::from(self.held)));
        RecordBatch::try_new(tables::steps(), columns)
    }
}

/// `object_poses` of `n` steps: every object's pose per step, the objects named in `names`' order;
/// `pos` and `quat` hold 3 and 4 values per object and step.
pub(crate) fn object_poses_column(
    names: &[impl AsRef<str>],
    n: usize,
    pos: Vec<f64>,
    quat: Vec<f64>,
) -> Result<ArrayRef, ArrowError> {
    let all: StringArray = (0..n).flat_map(|_| names.iter().map(|s| Some(s.as_ref()))).collect();
    let fields = tables::object_pose_fields();
    let poses =
        StructArray::try_new(fields.clone(), vec![Arc::new(all), fixed_f64(pos, 3)?, fixed_f64(quat, 4)?], None)?;
    list(DataType::Struct(fields), Arc::new(poses), std::iter::repeat_n(names.len(), n))
}

/// The step-timing columns every benchmark's steps table ends with (`sim_ms` … `forward_batch`).
pub(crate) fn timing_columns(
    sim_ms: Vec<f32>,
    policy_ms: Vec<f32>,
    render_ms: Vec<f32>,
    timing: &[Option<libero_policies::ActTiming>],
) -> Vec<ArrayRef> {
    vec![
        Arc::new(Float32Array::from(sim_ms)),
        Arc::new(Float32Array::from(policy_ms)),
        Arc::new(Float32Array::from(render_ms)),
        Arc::new(timing.iter().map(|t| t.map(|t| t.queue_ms)).collect::<Float32Array>()),
        Arc::new(timing.iter().map(|t| t.and_then(|t| t.prepare_ms)).collect::<Float32Array>()),
        Arc::new(timing.iter().map(|t| t.map(|t| t.forward_ms)).collect::<Float32Array>()),
        Arc::new(timing.iter().map(|t| t.map(|t| t.forward_id as i64)).collect::<Int64Array>()),
        Arc::new(timing.iter().map(|t| t.map(|t| t.forward_batch as i32)).collect::<Int32Array>()),
    ]
}

fn item(t: DataType) -> Arc<Field> {
    Arc::new(Field::new("item", t, false))
}

pub(crate) fn fixed_f64(values: Vec<f64>, size: i32) -> Result<ArrayRef, ArrowError> {
    Ok(Arc::new(FixedSizeListArray::try_new(
        item(DataType::Float64),
        size,
        Arc::new(Float64Array::from(values)),
        None,
    )?))
}

pub(crate) fn fixed_f32(values: Vec<f32>, size: i32) -> Result<ArrayRef, ArrowError> {
    Ok(Arc::new(FixedSizeListArray::try_new(
        item(DataType::Float32),
        size,
        Arc::new(Float32Array::from(values)),
        None,
    )?))
}

pub(crate) fn list(
    t: DataType,
    values: ArrayRef,
    lengths: impl IntoIterator<Item = usize>,
) -> Result<ArrayRef, ArrowError> {
    Ok(Arc::new(ListArray::try_new(item(t), OffsetBuffer::from_lengths(lengths), values, None)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_batch_matches_the_steps_schema() {
        let mut b =
            StepsBatchBuilder::new(EpisodeKey::new("libero_goal", 3, 12, 7), vec!["bowl".into(), "plate".into()]);
        for t in 0..3 {
            b.push(&StepRecord {
                step: t,
                policy_step: (t > 0).then_some(t - 1),
                action: [0.0; 7],
                eef_pos: [0.1, 0.2, 0.3],
                eef_quat: [1.0, 0.0, 0.0, 0.0],
                gripper_qpos: [0.04, -0.04],
                joint_pos: [0.0; 7],
                object_poses: &[([0.0; 3], [1.0, 0.0, 0.0, 0.0]), ([1.0; 3], [1.0, 0.0, 0.0, 0.0])],
                goal: t == 2,
                goal_terms: &[t == 2],
                gripper_contacts: if t == 1 { &[1] } else { &[] },
                sim_ms: 1.0,
                policy_ms: 0.0,
                render_ms: 0.0,
                timing: None,
                held: false,
            });
        }
        let batch = b.finish().unwrap();
        assert_eq!(batch.num_rows(), 3);
        assert_eq!(batch.schema(), tables::steps());
        let key = batch.column_by_name("episode_key").unwrap();
        assert_eq!(key.as_any().downcast_ref::<StringArray>().unwrap().value(0), "libero_goal/3/12/7");
    }
}
