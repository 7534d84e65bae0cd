//! Perturbations as spec columns: the reserved columns of a spec row that change its episode,
//! parsed, validated and turned into the env's edits, the instruction and the camera transform.
//!
//! A perturbation is nothing but columns of the spec row (LIBERO-Plus variants, a user's sweep of
//! camera azimuths alike). Each column acts at one hook point (`perturbation-spec.md` §0):
//!
//! | column(s) | hook | what it does |
//! |---|---|---|
//! | `camera_azimuth_deg`, `camera_elevation_deg`, `camera_distance_pct`, `camera_pan_deg`, `camera_tilt_deg` | model edit after reset | the `agentview` pose of LIBERO-Plus's `_setup_camera` ([`libero_sim::viewpoint`]); a column left out takes its nominal value (0, 0, 100, 0, 0) |
//! | `robot_init_qpos` (7 floats) | controller | the arm's reset configuration (`init_qpos`): the controller's null-space target and first-step cache ([`libero_sim::env::EpisodeEdits`]) |
//! | `instruction_override` | policy input | the instruction the policy gets instead of the task's |
//! | `sensor_noise` (1–50), `sensor_noise_revision` (`lb2025`, `head`) | observation | LIBERO-Plus's image corruption of the agentview image the policy sees ([`libero_sim::image_noise`]), its random draws seeded from the episode key and the step |
//!
//! The columns of a row, with its `variant` name if it has one, make the episode's *variant*: a
//! hash that joins the episode key (`suite/task/init/seed/v<hash>`), so perturbed copies of one
//! base episode are distinct episodes for resume, duplicates, file names and pairing, while an
//! unperturbed row keeps the key it always had. Everything is decided by the row: no global
//! state, no draw that the next run would not repeat.

use arrow::array::{Array, AsArray, RecordBatch};
use arrow::datatypes::{DataType, Float64Type};
use libero_sim::env::EpisodeEdits;
use libero_sim::image_noise::{NoiseRevision, SensorNoise};
use libero_sim::viewpoint::{self, ViewParams};
use serde_json::json;
use sha2::{Digest, Sha256};

/// The camera view columns, in [`ViewParams`] order, with their nominal values.
pub const CAMERA_COLUMNS: [(&str, f64); 5] = [
    ("camera_azimuth_deg", 0.0),
    ("camera_elevation_deg", 0.0),
    ("camera_distance_pct", 100.0),
    ("camera_pan_deg", 0.0),
    ("camera_tilt_deg", 0.0),
];
pub const ROBOT_INIT_QPOS: &str = "robot_init_qpos";
pub const INSTRUCTION_OVERRIDE: &str = "instruction_override";
pub const SENSOR_NOISE: &str = "sensor_noise";
pub const SENSOR_NOISE_REVISION: &str = "sensor_noise_revision";
/// A descriptive variant name (e.g. the LIBERO-Plus task name); part of the variant hash.
pub const VARIANT_NAME: &str = "variant";

/// Every column this module reads; a spec column of another name is carried through untouched.
pub fn reserved_columns() -> Vec<&'static str> {
    let mut out: Vec<&str> = CAMERA_COLUMNS.iter().map(|(n, _)| *n).collect();
    out.extend([ROBOT_INIT_QPOS, INSTRUCTION_OVERRIDE, SENSOR_NOISE, SENSOR_NOISE_REVISION, VARIANT_NAME]);
    out
}

/// One episode's perturbation, as its spec row states it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EpisodePerturbation {
    pub view: Option<ViewParams>,
    pub robot_init_qpos: Option<[f64; 7]>,
    pub instruction: Option<String>,
    pub sensor_noise: Option<SensorNoise>,
    /// The row's `variant` name, when it has one.
    pub variant_name: Option<String>,
}

impl EpisodePerturbation {
    /// Read row `row` of `extras` (a spec batch's non-key columns). Errors name the column and
    /// what it must be.
    pub fn from_row(extras: &RecordBatch, row: usize) -> Result<Self, String> {
        let mut p = EpisodePerturbation::default();
        let camera: Vec<Option<f64>> =
            CAMERA_COLUMNS.iter().map(|(name, _)| number(extras, name, row)).collect::<Result<_, _>>()?;
        if camera.iter().any(Option::is_some) {
            let v = |i: usize| camera[i].unwrap_or(CAMERA_COLUMNS[i].1);
            let view = ViewParams {
                azimuth_deg: v(0),
                elevation_deg: v(1),
                distance_pct: v(2),
                pan_deg: v(3),
                tilt_deg: v(4),
            };
            view.validate()?;
            p.view = Some(view);
        }
        p.robot_init_qpos = qpos(extras, row)?;
        p.instruction = text(extras, INSTRUCTION_OVERRIDE, row)?;
        if p.instruction.as_deref().is_some_and(|t| t.trim().is_empty()) {
            return Err(format!("{INSTRUCTION_OVERRIDE} is empty; leave it null to give the task's instruction"));
        }
        let revision = text(extras, SENSOR_NOISE_REVISION, row)?;
        match number(extras, SENSOR_NOISE, row)? {
            Some(level) => {
                let revision: NoiseRevision = match &revision {
                    None => NoiseRevision::Lb2025,
                    Some(r) => r.parse().map_err(|e| format!("{SENSOR_NOISE_REVISION}: {e}"))?,
                };
                if level.fract() != 0.0 || !(1.0..=50.0).contains(&level) {
                    return Err(format!(
                        "{SENSOR_NOISE} = {level} is out of range: LIBERO-Plus levels 1-50 (1-10 motion blur, 11-20 Gaussian blur, 21-30 zoom blur, 31-40 fog, 41-50 glass blur)"
                    ));
                }
                p.sensor_noise = Some(SensorNoise::new(level as u8, revision)?);
            }
            None if revision.is_some() => {
                return Err(format!("{SENSOR_NOISE_REVISION} is set but {SENSOR_NOISE} is not"));
            }
            None => {}
        }
        p.variant_name = text(extras, VARIANT_NAME, row)?;
        Ok(p)
    }

    /// Whether the row perturbs anything (a `variant` name alone perturbs nothing, but still
    /// names a distinct episode).
    pub fn changes_the_episode(&self) -> bool {
        self.view.is_some()
            || self.robot_init_qpos.is_some()
            || self.instruction.is_some()
            || self.sensor_noise.is_some()
    }

    /// Whether the policy must see the agentview camera for this perturbation to mean anything.
    pub fn needs_camera(&self) -> Option<&'static str> {
        if self.sensor_noise.is_some() {
            Some(SENSOR_NOISE)
        } else if self.view.is_some_and(|v| v != ViewParams::NOMINAL) {
            // (the nominal view every LIBERO-Plus row carries moves the camera by its rounding only)
            Some("camera_*")
        } else {
            None
        }
    }

    /// The canonical JSON of what the row sets (keys sorted, floats in their shortest exact form):
    /// stored as `episodes.perturbation_params`; None for a row that sets nothing.
    pub fn canonical(&self) -> Option<String> {
        if !self.changes_the_episode() && self.variant_name.is_none() {
            return None;
        }
        let mut m = serde_json::Map::new();
        // -0.0 and 0.0 are one perturbation: one hash (adding 0.0 turns -0.0 into 0.0)
        if let Some(v) = &self.view.map(|v| ViewParams {
            azimuth_deg: v.azimuth_deg + 0.0,
            elevation_deg: v.elevation_deg + 0.0,
            distance_pct: v.distance_pct + 0.0,
            pan_deg: v.pan_deg + 0.0,
            tilt_deg: v.tilt_deg + 0.0,
        }) {
            m.insert(
                "camera".into(),
                json!({"azimuth_deg": v.azimuth_deg, "elevation_deg": v.elevation_deg, "distance_pct": v.distance_pct,
                       "pan_deg": v.pan_deg, "tilt_deg": v.tilt_deg}),
            );
        }
        if let Some(q) = &self.robot_init_qpos {
            m.insert(ROBOT_INIT_QPOS.into(), json!(q.map(|x| x + 0.0)));
        }
        if let Some(t) = &self.instruction {
            m.insert("instruction".into(), json!(t));
        }
        if let Some(n) = &self.sensor_noise {
            m.insert(SENSOR_NOISE.into(), json!({"level": n.level, "revision": n.revision.name()}));
        }
        if let Some(v) = &self.variant_name {
            m.insert(VARIANT_NAME.into(), json!(v));
        }
        // serde_json's Map is a BTreeMap here (no preserve_order): keys come out sorted.
        Some(serde_json::Value::Object(m).to_string())
    }

    /// The perturbation back from its canonical JSON (`episodes.perturbation_params`): what a
    /// replay (`pipeline video`) applies to re-enact a stored episode.
    pub fn from_canonical(text: &str) -> Result<Self, String> {
        let v: serde_json::Value =
            serde_json::from_str(text).map_err(|e| format!("perturbation_params is not JSON: {e}"))?;
        let num = |x: &serde_json::Value, k: &str| {
            x[k].as_f64().ok_or_else(|| format!("perturbation_params: camera.{k} is not a number"))
        };
        let mut p = EpisodePerturbation::default();
        if let Some(c) = v.get("camera") {
            p.view = Some(ViewParams {
                azimuth_deg: num(c, "azimuth_deg")?,
                elevation_deg: num(c, "elevation_deg")?,
                distance_pct: num(c, "distance_pct")?,
                pan_deg: num(c, "pan_deg")?,
                tilt_deg: num(c, "tilt_deg")?,
            });
        }
        if let Some(q) = v.get(ROBOT_INIT_QPOS) {
            let q: Vec<f64> = serde_json::from_value(q.clone()).map_err(|e| format!("{ROBOT_INIT_QPOS}: {e}"))?;
            p.robot_init_qpos = Some(q.try_into().map_err(|_| format!("{ROBOT_INIT_QPOS} needs 7 values"))?);
        }
        p.instruction = v.get("instruction").and_then(|t| t.as_str()).map(str::to_string);
        if let Some(n) = v.get(SENSOR_NOISE) {
            let level = n["level"].as_u64().ok_or("perturbation_params: sensor_noise.level")? as u8;
            let revision = n["revision"].as_str().ok_or("perturbation_params: sensor_noise.revision")?.parse()?;
            p.sensor_noise = Some(SensorNoise::new(level, revision)?);
        }
        p.variant_name = v.get(VARIANT_NAME).and_then(|t| t.as_str()).map(str::to_string);
        Ok(p)
    }

    /// The variant id joining the episode key: the first 12 hex digits of the canonical JSON's
    /// sha256; None for an unperturbed row (its key is unchanged).
    pub fn variant(&self) -> Option<String> {
        self.canonical().map(|c| format!("{:x}", Sha256::digest(c.as_bytes()))[..12].to_string())
    }

    /// The env's edits for a task of problem class `problem` (the bundle's `problem`).
    pub fn env_edits(&self, problem: &str) -> Result<EpisodeEdits, libero_sim::SimError> {
        let agentview = match &self.view {
            Some(view) => Some(viewpoint::plus_agentview(viewpoint::nominal_agentview(problem)?, view)),
            None => None,
        };
        Ok(EpisodeEdits { agentview, robot_init_qpos: self.robot_init_qpos })
    }
}

/// A numeric column's value (any integer or float type), None when absent or null.
fn number(batch: &RecordBatch, name: &str, row: usize) -> Result<Option<f64>, String> {
    let Some(col) = batch.column_by_name(name) else { return Ok(None) };
    if col.is_null(row) {
        return Ok(None);
    }
    if !col.data_type().is_numeric() {
        return Err(format!("column {name} has type {}, expected a number", col.data_type()));
    }
    let cast = arrow::compute::cast(&col.slice(row, 1), &DataType::Float64).map_err(|e| format!("{name}: {e}"))?;
    Ok(Some(cast.as_primitive::<Float64Type>().value(0)))
}

/// A text column's value (Utf8, LargeUtf8 or Utf8View), None when absent or null.
fn text(batch: &RecordBatch, name: &str, row: usize) -> Result<Option<String>, String> {
    let Some(col) = batch.column_by_name(name) else { return Ok(None) };
    if col.is_null(row) {
        return Ok(None);
    }
    if !matches!(col.data_type(), DataType::Utf8 | DataType::LargeUtf8 | DataType::Utf8View) {
        return Err(format!("column {name} has type {}, expected text", col.data_type()));
    }
    let cast = arrow::compute::cast(&col.slice(row, 1), &DataType::Utf8).map_err(|e| format!("{name}: {e}"))?;
    Ok(Some(cast.as_string::<i32>().value(0).to_string()))
}

/// `robot_init_qpos`: a list (or fixed-size list) of 7 finite numbers.
fn qpos(batch: &RecordBatch, row: usize) -> Result<Option<[f64; 7]>, String> {
    let Some(col) = batch.column_by_name(ROBOT_INIT_QPOS) else { return Ok(None) };
    if col.is_null(row) {
        return Ok(None);
    }
    let values = match col.data_type() {
        DataType::List(_) => col.as_list::<i32>().value(row),
        DataType::LargeList(_) => col.as_list::<i64>().value(row),
        DataType::FixedSizeList(_, _) => col.as_fixed_size_list().value(row),
        other => return Err(format!("column {ROBOT_INIT_QPOS} has type {other}, expected a list of 7 numbers")),
    };
    let values = arrow::compute::cast(&values, &DataType::Float64)
        .map_err(|_| format!("column {ROBOT_INIT_QPOS} holds {}, expected numbers", values.data_type()))?;
    let values = values.as_primitive::<Float64Type>();
    if values.len() != 7 || values.null_count() > 0 {
        return Err(format!(
            "{ROBOT_INIT_QPOS} has {} values ({} null), expected the 7 arm joint positions (rad)",
            values.len(),
            values.null_count()
        ));
    }
    let q: [f64; 7] = std::array::from_fn(|i| values.value(i));
    for (i, (&x, [lo, hi])) in q.iter().zip(PANDA_JOINT_RANGES).enumerate() {
        if !(lo..=hi).contains(&x) {
            return Err(format!("{ROBOT_INIT_QPOS}[{i}] = {x} is outside the Panda joint's range [{lo}, {hi}] rad"));
        }
    }
    Ok(Some(q))
}

/// The Panda arm's joint ranges (robosuite 1.4 `robots/panda/robot.xml`, as every LIBERO scene
/// compiles them): a reset configuration outside them is no configuration the robot can have.
const PANDA_JOINT_RANGES: [[f64; 2]; 7] = [
    [-2.8973, 2.8973],
    [-1.7628, 1.7628],
    [-2.8973, 2.8973],
    [-3.0718, -0.0698],
    [-2.8973, 2.8973],
    [-0.0175, 3.7525],
    [-2.8973, 2.8973],
];

#[cfg(test)]
mod tests {
    use super::*;
    use arrow::array::{ArrayRef, Float64Array, Int32Array, StringArray};
    use std::sync::Arc;

    fn batch(cols: Vec<(&str, ArrayRef)>) -> RecordBatch {
        RecordBatch::try_from_iter(cols).unwrap()
    }

    #[test]
    fn a_row_without_perturbation_columns_keeps_its_key() {
        let b = batch(vec![("note", Arc::new(StringArray::from(vec!["x"])) as ArrayRef)]);
        let p = EpisodePerturbation::from_row(&b, 0).unwrap();
        assert_eq!(p, EpisodePerturbation::default());
        assert_eq!(p.variant(), None);
    }

    #[test]
    fn missing_camera_columns_take_their_nominal_values() {
        let b = batch(vec![("camera_azimuth_deg", Arc::new(Int32Array::from(vec![30])) as ArrayRef)]);
        let p = EpisodePerturbation::from_row(&b, 0).unwrap();
        assert_eq!(p.view, Some(ViewParams { azimuth_deg: 30.0, ..ViewParams::NOMINAL }));
        assert_eq!(p.needs_camera(), Some("camera_*"));
        // the same view from a float column is the same variant
        let b2 = batch(vec![("camera_azimuth_deg", Arc::new(Float64Array::from(vec![30.0])) as ArrayRef)]);
        assert_eq!(EpisodePerturbation::from_row(&b2, 0).unwrap().variant(), p.variant());
    }

    #[test]
    fn distinct_parameters_make_distinct_variants_and_the_name_counts() {
        let v = |az: f64, name: Option<&str>| {
            let b = batch(vec![
                ("camera_azimuth_deg", Arc::new(Float64Array::from(vec![az])) as ArrayRef),
                ("variant", Arc::new(StringArray::from(vec![name])) as ArrayRef),
            ]);
            EpisodePerturbation::from_row(&b, 0).unwrap().variant().unwrap()
        };
        assert_ne!(v(30.0, None), v(31.0, None));
        assert_ne!(v(30.0, None), v(30.0, Some("a")));
        assert_eq!(v(30.0, Some("a")), v(30.0, Some("a")));
        assert_eq!(v(30.0, None).len(), 12);
    }

    #[test]
    fn the_canonical_json_reads_back_to_the_same_perturbation() {
        let b = batch(vec![
            ("camera_azimuth_deg", Arc::new(Float64Array::from(vec![30.5])) as ArrayRef),
            ("camera_tilt_deg", Arc::new(Int32Array::from(vec![356])) as ArrayRef),
            ("instruction_override", Arc::new(StringArray::from(vec!["put it there"])) as ArrayRef),
            ("sensor_noise", Arc::new(Int32Array::from(vec![33])) as ArrayRef),
            ("variant", Arc::new(StringArray::from(vec!["v1"])) as ArrayRef),
        ]);
        let p = EpisodePerturbation::from_row(&b, 0).unwrap();
        let back = EpisodePerturbation::from_canonical(&p.canonical().unwrap()).unwrap();
        assert_eq!(back, p);
        assert_eq!(back.variant(), p.variant());
    }

    #[test]
    fn bad_values_are_refused_with_the_column_named() {
        let err = |cols: Vec<(&str, ArrayRef)>| EpisodePerturbation::from_row(&batch(cols), 0).unwrap_err();
        assert!(
            err(vec![("camera_distance_pct", Arc::new(Float64Array::from(vec![0.0])) as ArrayRef)])
                .contains("camera_distance_pct")
        );
        assert!(err(vec![("sensor_noise", Arc::new(Int32Array::from(vec![51])) as ArrayRef)]).contains("1-50"));
        assert!(
            err(vec![("sensor_noise_revision", Arc::new(StringArray::from(vec!["head"])) as ArrayRef)])
                .contains("sensor_noise is not")
        );
        assert!(
            err(vec![("camera_pan_deg", Arc::new(StringArray::from(vec!["ten"])) as ArrayRef)])
                .contains("expected a number")
        );
        assert!(
            err(vec![("instruction_override", Arc::new(StringArray::from(vec![" "])) as ArrayRef)]).contains("empty")
        );
    }
}
