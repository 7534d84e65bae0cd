//! The compact evidence of an episode's goal: the policy steps at which it changed.
//!
//! Every success definition and cap is a function of the goal's value at each policy step. The
//! steps table holds it row by row (the ground truth); the episode row holds it compactly as
//! `goal_changes`: the policy steps at which the goal's value differs from the step before, the
//! value before policy step 0 taken as false. The goal held at step p iff an odd number of entries
//! are ≤ p. So `queries/score.sql` re-scores a run from its episode rows alone (one row per episode
//! instead of ~300 step rows), and `queries/score_from_steps.sql` derives the same from the steps;
//! the tests hold the two equal on real runs.
//!
//! - [`GoalChanges`] builds the list while an episode runs;
//! - `goal_held_at(goal_changes, step)`: the SQL function reading it (NULL list or step → NULL,
//!   a negative step → false: before the first policy step nothing held).

use arrow::array::{Array, AsArray, BooleanArray};
use arrow::datatypes::{DataType, Int32Type, Int64Type};
use datafusion::common::{Result, plan_err};
use datafusion::logical_expr::{ColumnarValue, ScalarFunctionArgs, ScalarUDF, ScalarUDFImpl, Signature, Volatility};
use std::sync::Arc;

/// The goal changes of one episode, fed one policy step at a time.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GoalChanges {
    steps: Vec<u32>,
    held: bool,
}

impl GoalChanges {
    /// Record the goal's value after policy step `policy_step` (steps must come in order).
    pub fn record(&mut self, policy_step: u32, goal: bool) {
        if goal != self.held {
            self.steps.push(policy_step);
            self.held = goal;
        }
    }

    /// The changes of a goal given at policy steps 0, 1, 2, ... in order.
    pub fn from_goals(goals: impl IntoIterator<Item = bool>) -> Self {
        let mut changes = GoalChanges::default();
        for (p, g) in goals.into_iter().enumerate() {
            changes.record(p as u32, g);
        }
        changes
    }

    pub fn steps(&self) -> &[u32] {
        &self.steps
    }
}

/// Whether the goal held at `step`, from an episode's goal changes (sorted ascending).
pub fn goal_held_at(changes: &[i32], step: i64) -> bool {
    step >= 0 && changes.iter().take_while(|&&c| c as i64 <= step).count() % 2 == 1
}

/// `goal_held_at(goal_changes LIST<INT>, step BIGINT) -> BOOLEAN`.
#[derive(Debug, PartialEq, Eq, Hash)]
pub struct GoalHeldAt {
    signature: Signature,
}

impl Default for GoalHeldAt {
    fn default() -> Self {
        GoalHeldAt { signature: Signature::user_defined(Volatility::Immutable) }
    }
}

impl ScalarUDFImpl for GoalHeldAt {
    fn name(&self) -> &str {
        "goal_held_at"
    }
    fn signature(&self) -> &Signature {
        &self.signature
    }
    fn return_type(&self, _arg_types: &[DataType]) -> Result<DataType> {
        Ok(DataType::Boolean)
    }
    fn coerce_types(&self, arg_types: &[DataType]) -> Result<Vec<DataType>> {
        let step = |s: &DataType| s.is_integer() || s.is_null();
        match arg_types {
            [DataType::List(item), s] if item.data_type() == &DataType::Int32 && step(s) => {
                Ok(vec![arg_types[0].clone(), DataType::Int64])
            }
            [DataType::Null, s] if step(s) => Ok(vec![
                DataType::List(Arc::new(arrow::datatypes::Field::new("item", DataType::Int32, true))),
                DataType::Int64,
            ]),
            _ => plan_err!("goal_held_at(goal_changes LIST<INT>, step INTEGER) got {arg_types:?}"),
        }
    }
    fn invoke_with_args(&self, args: ScalarFunctionArgs) -> Result<ColumnarValue> {
        let arrays = ColumnarValue::values_to_arrays(&args.args)?;
        let lists = arrays[0].as_list::<i32>();
        let steps = arrays[1].as_primitive::<Int64Type>();
        let out: BooleanArray = (0..lists.len())
            .map(|i| {
                if lists.is_null(i) || steps.is_null(i) {
                    return None;
                }
                let changes = lists.value(i);
                let changes = changes.as_primitive::<Int32Type>();
                Some(goal_held_at(changes.values(), steps.value(i)))
            })
            .collect();
        Ok(ColumnarValue::Array(Arc::new(out)))
    }
}

pub fn goal_held_at_udf() -> ScalarUDF {
    ScalarUDF::from(GoalHeldAt::default())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The goal per step from the changes equals the goal it was built from, for every step.
    #[test]
    fn changes_give_back_the_goal_at_every_step() {
        let goal = [false, false, true, true, false, true, true, true, false];
        let mut changes = GoalChanges::default();
        for (p, &g) in goal.iter().enumerate() {
            changes.record(p as u32, g);
        }
        assert_eq!(changes.steps(), [2, 4, 5, 8]);
        let as_i32: Vec<i32> = changes.steps().iter().map(|&s| s as i32).collect();
        for (p, &g) in goal.iter().enumerate() {
            assert_eq!(goal_held_at(&as_i32, p as i64), g, "step {p}");
        }
        assert!(!goal_held_at(&as_i32, -1));
        assert!(!goal_held_at(&[], 3));
        assert!(goal_held_at(&[0], 0), "true from the first policy step");
    }
}
