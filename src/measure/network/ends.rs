//! Step 6 of the network: where a segment ends, refined on every point of the cloud near its
//! ends: a face it enters, an elbow's or a reducer's tangent point, a flange's rim.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::super::cloud::Cloud;
use super::super::cylinder::filled_arc;
use super::bends::{EndPoint, bend_tangent};
use super::segments::Piece;
use crate::robust::upper_median;

/// The end `at` of the piece `p` (the other end `other`), refined on every point of the
/// cloud near it:
/// - **a face**: points just beyond the end, off the pipe's surface (up to 10 cm out) with
///   normals along the axis, at one axial position (within 1 cm): a wall, floor or ceiling
///   the pipe enters, a flange or valve it ends at, whose points around the pipe the plane
///   removal or the shadow of the face took: the end is that face;
/// - **a bend**: the surface leaves the straight pipe's along an elbow's torus or a
///   reducer's cone: the end is the tangent point of the better of the two, when it explains
///   the points significantly better than the straight pipe alone (`bends::bend_tangent`);
/// - otherwise the extreme inlier stays.
pub(super) fn end_of(
    cloud: &Cloud,
    p: &Piece,
    at: Vector3<f64>,
    other: Vector3<f64>,
    raw: Vector3<f64>,
) -> Vector3<f64> {
    let c = &p.cylinder;
    let length = (at - other).norm();
    if length <= 0.0 {
        return at;
    }
    let d = (at - other) / length;
    let (e1, e2) = c.cross_section_basis();
    let tail = (0.15f64).max(3.0 * c.radius).min(0.4 * length);
    // How far the extreme inlier before the straight-part cut lies beyond the end.
    let cut = (raw - at).dot(&d).clamp(0.0, tail);
    let local_at = at - cloud.origin;
    let axis_point = c.point - cloud.origin;
    // The points near the end first, their normals then computed together (a batch through
    // the cloud's grid, not a query each).
    let near: Vec<usize> = (0..cloud.len())
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&pos| {
            let q = cloud.point_at(pos);
            let t = (q - local_at).dot(&d);
            if !(-tail..=0.1 + cut).contains(&t) {
                return false;
            }
            let w = q - axis_point;
            let rho = (w - c.direction * w.dot(&c.direction)).norm();
            rho <= c.radius + 0.1 && rho >= 0.5 * c.radius
        })
        .collect();
    cloud.prepare_at(&near);
    let pts: Vec<EndPoint> = near
        .par_iter()
        .map(|&pos| {
            let q = cloud.point_at(pos);
            let t = (q - local_at).dot(&d);
            let w = q - axis_point;
            let off = w - c.direction * w.dot(&c.direction);
            let rho = off.norm();
            let (n, _) = cloud.local_at(pos);
            let u = off / rho.max(f64::MIN_POSITIVE);
            EndPoint {
                axial: t,
                off_surface: rho - c.radius,
                radial: [u.dot(&e1), u.dot(&e2)],
                along_axis: n.dot(&d).abs(),
            }
        })
        .collect();
    if let Some(t) = end_face(&pts, 0.08) {
        return at + d * flange_front(&pts, t).unwrap_or(t);
    }
    // Further (an end the straight-part cut shortened at a wall's mixed pixels): a face the
    // straight surface runs up to without a break.
    if let Some(t) = end_face(&pts, 0.1 + cut).filter(|&t| straight_up_to(&pts, t)) {
        return at + d * t;
    }
    let near: Vec<EndPoint> = pts.iter().copied().filter(|p| p.axial <= 0.1).collect();
    if let Some(t) = bend_tangent(&near, c.radius, tail) {
        return at + d * t;
    }
    if let Some(t) = rim_start(&near) {
        return at + d * t;
    }
    at
}

/// A flange's rim just beyond the end whose faces no station saw (the flange's shadow hides
/// the pipe's last centimetres and its front face): points 4 mm to 10 cm off the pipe's
/// surface within 3 mm of their median offset, normals radial, around at least 120° of the axis;
/// the flange's front is where the rim begins (the 5th percentile of their axial offsets).
fn rim_start(pts: &[EndPoint]) -> Option<f64> {
    let rim = rim_points(pts, -0.01, 0.08, 15)?;
    if filled_arc(rim.iter().map(|p| p.radial[1].atan2(p.radial[0]))) < 120f64.to_radians() {
        return None;
    }
    Some(rim_front(&rim))
}

/// The points of a rim between the axial offsets `from` and `to`: 4 mm to 10 cm off the
/// pipe's surface, normals radial, within 3 mm of their median offset (the rim's radius; a
/// valve's body behind a flange lies further in); `None` with fewer than `min_points`.
fn rim_points(pts: &[EndPoint], from: f64, to: f64, min_points: usize) -> Option<Vec<&EndPoint>> {
    let rim: Vec<&EndPoint> = pts
        .iter()
        .filter(|p| {
            p.axial >= from
                && p.axial <= to
                && p.off_surface > 0.004
                && p.off_surface < 0.1
                && p.along_axis <= 0.5
        })
        .collect();
    if rim.len() < min_points {
        return None;
    }
    let mut e: Vec<f64> = rim.iter().map(|p| p.off_surface).collect();
    let radius = upper_median(&mut e);
    let rim: Vec<&EndPoint> = rim
        .into_iter()
        .filter(|p| (p.off_surface - radius).abs() <= 0.003)
        .collect();
    (rim.len() >= min_points).then_some(rim)
}

/// Where a rim begins along the axis: the 5th percentile of its points' axial offsets.
fn rim_front(rim: &[&EndPoint]) -> f64 {
    let mut t: Vec<f64> = rim.iter().map(|p| p.axial).collect();
    t.sort_by(f64::total_cmp);
    t[((t.len() - 1) as f64 * 0.05).round() as usize]
}

/// The axial offset of a face just beyond the end ([`end_of`]), up to `reach`, if there is
/// one: the nearest
/// centimetre-thick layer of at least 15 face points (off the surface, normals along the
/// axis) whose azimuths fill at least 120° around the axis (a face surrounds the pipe; the
/// side of an elbow's other leg lies at one azimuth).
fn end_face(pts: &[EndPoint], reach: f64) -> Option<f64> {
    let cos30 = 30f64.to_radians().cos();
    let mut face: Vec<&EndPoint> = pts
        .iter()
        .filter(|p| {
            (-0.01..=reach).contains(&p.axial) && p.off_surface > 0.004 && p.along_axis >= cos30
        })
        .collect();
    face.sort_by(|a, b| a.axial.total_cmp(&b.axial));
    let mut j = 0;
    for i in 0..face.len() {
        while j < face.len() && face[j].axial <= face[i].axial + 0.01 {
            j += 1;
        }
        let layer = &face[i..j];
        if layer.len() >= 15
            && filled_arc(layer.iter().map(|p| p.radial[1].atan2(p.radial[0])))
                >= 120f64.to_radians()
        {
            return Some(layer[layer.len() / 2].axial);
        }
    }
    None
}

/// Whether the pipe's straight surface (points within 5 mm of it, normals radial) fills at
/// least 80 % of the centimetres from the end to `face` (a shadow may take a few; an elbow's
/// surface leaves the straight one within centimetres).
fn straight_up_to(pts: &[EndPoint], face: f64) -> bool {
    let bins = (face / 0.01).ceil().max(0.0) as usize;
    let mut seen = vec![false; bins];
    for p in pts {
        if p.axial >= 0.0
            && p.axial < face
            && p.off_surface.abs() <= 0.005
            && p.along_axis <= 0.5
            && let Some(b) = seen.get_mut((p.axial / 0.01) as usize)
        {
            *b = true;
        }
    }
    seen.iter().filter(|&&b| b).count() * 5 >= seen.len() * 4
}

/// When the face at `face` is the back of a flange (its front faces away from every
/// station): the flange's rim ([`rim_points`]) between the end and the face, standing at
/// least 1 cm proud of the pipe (a flange's outside diameter exceeds its pipe's by 5 cm or
/// more, ASME B16.5); the front is where the rim begins. `None` without a rim (a wall, a
/// floor, a flange's front): the few noisy surface points where a pipe enters a wall, 4–7 mm
/// off at scattered offsets, are no rim.
fn flange_front(pts: &[EndPoint], face: f64) -> Option<f64> {
    let rim = rim_points(pts, -0.01, face - 0.002, 10)?;
    let mut e: Vec<f64> = rim.iter().map(|p| p.off_surface).collect();
    (upper_median(&mut e) >= 0.01).then(|| rim_front(&rim))
}
