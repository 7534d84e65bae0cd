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
//! | `camera_pos` (3), `camera_quat_wxyz` (4) | model edit after reset | LIBERO-PRO's raw `agentview` pose, written as given (not normalised) |
//! | `light_ambient`, `light_diffuse`, `light_specular` | model edit after reset | LIBERO-PRO's lighting: every light on, each colour set broadcast to all lights ([`libero_sim::env::Lighting`]) |
//! | `appearance_objects` (comma-separated names), `appearance_rgba` (4) | model edit after reset | LIBERO-PRO's object appearance: the objects' visual geoms and materials recoloured, textures dropped |
//! | `image_brightness`, `image_noise_std` | observation | LIBERO-PRO's `dark_noise` on every camera image the policy sees ([`libero_sim::dark_noise`]), one frozen noise field per episode and camera |
//! | `initial_pose_object`, `initial_pose_delta_xy` (2), `initial_pose_yaw_rad`, `initial_pose_min_delta` | state edit after `set_init_state` | LIBERO-PRO's initial pose: the object yawed (absolute) and shifted by a safe delta |
//! | `runtime_move_object`, `runtime_move_delta_xy` (2), `runtime_move_min_delta`, `runtime_move_trigger_m` (0.09), `runtime_move_fallback_step` (160) | state edit before a step | LIBERO-PRO's runtime move: the object shifted once, when the gripper nears it or at the fallback step |
//! | `occluder_object`, `occlusion_reference`, `occlusion_offset_xy` (2), `occlusion_partner`, `occlusion_partner_threshold_m` (0.24), `occlusion_partner_delta_xy` (2), `occlusion_partner_clearance_m` (0.08) | state edit after `set_init_state`, and after every step | LIBERO-PRO's `view_occlusion`: the goal partner moved away when too close, the occluder (in the `<suite>_view_occlusion` scenes only) placed in front of the reference by a safe offset and pinned there ([`libero_sim::env::Occlusion`]) |
//!
//! The columns of a row, with its `variant` name if it has one, make the episode's *variant*: a
//! hash that joins the episode key (`suite/task/init/seed/v<hash>`), so perturbed copies of one
//! base episode are distinct episodes for resume, duplicates, file names and pairing, while an
//! unperturbed row keeps the key it always had. Everything is decided by the row: no global
//! state, no draw that the next run would not repeat.

use arrow::array::{Array, AsArray, RecordBatch};
use arrow::datatypes::{DataType, Float64Type};
use libero_sim::dark_noise::DarkNoise;
use libero_sim::env::{
    Appearance, EpisodeEdits, InitialPose, Lighting, ObjectShift, Occlusion, OcclusionPartner, RuntimeMove,
};
use libero_sim::image_noise::{NoiseRevision, SensorNoise};
use libero_sim::viewpoint::{self, CameraPose, ViewParams};
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
pub const CAMERA_POS: &str = "camera_pos";
pub const CAMERA_QUAT: &str = "camera_quat_wxyz";
pub const LIGHT_COLUMNS: [&str; 3] = ["light_ambient", "light_diffuse", "light_specular"];
pub const APPEARANCE_OBJECTS: &str = "appearance_objects";
pub const APPEARANCE_RGBA: &str = "appearance_rgba";
pub const IMAGE_BRIGHTNESS: &str = "image_brightness";
pub const IMAGE_NOISE_STD: &str = "image_noise_std";
/// The columns of one object shift, by prefix (`initial_pose_*`, `runtime_move_*`).
const SHIFT_SUFFIXES: [&str; 3] = ["object", "delta_xy", "min_delta"];
pub const INITIAL_POSE_YAW: &str = "initial_pose_yaw_rad";
pub const RUNTIME_MOVE_TRIGGER: &str = "runtime_move_trigger_m";
pub const RUNTIME_MOVE_FALLBACK: &str = "runtime_move_fallback_step";
/// LIBERO-PRO's defaults for a runtime move (`PerturbationRuntimeOptions`, as shipped).
pub const DEFAULT_TRIGGER_M: f64 = 0.09;
pub const DEFAULT_FALLBACK_STEP: u32 = 160;
pub const OCCLUDER_OBJECT: &str = "occluder_object";
pub const OCCLUSION_REFERENCE: &str = "occlusion_reference";
pub const OCCLUSION_OFFSET: &str = "occlusion_offset_xy";
pub const OCCLUSION_PARTNER: &str = "occlusion_partner";
pub const OCCLUSION_PARTNER_THRESHOLD: &str = "occlusion_partner_threshold_m";
pub const OCCLUSION_PARTNER_DELTA: &str = "occlusion_partner_delta_xy";
pub const OCCLUSION_PARTNER_CLEARANCE: &str = "occlusion_partner_clearance_m";
/// LIBERO-PRO's shipped `object_placement` values for the goal partner (§C2): moved when closer
/// than 0.24 m, by (0.16, 0), the occluder kept 0.08 m from it.
pub const DEFAULT_PARTNER_THRESHOLD_M: f64 = 0.24;
pub const DEFAULT_PARTNER_DELTA: [f64; 2] = [0.16, 0.0];
pub const DEFAULT_PARTNER_CLEARANCE_M: f64 = 0.08;

/// Every column this module reads; a spec column of another name is carried through untouched.
pub fn reserved_columns() -> Vec<&'static str> {
    let mut out: Vec<&str> = CAMERA_COLUMNS.iter().map(|(n, _)| *n).collect();
    out.extend([ROBOT_INIT_QPOS, INSTRUCTION_OVERRIDE, SENSOR_NOISE, SENSOR_NOISE_REVISION, VARIANT_NAME]);
    out.extend([CAMERA_POS, CAMERA_QUAT, APPEARANCE_OBJECTS, APPEARANCE_RGBA, IMAGE_BRIGHTNESS, IMAGE_NOISE_STD]);
    out.extend(LIGHT_COLUMNS);
    out.extend([
        "initial_pose_object",
        "initial_pose_delta_xy",
        "initial_pose_min_delta",
        INITIAL_POSE_YAW,
        "runtime_move_object",
        "runtime_move_delta_xy",
        "runtime_move_min_delta",
        RUNTIME_MOVE_TRIGGER,
        RUNTIME_MOVE_FALLBACK,
    ]);
    out.extend([
        OCCLUDER_OBJECT,
        OCCLUSION_REFERENCE,
        OCCLUSION_OFFSET,
        OCCLUSION_PARTNER,
        OCCLUSION_PARTNER_THRESHOLD,
        OCCLUSION_PARTNER_DELTA,
        OCCLUSION_PARTNER_CLEARANCE,
    ]);
    out
}

/// One episode's perturbation, as its spec row states it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EpisodePerturbation {
    pub view: Option<ViewParams>,
    pub robot_init_qpos: Option<[f64; 7]>,
    pub instruction: Option<String>,
    pub sensor_noise: Option<SensorNoise>,
    /// LIBERO-PRO's raw agentview pose (not normalised).
    pub camera_raw: Option<CameraPose>,
    pub lighting: Option<Lighting>,
    pub appearance: Option<Appearance>,
    pub dark_noise: Option<DarkNoise>,
    pub initial_pose: Option<InitialPose>,
    pub runtime_move: Option<RuntimeMove>,
    pub occlusion: Option<Occlusion>,
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
        p.read_pro_columns(extras, row)?;
        p.variant_name = text(extras, VARIANT_NAME, row)?;
        Ok(p)
    }

    /// The LIBERO-PRO robustness columns (`perturbation-spec.md` §C2).
    fn read_pro_columns(&mut self, extras: &RecordBatch, row: usize) -> Result<(), String> {
        match (floats::<3>(extras, CAMERA_POS, row)?, floats::<4>(extras, CAMERA_QUAT, row)?) {
            (None, None) => {}
            (Some(pos), Some(quat)) => {
                if quat.iter().map(|x| x * x).sum::<f64>() < 1e-6 {
                    return Err(format!("{CAMERA_QUAT} is zero: give a rotation quaternion (w, x, y, z)"));
                }
                if self.view.is_some() {
                    return Err(format!(
                        "{CAMERA_POS} with camera_* columns: a row sets the agentview either as a LIBERO-Plus view or as a raw pose, not both"
                    ));
                }
                self.camera_raw = Some(CameraPose { pos, quat });
            }
            _ => return Err(format!("{CAMERA_POS} and {CAMERA_QUAT} go together: set both or neither")),
        }
        let light: Vec<Option<f64>> = LIGHT_COLUMNS.iter().map(|c| number(extras, c, row)).collect::<Result<_, _>>()?;
        for (c, v) in LIGHT_COLUMNS.iter().zip(&light) {
            if v.is_some_and(|v| !(0.0..=10.0).contains(&v)) {
                return Err(format!("{c} = {} is out of range [0, 10]", v.unwrap()));
            }
        }
        if light.iter().any(Option::is_some) {
            let f = |i: usize| light[i].map(|v| v as f32);
            self.lighting = Some(Lighting { ambient: f(0), diffuse: f(1), specular: f(2) });
        }
        match (text(extras, APPEARANCE_OBJECTS, row)?, floats::<4>(extras, APPEARANCE_RGBA, row)?) {
            (None, None) => {}
            (Some(objects), Some(rgba)) => {
                let objects: Vec<String> =
                    objects.split(',').map(|o| o.trim().to_string()).filter(|o| !o.is_empty()).collect();
                if objects.is_empty() {
                    return Err(format!("{APPEARANCE_OBJECTS} names no object"));
                }
                if rgba.iter().any(|c| !(0.0..=1.0).contains(c)) {
                    return Err(format!("{APPEARANCE_RGBA} = {rgba:?}: each channel is in [0, 1]"));
                }
                self.appearance = Some(Appearance { objects, rgba: rgba.map(|c| c as f32) });
            }
            _ => return Err(format!("{APPEARANCE_OBJECTS} and {APPEARANCE_RGBA} go together: set both or neither")),
        }
        match (number(extras, IMAGE_BRIGHTNESS, row)?, number(extras, IMAGE_NOISE_STD, row)?) {
            (None, None) => {}
            (b, s) => {
                let d = DarkNoise { brightness: b.unwrap_or(1.0) as f32, std: s.unwrap_or(0.0) };
                d.validate()?;
                self.dark_noise = Some(d);
            }
        }
        if let Some(shift) = shift(extras, "initial_pose", row)? {
            let yaw = number(extras, INITIAL_POSE_YAW, row)?;
            if yaw.is_some_and(|y| y.abs() > 2.0 * std::f64::consts::PI) {
                return Err(format!("{INITIAL_POSE_YAW} = {} is outside [-2π, 2π] rad", yaw.unwrap()));
            }
            self.initial_pose = Some(InitialPose { shift, yaw });
        } else if number(extras, INITIAL_POSE_YAW, row)?.is_some() {
            return Err(format!("{INITIAL_POSE_YAW} is set but initial_pose_object is not"));
        }
        if let Some(shift) = shift(extras, "runtime_move", row)? {
            let trigger = number(extras, RUNTIME_MOVE_TRIGGER, row)?.unwrap_or(DEFAULT_TRIGGER_M);
            let fallback = number(extras, RUNTIME_MOVE_FALLBACK, row)?.unwrap_or(DEFAULT_FALLBACK_STEP as f64);
            if !(0.0..=2.0).contains(&trigger) {
                return Err(format!("{RUNTIME_MOVE_TRIGGER} = {trigger} is out of range [0, 2] m"));
            }
            if fallback.fract() != 0.0 || !(0.0..=100_000.0).contains(&fallback) {
                return Err(format!("{RUNTIME_MOVE_FALLBACK} = {fallback} is not a step number"));
            }
            self.runtime_move = Some(RuntimeMove { shift, trigger_distance: trigger, fallback_step: fallback as u32 });
        } else if [RUNTIME_MOVE_TRIGGER, RUNTIME_MOVE_FALLBACK]
            .iter()
            .any(|c| extras.column_by_name(c).is_some_and(|col| !col.is_null(row)))
        {
            return Err(
                "runtime_move_trigger_m / runtime_move_fallback_step are set but runtime_move_object is not".into()
            );
        }
        self.occlusion = occlusion(extras, row)?;
        Ok(())
    }

    /// Whether the row perturbs anything (a `variant` name alone perturbs nothing, but still
    /// names a distinct episode).
    pub fn changes_the_episode(&self) -> bool {
        self.view.is_some()
            || self.robot_init_qpos.is_some()
            || self.instruction.is_some()
            || self.sensor_noise.is_some()
            || self.camera_raw.is_some()
            || self.lighting.is_some()
            || self.appearance.is_some()
            || self.dark_noise.is_some()
            || self.initial_pose.is_some()
            || self.runtime_move.is_some()
            || self.occlusion.is_some()
    }

    /// Whether the policy must see the agentview camera for this perturbation to mean anything.
    pub fn needs_camera(&self) -> Option<&'static str> {
        if self.sensor_noise.is_some() {
            Some(SENSOR_NOISE)
        } else if self.dark_noise.is_some() {
            Some("image_brightness/image_noise_std")
        } else if self.camera_raw.is_some() {
            Some(CAMERA_POS)
        } else if self.lighting.is_some() {
            Some("light_*")
        } else if self.appearance.is_some() {
            Some(APPEARANCE_OBJECTS)
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
        if let Some(c) = &self.camera_raw {
            m.insert("camera_raw".into(), json!({"pos": c.pos.map(|x| x + 0.0), "quat_wxyz": c.quat.map(|x| x + 0.0)}));
        }
        if let Some(l) = &self.lighting {
            m.insert("lighting".into(), json!({"ambient": l.ambient, "diffuse": l.diffuse, "specular": l.specular}));
        }
        if let Some(a) = &self.appearance {
            m.insert("appearance".into(), json!({"objects": a.objects, "rgba": a.rgba}));
        }
        if let Some(d) = &self.dark_noise {
            m.insert("dark_noise".into(), json!({"brightness": d.brightness, "std": d.std}));
        }
        let shift = |s: &ObjectShift| json!({"object": s.object, "delta_xy": s.delta_xy.map(|x| x + 0.0), "min_delta": s.min_delta_norm + 0.0});
        if let Some(p) = &self.initial_pose {
            let mut v = shift(&p.shift);
            v["yaw_rad"] = json!(p.yaw.map(|y| y + 0.0));
            m.insert("initial_pose".into(), v);
        }
        if let Some(r) = &self.runtime_move {
            let mut v = shift(&r.shift);
            v["trigger_m"] = json!(r.trigger_distance + 0.0);
            v["fallback_step"] = json!(r.fallback_step);
            m.insert("runtime_move".into(), v);
        }
        if let Some(o) = &self.occlusion {
            let partner = o.partner.as_ref().map(|p| {
                json!({"object": p.object, "threshold_m": p.threshold + 0.0, "delta_xy": p.delta_xy.map(|x| x + 0.0),
                       "clearance_m": p.clearance + 0.0})
            });
            m.insert(
                "occlusion".into(),
                json!({"occluder": o.occluder, "reference": o.reference, "offset_xy": o.offset_xy.map(|x| x + 0.0),
                       "partner": partner}),
            );
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
        let field = |k: &str| -> Result<Option<serde_json::Value>, String> { Ok(v.get(k).cloned()) };
        let parse = |x: serde_json::Value, what: &str| -> Result<serde_json::Value, String> {
            if x.is_object() { Ok(x) } else { Err(format!("perturbation_params: {what} is not an object")) }
        };
        let de = |x: &serde_json::Value, k: &str| -> Result<serde_json::Value, String> {
            x.get(k).cloned().ok_or_else(|| format!("perturbation_params: {k} missing"))
        };
        fn from<T: serde::de::DeserializeOwned>(x: serde_json::Value, what: &str) -> Result<T, String> {
            serde_json::from_value(x).map_err(|e| format!("perturbation_params: {what}: {e}"))
        }
        if let Some(c) = field("camera_raw")? {
            let c = parse(c, "camera_raw")?;
            p.camera_raw =
                Some(CameraPose { pos: from(de(&c, "pos")?, "pos")?, quat: from(de(&c, "quat_wxyz")?, "quat")? });
        }
        if let Some(l) = field("lighting")? {
            let l = parse(l, "lighting")?;
            p.lighting = Some(Lighting {
                ambient: from(de(&l, "ambient")?, "ambient")?,
                diffuse: from(de(&l, "diffuse")?, "diffuse")?,
                specular: from(de(&l, "specular")?, "specular")?,
            });
        }
        if let Some(a) = field("appearance")? {
            let a = parse(a, "appearance")?;
            p.appearance = Some(Appearance {
                objects: from(de(&a, "objects")?, "objects")?,
                rgba: from(de(&a, "rgba")?, "rgba")?,
            });
        }
        if let Some(d) = field("dark_noise")? {
            let d = parse(d, "dark_noise")?;
            p.dark_noise = Some(DarkNoise {
                brightness: from(de(&d, "brightness")?, "brightness")?,
                std: from(de(&d, "std")?, "std")?,
            });
        }
        let shift = |s: &serde_json::Value| -> Result<ObjectShift, String> {
            Ok(ObjectShift {
                object: from(de(s, "object")?, "object")?,
                delta_xy: from(de(s, "delta_xy")?, "delta_xy")?,
                min_delta_norm: from(de(s, "min_delta")?, "min_delta")?,
            })
        };
        if let Some(i) = field("initial_pose")? {
            let i = parse(i, "initial_pose")?;
            p.initial_pose = Some(InitialPose { shift: shift(&i)?, yaw: from(de(&i, "yaw_rad")?, "yaw_rad")? });
        }
        if let Some(r) = field("runtime_move")? {
            let r = parse(r, "runtime_move")?;
            p.runtime_move = Some(RuntimeMove {
                shift: shift(&r)?,
                trigger_distance: from(de(&r, "trigger_m")?, "trigger_m")?,
                fallback_step: from(de(&r, "fallback_step")?, "fallback_step")?,
            });
        }
        if let Some(o) = field("occlusion")? {
            let o = parse(o, "occlusion")?;
            let partner = match o.get("partner").filter(|x| !x.is_null()) {
                None => None,
                Some(x) => Some(OcclusionPartner {
                    object: from(de(x, "object")?, "partner.object")?,
                    threshold: from(de(x, "threshold_m")?, "partner.threshold_m")?,
                    delta_xy: from(de(x, "delta_xy")?, "partner.delta_xy")?,
                    clearance: from(de(x, "clearance_m")?, "partner.clearance_m")?,
                }),
            };
            p.occlusion = Some(Occlusion {
                occluder: from(de(&o, "occluder")?, "occluder")?,
                reference: from(de(&o, "reference")?, "reference")?,
                offset_xy: from(de(&o, "offset_xy")?, "offset_xy")?,
                partner,
            });
        }
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
        Ok(EpisodeEdits {
            agentview,
            robot_init_qpos: self.robot_init_qpos,
            agentview_raw: self.camera_raw,
            lighting: self.lighting,
            appearance: self.appearance.clone(),
            initial_pose: self.initial_pose.clone(),
            runtime_move: self.runtime_move.clone(),
            occlusion: self.occlusion.clone(),
        })
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

/// A list column of exactly `N` finite numbers (list, large list or fixed-size list).
fn floats<const N: usize>(batch: &RecordBatch, name: &str, row: usize) -> Result<Option<[f64; N]>, String> {
    let Some(col) = batch.column_by_name(name) else { return Ok(None) };
    if col.is_null(row) {
        return Ok(None);
    }
    let values = match col.data_type() {
        DataType::List(_) => col.as_list::<i32>().value(row),
        DataType::LargeList(_) => col.as_list::<i64>().value(row),
        DataType::FixedSizeList(_, _) => col.as_fixed_size_list().value(row),
        other => return Err(format!("column {name} has type {other}, expected a list of {N} numbers")),
    };
    let values = arrow::compute::cast(&values, &DataType::Float64)
        .map_err(|_| format!("column {name} holds {}, expected numbers", values.data_type()))?;
    let values = values.as_primitive::<Float64Type>();
    if values.len() != N || values.null_count() > 0 {
        return Err(format!("{name} has {} values ({} null), expected {N} numbers", values.len(), values.null_count()));
    }
    let out: [f64; N] = std::array::from_fn(|i| values.value(i));
    if out.iter().any(|x| !x.is_finite()) {
        return Err(format!("{name} = {out:?} is not finite"));
    }
    Ok(Some(out))
}

/// The `<prefix>_object`, `<prefix>_delta_xy` and `<prefix>_min_delta` columns of one object shift.
fn shift(batch: &RecordBatch, prefix: &str, row: usize) -> Result<Option<ObjectShift>, String> {
    let [object, delta, min] = SHIFT_SUFFIXES.map(|s| format!("{prefix}_{s}"));
    let Some(name) = text(batch, &object, row)? else {
        if floats::<2>(batch, &delta, row)?.is_some() || number(batch, &min, row)?.is_some() {
            return Err(format!("{delta} / {min} are set but {object} is not"));
        }
        return Ok(None);
    };
    let delta_xy = floats::<2>(batch, &delta, row)?.ok_or_else(|| format!("{object} is set but {delta} is not"))?;
    let min_delta_norm = number(batch, &min, row)?.unwrap_or(0.0);
    if delta_xy.iter().any(|d| d.abs() > 1.0) || !(0.0..=1.0).contains(&min_delta_norm) {
        return Err(format!("{delta} = {delta_xy:?} / {min} = {min_delta_norm}: shifts are at most 1 m"));
    }
    Ok(Some(ObjectShift { object: name.trim().to_string(), delta_xy, min_delta_norm }))
}

/// The `occluder_object` / `occlusion_*` columns (LIBERO-PRO's `view_occlusion`). The partner's
/// threshold, move and clearance default to the shipped values when `occlusion_partner` is set.
fn occlusion(batch: &RecordBatch, row: usize) -> Result<Option<Occlusion>, String> {
    let occluder = text(batch, OCCLUDER_OBJECT, row)?;
    let reference = text(batch, OCCLUSION_REFERENCE, row)?;
    let offset = floats::<2>(batch, OCCLUSION_OFFSET, row)?;
    let partner = text(batch, OCCLUSION_PARTNER, row)?;
    let threshold = number(batch, OCCLUSION_PARTNER_THRESHOLD, row)?;
    let delta = floats::<2>(batch, OCCLUSION_PARTNER_DELTA, row)?;
    let clearance = number(batch, OCCLUSION_PARTNER_CLEARANCE, row)?;
    let Some(occluder) = occluder else {
        if reference.is_some()
            || offset.is_some()
            || partner.is_some()
            || threshold.is_some()
            || delta.is_some()
            || clearance.is_some()
        {
            return Err(format!(
                "occlusion_* columns are set but {OCCLUDER_OBJECT} is not: name the occluder (black_book_occluder_1 in the <suite>_view_occlusion scenes)"
            ));
        }
        return Ok(None);
    };
    let occluder = occluder.trim().to_string();
    let reference = reference.map(|r| r.trim().to_string()).filter(|r| !r.is_empty()).ok_or_else(|| {
        format!("{OCCLUDER_OBJECT} is set but {OCCLUSION_REFERENCE} is not: name the object it stands in front of")
    })?;
    let offset_xy = offset
        .ok_or_else(|| format!("{OCCLUDER_OBJECT} is set but {OCCLUSION_OFFSET} is not (LIBERO-PRO: [0.08, 0])"))?;
    if occluder.is_empty() {
        return Err(format!("{OCCLUDER_OBJECT} is empty"));
    }
    if offset_xy.iter().any(|d| d.abs() > 1.0) {
        return Err(format!("{OCCLUSION_OFFSET} = {offset_xy:?}: offsets are at most 1 m"));
    }
    let partner = match partner.map(|p| p.trim().to_string()).filter(|p| !p.is_empty()) {
        None => {
            if threshold.is_some() || delta.is_some() || clearance.is_some() {
                return Err(format!("{OCCLUSION_PARTNER}_* columns are set but {OCCLUSION_PARTNER} is not"));
            }
            None
        }
        Some(object) => {
            let threshold = threshold.unwrap_or(DEFAULT_PARTNER_THRESHOLD_M);
            let clearance = clearance.unwrap_or(DEFAULT_PARTNER_CLEARANCE_M);
            let delta_xy = delta.unwrap_or(DEFAULT_PARTNER_DELTA);
            if !(0.0..=2.0).contains(&threshold) {
                return Err(format!("{OCCLUSION_PARTNER_THRESHOLD} = {threshold} is out of range [0, 2] m"));
            }
            if !(0.0..=1.0).contains(&clearance) {
                return Err(format!("{OCCLUSION_PARTNER_CLEARANCE} = {clearance} is out of range [0, 1] m"));
            }
            if delta_xy.iter().any(|d| d.abs() > 1.0) {
                return Err(format!("{OCCLUSION_PARTNER_DELTA} = {delta_xy:?}: moves are at most 1 m"));
            }
            Some(OcclusionPartner { object, threshold, delta_xy, clearance })
        }
    };
    Ok(Some(Occlusion { occluder, reference, offset_xy, partner }))
}

/// `robot_init_qpos`: a list (or fixed-size list) of 7 finite numbers.
fn qpos(batch: &RecordBatch, row: usize) -> Result<Option<[f64; 7]>, String> {
    let Some(q) =
        floats::<7>(batch, ROBOT_INIT_QPOS, row).map_err(|e| format!("{e} (the 7 arm joint positions, rad)"))?
    else {
        return Ok(None);
    };
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

    fn list(values: Vec<f64>) -> ArrayRef {
        let mut b = arrow::array::ListBuilder::new(arrow::array::Float64Builder::new());
        b.values().append_slice(&values);
        b.append(true);
        Arc::new(b.finish())
    }

    #[test]
    fn libero_pro_columns_read_back_from_their_canonical_json() {
        let b = batch(vec![
            ("light_ambient", Arc::new(Float64Array::from(vec![0.02])) as ArrayRef),
            ("light_diffuse", Arc::new(Float64Array::from(vec![0.16])) as ArrayRef),
            ("camera_pos", list(vec![0.48, 0.24, 1.62])),
            ("camera_quat_wxyz", list(vec![0.6099232, 0.3594558, 0.3594558, 0.6099232])),
            ("appearance_objects", Arc::new(StringArray::from(vec!["plate_1, basket_1"])) as ArrayRef),
            ("appearance_rgba", list(vec![0.72, 0.63, 0.5, 1.0])),
            ("image_brightness", Arc::new(Float64Array::from(vec![0.68])) as ArrayRef),
            ("image_noise_std", Arc::new(Int32Array::from(vec![12])) as ArrayRef),
            ("initial_pose_object", Arc::new(StringArray::from(vec!["akita_black_bowl_1"])) as ArrayRef),
            ("initial_pose_delta_xy", list(vec![0.17, -0.06])),
            ("initial_pose_yaw_rad", Arc::new(Float64Array::from(vec![0.785])) as ArrayRef),
            ("runtime_move_object", Arc::new(StringArray::from(vec!["plate_1"])) as ArrayRef),
            ("runtime_move_delta_xy", list(vec![0.17, 0.06])),
            ("runtime_move_min_delta", Arc::new(Float64Array::from(vec![0.18])) as ArrayRef),
        ]);
        let p = EpisodePerturbation::from_row(&b, 0).unwrap();
        assert_eq!(p.appearance.as_ref().unwrap().objects, ["plate_1", "basket_1"]);
        assert_eq!(p.lighting.unwrap().specular, None);
        let m = p.runtime_move.as_ref().unwrap();
        assert_eq!((m.trigger_distance, m.fallback_step), (DEFAULT_TRIGGER_M, DEFAULT_FALLBACK_STEP));
        assert_eq!(p.needs_camera(), Some("image_brightness/image_noise_std"));
        let back = EpisodePerturbation::from_canonical(&p.canonical().unwrap()).unwrap();
        assert_eq!(back, p);
        let edits = p.env_edits("libero_tabletop_manipulation").unwrap();
        assert_eq!(edits.agentview_raw.unwrap().quat[0], 0.6099232, "the raw quaternion is kept as given");
        // moves alone need no camera
        let moves = EpisodePerturbation { initial_pose: p.initial_pose.clone(), ..Default::default() };
        assert_eq!(moves.needs_camera(), None);
        assert!(moves.variant().is_some());
    }

    #[test]
    fn occlusion_columns_read_back_and_take_the_shipped_partner_defaults() {
        let text = |v: &str| Arc::new(StringArray::from(vec![v])) as ArrayRef;
        let b = batch(vec![
            ("occluder_object", text("black_book_occluder_1")),
            ("occlusion_reference", text("akita_black_bowl_1")),
            ("occlusion_offset_xy", list(vec![0.08, 0.0])),
            ("occlusion_partner", text("plate_1")),
        ]);
        let p = EpisodePerturbation::from_row(&b, 0).unwrap();
        let o = p.occlusion.as_ref().unwrap();
        let partner = o.partner.as_ref().unwrap();
        assert_eq!((partner.threshold, partner.delta_xy, partner.clearance), (0.24, [0.16, 0.0], 0.08));
        assert_eq!(p.needs_camera(), None, "an obstacle in the way: blind policies meet it too");
        assert_eq!(EpisodePerturbation::from_canonical(&p.canonical().unwrap()).unwrap(), p);
        assert_eq!(p.env_edits("libero_tabletop_manipulation").unwrap().occlusion.as_ref(), Some(o));
        let err = |cols: Vec<(&str, ArrayRef)>| EpisodePerturbation::from_row(&batch(cols), 0).unwrap_err();
        assert!(err(vec![("occlusion_offset_xy", list(vec![0.08, 0.0]))]).contains("occluder_object"));
        assert!(
            err(vec![("occluder_object", text("b")), ("occlusion_offset_xy", list(vec![0.08, 0.0]))])
                .contains("occlusion_reference")
        );
        assert!(
            err(vec![
                ("occluder_object", text("b")),
                ("occlusion_reference", text("r")),
                ("occlusion_offset_xy", list(vec![0.08, 0.0])),
                ("occlusion_partner_threshold_m", Arc::new(Float64Array::from(vec![0.2])) as ArrayRef),
            ])
            .contains("occlusion_partner is not")
        );
    }

    #[test]
    fn libero_pro_columns_that_do_not_go_together_are_refused() {
        let err = |cols: Vec<(&str, ArrayRef)>| EpisodePerturbation::from_row(&batch(cols), 0).unwrap_err();
        assert!(err(vec![("camera_pos", list(vec![0.0, 0.0, 1.0]))]).contains("go together"));
        assert!(
            err(vec![
                ("camera_pos", list(vec![0.0, 0.0, 1.0])),
                ("camera_quat_wxyz", list(vec![1.0, 0.0, 0.0, 0.0])),
                ("camera_azimuth_deg", Arc::new(Float64Array::from(vec![10.0])) as ArrayRef),
            ])
            .contains("not both")
        );
        assert!(err(vec![("appearance_rgba", list(vec![2.0, 0.0, 0.0, 1.0]))]).contains("appearance"));
        assert!(err(vec![("initial_pose_delta_xy", list(vec![0.1, 0.0]))]).contains("initial_pose_object"));
        assert!(
            err(vec![("runtime_move_fallback_step", Arc::new(Int32Array::from(vec![10])) as ArrayRef)])
                .contains("runtime_move_object")
        );
        assert!(err(vec![("image_noise_std", Arc::new(Float64Array::from(vec![-1.0])) as ArrayRef)]).contains("range"));
        assert!(err(vec![("light_diffuse", Arc::new(Float64Array::from(vec![11.0])) as ArrayRef)]).contains("range"));
    }
}
