//! Step 5 of the network: where a segment ends, refined on every point of the cloud near its
//! ends: a face it enters, an elbow's tangent point, a flange's rim.

use std::sync::atomic::{AtomicU64, Ordering};

use nalgebra::Vector3;
use rayon::prelude::*;

use super::super::cloud::Cloud;
use super::super::cylinder::filled_arc;
use super::segments::Piece;
use crate::robust::upper_median;

/// Points of an end's neighbourhood: (axial offset beyond the end, residual from the
/// surface, radial unit vector in the cross-section basis, |normal · axis|).
pub(super) type EndPoint = (f64, f64, [f64; 2], f64);

/// The end `at` of the piece `p` (the other end `other`), refined on every point of the
/// cloud near it:
/// - **a face**: points just beyond the end, off the pipe's surface (up to 10 cm out) with
///   normals along the axis, at one axial position (within 1 cm): a wall, floor or ceiling
///   the pipe enters, a flange or valve it ends at, whose points around the pipe the plane
///   removal or the shadow of the face took: the end is that face;
/// - **an elbow**: the surface leaves the straight pipe's as a parabola
///   (`δ = s²/2R` for a bend of radius `R`, `s` past the tangent point): the end is the
///   tangent point of the best parabola, when it explains the points significantly better
///   than the straight pipe alone;
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
            (t, rho - c.radius, [u.dot(&e1), u.dot(&e2)], n.dot(&d).abs())
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
    let near: Vec<EndPoint> = pts.iter().copied().filter(|p| p.0 <= 0.1).collect();
    if let Some(t) = elbow_tangent(&near, c.radius, tail) {
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
    if filled_arc(rim.iter().map(|p| p.2[1].atan2(p.2[0]))) < 120f64.to_radians() {
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
        .filter(|p| p.0 >= from && p.0 <= to && p.1 > 0.004 && p.1 < 0.1 && p.3 <= 0.5)
        .collect();
    if rim.len() < min_points {
        return None;
    }
    let mut e: Vec<f64> = rim.iter().map(|p| p.1).collect();
    let radius = upper_median(&mut e);
    let rim: Vec<&EndPoint> = rim
        .into_iter()
        .filter(|p| (p.1 - radius).abs() <= 0.003)
        .collect();
    (rim.len() >= min_points).then_some(rim)
}

/// Where a rim begins along the axis: the 5th percentile of its points' axial offsets.
fn rim_front(rim: &[&EndPoint]) -> f64 {
    let mut t: Vec<f64> = rim.iter().map(|p| p.0).collect();
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
        .filter(|p| (-0.01..=reach).contains(&p.0) && p.1 > 0.004 && p.3 >= cos30)
        .collect();
    face.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut j = 0;
    for i in 0..face.len() {
        while j < face.len() && face[j].0 <= face[i].0 + 0.01 {
            j += 1;
        }
        let layer = &face[i..j];
        if layer.len() >= 15
            && filled_arc(layer.iter().map(|p| p.2[1].atan2(p.2[0]))) >= 120f64.to_radians()
        {
            return Some(layer[layer.len() / 2].0);
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
        if p.0 >= 0.0 && p.0 < face && p.1.abs() <= 0.005 && p.3 <= 0.5 {
            if let Some(b) = seen.get_mut((p.0 / 0.01) as usize) {
                *b = true;
            }
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
    let mut e: Vec<f64> = rim.iter().map(|p| p.1).collect();
    (upper_median(&mut e) >= 0.01).then(|| rim_front(&rim))
}

/// How far beyond the end an elbow's surface is looked for before its tangent is sought (m):
/// within 5 cm past its tangent the surface of a long-radius 2-inch elbow leaves the straight
/// one by 16 mm at most, so nearly all of it lies in the 15 mm band.
const ELBOW_CONTINUATION_M: f64 = 0.05;
/// Fewest surface points beyond the end, as a fraction of those in as long a stretch before
/// it, for an elbow to be sought.
const ELBOW_CONTINUATION_FRACTION: f64 = 0.1;

/// Bend radii tried for an elbow, in units of the pipe's outside radius: short-radius
/// elbows (ASME B16.9: R = 1.0 × the nominal size, 1.7–2 r), long-radius ones (1.5 ×, 2.5–3 r)
/// and 3D–5D bends (6–10 r).
const BEND_RADII: [f64; 13] = [
    1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0,
];

/// The tangent point of an elbow beyond the end ([`end_of`]): the surface points (within
/// 15 mm of the straight surface, normals radial) beyond the tangent point `te` lie on a
/// torus, the elbow's surface — its centre line a circle of radius `R` leaving the axis at
/// `te` toward the bend direction `θ`, its tube the pipe's radius. `te`, `θ` and `R`
/// minimise the truncated squared residuals (`min(e², c²)`, `c = max(3σ, 2 mm)`: points of
/// a support, a flange or the next leg saturate) over a grid refined once; the tangent is
/// kept when it explains the points significantly better than the straight pipe alone
/// (25 σ², σ from the straight part).
///
/// A parabola (`δ = s²/2R`) fits only the first centimetres past the tangent: on the
/// elbow's inside the surface leaves the straight one `R/(R − r)` times faster than the
/// centre line, on its outside `R/(R + r)` times slower, and a free parabola fitted to both
/// put the tangent 1.5–2.6 cm early on photogrammetric clouds.
pub(super) fn elbow_tangent(pts: &[EndPoint], radius: f64, tail: f64) -> Option<f64> {
    let cos30 = 30f64.to_radians().cos();
    let mut surface: Vec<[f64; 4]> = pts
        .iter()
        .filter(|p| p.1.abs() <= 0.015 && p.3 <= (1.0 - cos30 * cos30).sqrt())
        .map(|p| {
            let rho = radius + p.1;
            [p.0, p.1, p.2[0] * rho, p.2[1] * rho]
        })
        .collect();
    let mut straight: Vec<f64> = surface
        .iter()
        .filter(|p| p[0] < -0.5 * tail)
        .map(|p| p[1] * p[1])
        .collect();
    if straight.len() < 20 || surface.len() < 40 {
        return None;
    }
    // An elbow's surface runs on beyond the end, within centimetres of the straight one;
    // where (nearly) nothing does, the pipe ends there and no bend is sought (the grid below
    // is most of the time the ends take).
    let count = |from: f64, to: f64| surface.iter().filter(|p| p[0] > from && p[0] <= to).count();
    let (before, beyond) = (
        count(-ELBOW_CONTINUATION_M, 0.0),
        count(0.0, ELBOW_CONTINUATION_M),
    );
    if (beyond as f64) < ELBOW_CONTINUATION_FRACTION * before as f64 {
        return None;
    }
    let sigma2 = upper_median(&mut straight) / 0.455;
    let c2 = (9.0 * sigma2).max(4e-6);
    surface.sort_by(|a, b| a[0].total_cmp(&b[0]));
    // prefix[k]: the straight pipe's truncated cost of the first k points.
    let mut prefix = Vec::with_capacity(surface.len() + 1);
    prefix.push(0.0);
    for p in &surface {
        prefix.push(prefix[prefix.len() - 1] + (p[1] * p[1]).min(c2));
    }
    let straight_cost = prefix[surface.len()];
    // The smallest cost found so far, as bits (non-negative doubles order as their bits): a
    // cell whose partial sum passes it cannot be the minimum (the terms are non-negative), so
    // its sum stops there. The minimum and its ties are never cut, so the grid's answer is the
    // one the full sums give, on any thread count.
    let best_bits = AtomicU64::new(f64::INFINITY.to_bits());
    let cost = |theta: f64, bend: f64, te: f64| -> f64 {
        let bound = f64::from_bits(best_bits.load(Ordering::Relaxed));
        let (sin, cos) = theta.sin_cos();
        let from = surface.partition_point(|p| p[0] <= te);
        let mut sum = prefix[from];
        for p in &surface[from..] {
            if sum > bound {
                return f64::INFINITY;
            }
            // w = q − C, C = te·axis + R·v; n = axis × v = (−sin θ, cos θ, 0).
            let (wx, wy, wz) = (p[2] - bend * cos, p[3] - bend * sin, p[0] - te);
            let h = -wx * sin + wy * cos;
            let in_plane = (wx * wx + wy * wy + wz * wz - h * h).max(0.0).sqrt();
            // Not `hypot`: libm's overflow-safe form was a fifth of the main command's time
            // on a cluttered million points, and these are metres.
            let a = in_plane - bend;
            let e = (a * a + h * h).sqrt() - radius;
            sum += (e * e).min(c2);
        }
        best_bits.fetch_min(sum.to_bits(), Ordering::Relaxed);
        sum
    };
    let te_min = -tail;
    let te_max = 0.05;
    // Coarse grid (θ 15°, te 4 mm, every bend radius), then around its best (θ 2.5°,
    // te 1 mm, the neighbouring radii). Ties go to the lowest index: the same answer on any
    // thread count.
    let best_of = |grid: Vec<(f64, usize, f64)>| -> Option<(f64, (f64, usize, f64))> {
        grid.into_par_iter()
            .map(|(theta, k, te)| (cost(theta, BEND_RADII[k] * radius, te), (theta, k, te)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
    };
    let te_steps = ((te_max - te_min) / 0.004).floor() as usize;
    let coarse: Vec<(f64, usize, f64)> = (0..24)
        .flat_map(|i| {
            (0..BEND_RADII.len()).flat_map(move |k| {
                (0..=te_steps)
                    .map(move |j| ((i as f64 * 15.0).to_radians(), k, te_min + j as f64 * 0.004))
            })
        })
        .collect();
    let (_, (theta0, k0, te0)) = best_of(coarse)?;
    let fine: Vec<(f64, usize, f64)> = (-4..=4)
        .flat_map(|i| {
            (k0.saturating_sub(1)..(k0 + 2).min(BEND_RADII.len())).flat_map(move |k| {
                (-4..=4).map(move |j| {
                    (
                        theta0 + (i as f64 * 2.5).to_radians(),
                        k,
                        (te0 + j as f64 * 0.001).clamp(te_min, te_max),
                    )
                })
            })
        })
        .collect();
    let (best, (_, _, te)) = best_of(fine)?;
    (straight_cost - best > 25.0 * sigma2).then_some(te)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// End points ([`EndPoint`]) of a pipe (r 30.15 mm, 0.7 mm noise) straight up to its
    /// tangent point at −3 cm, then a long-radius 90° elbow (R 76.2 mm, ASME B16.9 NPS 2)
    /// bending toward 40°: the tangent from the torus within 3 mm; the straight pipe alone
    /// has none.
    #[test]
    fn an_elbow_s_tangent_is_where_its_torus_leaves_the_pipe() {
        let (r, bend, te, theta) = (0.03015, 0.0762, -0.03, 40f64.to_radians());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut noise = || (rng.random::<f64>() - 0.5) * 0.7e-3 * 12f64.sqrt();
        let v = Vector3::new(theta.cos(), theta.sin(), 0.0);
        let b = Vector3::z().cross(&v);
        let end_point = |q: Vector3<f64>, n: Vector3<f64>| -> Option<EndPoint> {
            let rho = q.xy().norm();
            (q.z <= 0.1 && rho >= 0.5 * r && rho <= r + 0.1)
                .then(|| (q.z, rho - r, [q.x / rho, q.y / rho], n.z.abs()))
        };
        let ring = |psi: f64, m: Vector3<f64>| m * psi.cos() + b * psi.sin();
        let mut straight = Vec::new();
        for i in 0..300 {
            let t = -0.15 + (te + 0.15) * (i as f64 + 0.5) / 300.0;
            for k in 0..24 {
                let n = ring(std::f64::consts::TAU * k as f64 / 24.0, v);
                let q = Vector3::new(0.0, 0.0, t) + n * (r + noise());
                straight.extend(end_point(q, n));
            }
        }
        assert_eq!(elbow_tangent(&straight, r, 0.15), None);
        let mut pts = straight;
        for i in 0..200 {
            let phi = std::f64::consts::FRAC_PI_2 * (i as f64 + 0.5) / 200.0;
            let centre = Vector3::new(0.0, 0.0, te)
                + v * bend * (1.0 - phi.cos())
                + Vector3::z() * bend * phi.sin();
            let m = v * phi.cos() - Vector3::z() * phi.sin();
            for k in 0..24 {
                let n = ring(std::f64::consts::TAU * k as f64 / 24.0, m);
                pts.extend(end_point(centre + n * (r + noise()), n));
            }
        }
        let found = elbow_tangent(&pts, r, 0.15).expect("an elbow");
        assert!((found - te).abs() < 3e-3, "{found}");
    }
}
