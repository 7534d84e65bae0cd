//! Where to grasp an object and where to put it, from its box and the goal term.

use super::motion::yaw_closing_along;
use crate::scene::{Aabb, SceneView};
use nalgebra::{Matrix3, Vector3};

/// Widest object the Panda's fingers close across (their stroke is 8 cm; keep a margin).
const MAX_GRASP_WIDTH: f64 = 0.068;
/// The finger tips reach about 2 cm below the grip site: keep the site this far above a support.
pub const FINGER_CLEARANCE: f64 = 0.018;

/// A grasp: the grip-site position and the hand's yaw.
#[derive(Debug, Clone, Copy)]
pub struct Grasp {
    pub point: Vector3<f64>,
    pub yaw: f64,
}

fn v(a: [f64; 3]) -> Vector3<f64> {
    Vector3::from(a)
}

fn rot(xmat: &[f64; 9]) -> Matrix3<f64> {
    Matrix3::from_row_slice(xmat)
}

/// The grasp for an object now. Objects narrow enough are grasped across their narrow horizontal
/// axis at mid height (at most 2.5 cm below the top); wider ones (bowls) by the rim, on the side
/// with the most room around it.
pub fn plan_grasp(view: &SceneView, obj: usize) -> Grasp {
    let o = &view.state.objects[obj];
    let r = rot(&o.xmat);
    let half = o.local_box.half_extent();
    let center = v(o.world_box.center());
    // Horizontal body axes and their extents.
    let ax = horizontal(&(r * Vector3::x()));
    let ay = horizontal(&(r * Vector3::y()));
    let (narrow, narrow_w, wide_w) =
        if half[0] <= half[1] { (ax, 2.0 * half[0], 2.0 * half[1]) } else { (ay, 2.0 * half[1], 2.0 * half[0]) };
    let (bottom, top) = (o.world_box.min[2], o.world_box.max[2]);
    if narrow_w <= MAX_GRASP_WIDTH {
        let z = (0.5 * (bottom + top)).min(top - 0.025).max(bottom + FINGER_CLEARANCE);
        return Grasp { point: Vector3::new(center.x, center.y, z), yaw: yaw_closing_along(&narrow) };
    }
    // Rim grasp: fingers across the wall, closing radially.
    let radius = 0.5 * narrow_w.min(wide_w) - 0.012;
    let z = (top - 0.02).max(bottom + FINGER_CLEARANCE);
    let candidates = [Vector3::x(), -Vector3::x(), Vector3::y(), -Vector3::y()];
    let score = |d: &Vector3<f64>| {
        let p = center + d * radius;
        let room = clearance_xy(view, obj, &p);
        // Prefer the side facing the robot (its base is at -x) a little.
        room - 0.01 * d.x
    };
    let best = candidates.iter().max_by(|a, b| score(a).total_cmp(&score(b))).copied().unwrap_or(-Vector3::x());
    let p = center + best * radius;
    Grasp { point: Vector3::new(p.x, p.y, z), yaw: yaw_closing_along(&best) }
}

fn horizontal(a: &Vector3<f64>) -> Vector3<f64> {
    let h = Vector3::new(a.x, a.y, 0.0);
    if h.norm() < 1e-6 { Vector3::x() } else { h.normalize() }
}

/// Horizontal distance from `p` to the nearest other movable object's box (capped at 10 cm).
fn clearance_xy(view: &SceneView, except: usize, p: &Vector3<f64>) -> f64 {
    view.state
        .objects
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != except && !view.facts.objects[i].fixture)
        .map(|(_, o)| box_distance_xy(&o.world_box, p))
        .fold(0.10, f64::min)
}

fn box_distance_xy(b: &Aabb, p: &Vector3<f64>) -> f64 {
    let dx = (b.min[0] - p.x).max(p.x - b.max[0]).max(0.0);
    let dy = (b.min[1] - p.y).max(p.y - b.max[1]).max(0.0);
    (dx * dx + dy * dy).sqrt()
}

/// Where the object's root should be to satisfy a placement, and the height its bottom must
/// clear over the target (the top of what it is put on or in).
#[derive(Debug, Clone, Copy)]
pub struct Placement {
    pub root: Vector3<f64>,
    pub surface_z: f64,
}

/// The placement for `on <obj> <target>` / `in <obj> <region>`.
pub fn plan_placement(view: &SceneView, obj: usize, relation: &str, target: &str) -> Option<Placement> {
    let o = &view.state.objects[obj];
    let root_above_bottom = o.pos[2] - o.world_box.min[2];
    if let Some(t) = view.facts.object(target) {
        let b = &view.state.objects[t].world_box;
        let c = b.center();
        return Some(Placement {
            root: Vector3::new(c[0], c[1], b.max[2] + root_above_bottom + 0.01),
            surface_z: b.max[2],
        });
    }
    let s = view.facts.site(target)?;
    let (site, size) = (&view.state.sites[s], view.facts.sites[s].size);
    let p = v(site.pos);
    let surface_z = site_surface(view, s);
    let root = match relation {
        // Inside the region's box: the root at its centre, the bottom above the region's floor.
        "in" => Vector3::new(p.x, p.y, (p.z).max(p.z - size[2] + root_above_bottom + 0.01)),
        // On the region: just above its top face.
        _ => Vector3::new(p.x, p.y, p.z + size[2] + root_above_bottom.max(0.0) + 0.01),
    };
    Some(Placement { root, surface_z })
}

/// Top of what a region sits on: the parent object's box top where the region is on top of it,
/// else the region's own bottom.
fn site_surface(view: &SceneView, s: usize) -> f64 {
    let facts = &view.facts.sites[s];
    let p = view.state.sites[s].pos;
    match facts.parent.as_deref().and_then(|n| view.facts.object(n)) {
        Some(parent) => view.state.objects[parent].world_box.max[2].min(p[2] + facts.size[2]),
        None => p[2],
    }
}

/// Highest top of anything (but `carried`) whose box comes within `margin` of the straight
/// path from `from` to `to` in the horizontal plane.
pub fn obstacle_top(view: &SceneView, carried: usize, from: &Vector3<f64>, to: &Vector3<f64>, margin: f64) -> f64 {
    view.state
        .objects
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != carried)
        .filter(|(_, o)| segment_box_distance_xy(&o.world_box, from, to) < margin)
        .map(|(_, o)| o.world_box.max[2])
        .fold(f64::MIN, f64::max)
}

fn segment_box_distance_xy(b: &Aabb, a: &Vector3<f64>, c: &Vector3<f64>) -> f64 {
    (0..=20)
        .map(|i| {
            let t = i as f64 / 20.0;
            box_distance_xy(b, &(a + (c - a) * t))
        })
        .fold(f64::MAX, f64::min)
}
