//! The BDDL goal of a task, evaluated as LIBERO evaluates it (`_check_success`).
//!
//! Success is the AND of every goal term; each term is evaluated (no short-circuit) so the per-term
//! truth values can be stored. Object positions are root-body `xpos`; regions are sites
//! (`site_xpos`, `site_xmat`, the region's size); `contact(a, b)` is true when any active contact
//! pairs one of a's non-visual geoms with one of b's. Thresholds and comparisons are LIBERO's
//! (`envs/object_states/base_object_states.py`, `envs/objects/site_object.py`,
//! `envs/objects/articulated_objects.py`); see `shared/reference/libero-port-spec.md` §5.

use crate::SimError;
use crate::bundle::{ArticulationRule, TaskInfo};
use crate::scene::object_id;
use mujoco_rs::prelude::*;
use std::ops::Deref;

/// One goal term, resolved to model ids.
#[derive(Debug, Clone)]
enum Term {
    /// On(a, object b): b below a, in contact, xy within 3 cm.
    OnObject { a: Obj, b: Obj },
    /// On(a, region b): a within the region's footprint, just above it; contact with the region's
    /// parent object when it has one.
    OnSite { a: Obj, site: Site, parent: Option<Obj> },
    /// In(a, region b): a strictly inside the region's box (z extended 1 cm down).
    InSite { a: Obj, site: Site },
    /// Open/Close/TurnOn/TurnOff: joint positions against the articulated object's rule.
    Joints { qpos_adr: Vec<usize>, rule: ArticulationRule, any: bool },
    /// Up(a): root body at least 1 m high.
    Up { a: Obj },
}

#[derive(Debug, Clone)]
struct Obj {
    body: usize,
    /// Sorted geom ids of the object's contact geoms.
    geoms: Vec<usize>,
}

#[derive(Debug, Clone)]
struct Site {
    id: usize,
    size: [f64; 3],
}

/// The goal of a task, compiled against a model.
#[derive(Debug, Clone)]
pub struct Goal {
    terms: Vec<Term>,
    /// The BDDL text of each term, e.g. `on akita_black_bowl_1 plate_1`.
    pub term_names: Vec<String>,
}

/// Truth of the goal and of each of its terms at one step.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GoalStatus {
    pub satisfied: bool,
    pub terms: Vec<bool>,
}

impl Goal {
    pub fn compile(task: &TaskInfo, model: &MjModel) -> Result<Self, SimError> {
        let mut terms = Vec::new();
        let mut names = Vec::new();
        for term in &task.goal {
            let name = term.join(" ");
            let err = |detail: String| SimError::Predicate { predicate: name.clone(), detail };
            let arg = |i: usize| term.get(i).map(String::as_str).ok_or_else(|| err(format!("missing argument {i}")));
            let compiled = match arg(0)? {
                "on" => {
                    let a = obj(task, model, arg(1)?).map_err(&err)?;
                    let b = arg(2)?;
                    if let Some(site) = task.sites.get(b) {
                        let parent = match &site.parent {
                            Some(p) if task.objects.contains_key(p) => Some(obj(task, model, p).map_err(&err)?),
                            _ => None,
                        };
                        Term::OnSite { a, site: site_of(task, model, b).map_err(&err)?, parent }
                    } else {
                        Term::OnObject { a, b: obj(task, model, b).map_err(&err)? }
                    }
                }
                "in" => {
                    let a = obj(task, model, arg(1)?).map_err(&err)?;
                    let b = arg(2)?;
                    if !task.sites.contains_key(b) {
                        return Err(err(format!("In(_, {b}) with an object container is not used by LIBERO suites")));
                    }
                    Term::InSite { a, site: site_of(task, model, b).map_err(&err)? }
                }
                op @ ("open" | "close" | "turnon" | "turnoff") => {
                    let x = arg(1)?;
                    // A region names its parent's joints (e.g. one drawer of a cabinet).
                    let (owner, joints) = match task.sites.get(x) {
                        Some(site) => (site.parent.clone().unwrap_or_default(), site.joints.clone()),
                        None => (x.to_string(), task.objects.get(x).map(|o| o.joints.clone()).unwrap_or_default()),
                    };
                    let object = task.objects.get(&owner).ok_or_else(|| err(format!("no object {owner:?}")))?;
                    let rule = *object
                        .articulation
                        .get(op)
                        .ok_or_else(|| err(format!("{} ({}) has no {op} rule", owner, object.cls)))?;
                    let qpos_adr = joints
                        .iter()
                        .map(|j| {
                            let id =
                                object_id(model, MjtObj::mjOBJ_JOINT, j, "joint").map_err(|e| err(e.to_string()))?;
                            Ok(model.jnt_qposadr()[id] as usize)
                        })
                        .collect::<Result<Vec<_>, SimError>>()?;
                    Term::Joints { qpos_adr, rule, any: matches!(op, "open" | "turnon") }
                }
                "up" => Term::Up { a: obj(task, model, arg(1)?).map_err(&err)? },
                other => return Err(err(format!("unknown predicate {other:?}"))),
            };
            terms.push(compiled);
            names.push(name);
        }
        Ok(Goal { terms, term_names: names })
    }

    /// Evaluate every term on the data as the last `mj_step` left it.
    pub fn evaluate<M: Deref<Target = MjModel>>(&self, data: &MjData<M>) -> GoalStatus {
        let terms: Vec<bool> = self.terms.iter().map(|t| eval(t, data)).collect();
        GoalStatus { satisfied: terms.iter().all(|&x| x), terms }
    }
}

fn obj(task: &TaskInfo, model: &MjModel, name: &str) -> Result<Obj, String> {
    let info = task.objects.get(name).ok_or_else(|| format!("no object {name:?} in the task"))?;
    let body = object_id(model, MjtObj::mjOBJ_BODY, &info.root_body, "body").map_err(|e| e.to_string())?;
    let mut geoms = info
        .contact_geoms
        .iter()
        .map(|g| object_id(model, MjtObj::mjOBJ_GEOM, g, "geom").map_err(|e| e.to_string()))
        .collect::<Result<Vec<_>, _>>()?;
    geoms.sort_unstable();
    Ok(Obj { body, geoms })
}

fn site_of(task: &TaskInfo, model: &MjModel, name: &str) -> Result<Site, String> {
    let info = &task.sites[name];
    let id = object_id(model, MjtObj::mjOBJ_SITE, name, "site").map_err(|e| e.to_string())?;
    let size: [f64; 3] = info.size.as_slice().try_into().map_err(|_| format!("site {name} size is not 3-D"))?;
    Ok(Site { id, size })
}

fn eval<M: Deref<Target = MjModel>>(term: &Term, d: &MjData<M>) -> bool {
    let xpos = d.xpos();
    match term {
        Term::OnObject { a, b } => {
            let (pa, pb) = (xpos[a.body], xpos[b.body]);
            let dxy = ((pb[0] - pa[0]).powi(2) + (pb[1] - pa[1]).powi(2)).sqrt();
            pb[2] <= pa[2] && in_contact(d, b, a) && dxy < 0.03
        }
        Term::OnSite { a, site, parent } => {
            let delta = site_frame_delta(d, site.id, &xpos[a.body]);
            let s = site.size;
            let above = s[2] - 0.005 < delta[2] && delta[2] < s[2] + 0.10;
            let inside = delta[0].abs() < s[0] && delta[1].abs() < s[1];
            above && inside && parent.as_ref().is_none_or(|p| in_contact(d, p, a))
        }
        Term::InSite { a, site } => {
            let (p, m) = (d.site_xpos()[site.id], d.site_xmat()[site.id]);
            let s = site.size;
            let pa = xpos[a.body];
            (0..3).all(|i| {
                let tot = (m[3 * i] * s[0] + m[3 * i + 1] * s[1] + m[3 * i + 2] * s[2]).abs();
                let lb = p[i] - tot - if i == 2 { 0.01 } else { 0.0 };
                let ub = p[i] + tot;
                pa[i] > lb && pa[i] < ub
            })
        }
        Term::Joints { qpos_adr, rule, any } => {
            let q = d.qpos();
            if *any { qpos_adr.iter().any(|&i| rule.holds(q[i])) } else { qpos_adr.iter().all(|&i| rule.holds(q[i])) }
        }
        Term::Up { a } => xpos[a.body][2] >= 1.0,
    }
}

/// `site_xmat @ (p - site_pos)`: LIBERO multiplies by R, not Rᵀ (reproduced as is).
fn site_frame_delta<M: Deref<Target = MjModel>>(d: &MjData<M>, site: usize, p: &[f64; 3]) -> [f64; 3] {
    let (sp, m) = (d.site_xpos()[site], d.site_xmat()[site]);
    let v = [p[0] - sp[0], p[1] - sp[1], p[2] - sp[2]];
    std::array::from_fn(|i| m[3 * i] * v[0] + m[3 * i + 1] * v[1] + m[3 * i + 2] * v[2])
}

fn in_contact<M: Deref<Target = MjModel>>(d: &MjData<M>, a: &Obj, b: &Obj) -> bool {
    d.contacts().iter().any(|c| {
        let (g1, g2) = (c.geom[0] as usize, c.geom[1] as usize);
        let has = |o: &Obj, g: usize| o.geoms.binary_search(&g).is_ok();
        (has(a, g1) && has(b, g2)) || (has(a, g2) && has(b, g1))
    })
}
