//! Step 4 of the network: a candidate's inliers cut into stretches along its axis, each
//! re-fitted alone on its straight part.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::super::cloud::Cloud;
use super::super::cylinder::{Cylinder, refit_warm};
use super::NetworkConfig;
use super::rings::split_at_rings;
use super::shape::{
    Flanks, Patches, SHAPE_SAMPLE, normal_arc, normal_deviation, normal_turn, shape_departure,
};
use crate::robust::upper_median;

/// A stretch of a candidate's inliers along its axis, re-fitted.
#[derive(Clone, Debug)]
pub(super) struct Piece {
    pub(super) cylinder: Cylinder,
    pub(super) radius_std: f64,
    pub(super) rmse: f64,
    pub(super) coverage: f64,
    /// The arc the inliers' normals fill about the axis (rad): a cylinder's turn with the
    /// points, a box's faces each hold one direction.
    pub(super) normal_arc: f64,
    /// The median angle between the inliers' normals and the radial direction (rad): a few
    /// degrees on a cylinder, tens on the faces of a box's edge.
    pub(super) normal_deviation: f64,
    /// [`normal_turn`]: 1 on a cylinder, near 0 on a box's faces.
    pub(super) normal_turn: f64,
    /// [`shape_departure`] (m).
    pub(super) departure: f64,
    /// The points across its surface ([`Flanks`]).
    pub(super) flanks: Flanks,
    pub(super) start: Vector3<f64>,
    pub(super) end: Vector3<f64>,
    /// The extreme inliers before the straight part was cut, on the axis, in `start`/`end`
    /// order (an end cut by mixed pixels at a wall still finds the wall from there).
    pub(super) raw: [Vector3<f64>; 2],
    /// Its inliers (cloud indices), sorted.
    pub(super) indices: Vec<usize>,
    pub(super) fitted: bool,
    /// The centres on the axis of the rings (flanges, [`super::rings`]) at which it was cut
    /// from the next stretch of its candidate.
    pub(super) rings: Vec<Vector3<f64>>,
}

/// The candidate's inliers cut at gaps along its axis, each stretch re-fitted alone, with its
/// extreme inliers as endpoints.
pub(super) fn pieces_of(
    cloud: &Cloud,
    cyl: &Cylinder,
    inliers: &[usize],
    config: &NetworkConfig,
) -> Vec<Piece> {
    let along =
        |k: usize, c: &Cylinder| (cloud.point(k) + cloud.origin - c.point).dot(&c.direction);
    let mut order: Vec<(f64, usize)> = inliers.par_iter().map(|&k| (along(k, cyl), k)).collect();
    // A total order (ties broken by index): the same on any number of threads.
    order.par_sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut out = Vec::new();
    let patches = Patches::new(cloud, cyl, inliers);
    let runs = order
        .chunk_by(|a, b| b.0 - a.0 <= config.gap_m)
        .flat_map(|run| split_unbridged(cloud, cyl, &patches, run, config.gap_m))
        .flat_map(|run| split_at_rings(cloud, cyl, run));
    for (run, rings) in runs {
        let rings: Vec<Vector3<f64>> = rings
            .iter()
            .map(|&t| cyl.point + cyl.direction * t)
            .collect();
        if run.len() < config.cylinder.min_inliers {
            continue;
        }
        let mut idx: Vec<usize> = run.iter().map(|r| r.1).collect();
        idx.par_sort_unstable();
        // Warm from the candidate's fit: a run that is (nearly) all its inliers settles at once.
        let rf = refit_straight(cloud, &idx, cyl, inliers, config);
        let piece = match rf {
            Some((fit, coverage, raw)) => {
                let c = fit.cylinder;
                let (lo, hi) = fit
                    .inlier_indices
                    .iter()
                    .map(|&k| along(k, &c))
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| {
                        (lo.min(t), hi.max(t))
                    });
                let patches = Patches::new(cloud, &c, &fit.inlier_indices);
                let oriented = patches.oriented(cloud, &c, &fit.inlier_indices);
                let normal_arc = normal_arc(&c, &oriented);
                let normal_deviation = normal_deviation(&c, &oriented);
                let normal_turn = normal_turn(&c, &oriented).unwrap_or(0.0);
                let departure = shape_departure(cloud, &c, &fit.inlier_indices);
                Piece {
                    cylinder: c,
                    radius_std: fit.radius_std,
                    rmse: fit.rmse,
                    coverage,
                    normal_arc,
                    normal_deviation,
                    normal_turn,
                    departure,
                    flanks: patches.flanks,
                    start: c.point + c.direction * lo,
                    end: c.point + c.direction * hi,
                    raw: raw.map(|q| c.point + c.direction * (q - c.point).dot(&c.direction)),
                    indices: fit.inlier_indices,
                    fitted: true,
                    rings,
                }
            }
            None => Piece {
                cylinder: *cyl,
                radius_std: f64::NAN,
                rmse: f64::NAN,
                coverage: 0.0,
                normal_arc: 0.0,
                normal_deviation: std::f64::consts::FRAC_PI_2,
                normal_turn: 0.0,
                departure: f64::INFINITY,
                flanks: Flanks::default(),
                start: cyl.point + cyl.direction * run[0].0,
                end: cyl.point + cyl.direction * run[run.len() - 1].0,
                raw: [
                    cyl.point + cyl.direction * run[0].0,
                    cyl.point + cyl.direction * run[run.len() - 1].0,
                ],
                indices: idx,
                fitted: false,
                rings,
            },
        };
        out.push(piece);
    }
    out
}

/// Largest angle between a point's normal and the radial direction for the point to hold a
/// run together ([`split_unbridged`]).
pub(super) const BRIDGE_NORMAL_ANGLE_DEG: f64 = 15.0;

/// The run `run` (inliers `(t, k)` in axial order, no gap over `gap`) split where no point
/// with a radial normal (its patch's, [`Patches`], within [`BRIDGE_NORMAL_ANGLE_DEG`]) lies
/// over more than `gap`: the points in such a stretch are dropped. A pipe's surface has
/// radial normals; where a valve's box or a support's face crosses the candidate's surface,
/// its points pass the inlier test (normals within 30°) along lines at the faces' angle and
/// had joined a valve's two flange rims, 0.66 m apart, into one "pipe"; outliers scattered
/// through the band beyond a capped pipe's end have no patch of their own and had carried
/// its segment on along the pipe behind it. For the same reason the run's points before its
/// first and after its last radial point are dropped: its extreme inliers are where its end
/// is sought ([`super::ends`]), and a stray outlier is no end. The normals are read on an
/// even stride of at most [`SHAPE_SAMPLE`] points of the run (and its first and last). A run
/// without a radial point is returned whole.
pub(super) fn split_unbridged<'a>(
    cloud: &Cloud,
    cyl: &Cylinder,
    patches: &Patches,
    run: &'a [(f64, usize)],
    gap: f64,
) -> Vec<&'a [(f64, usize)]> {
    let cos_max = BRIDGE_NORMAL_ANGLE_DEG.to_radians().cos();
    let step = run.len().div_ceil(SHAPE_SAMPLE).max(1);
    let sampled: Vec<usize> = (0..run.len())
        .step_by(step)
        .chain(std::iter::once(run.len() - 1))
        .collect();
    let mut radial: Vec<usize> = sampled
        .into_par_iter()
        .filter(|&i| {
            let k = run[i].1;
            let p = cloud.point(k) + cloud.origin;
            patches
                .normal(cloud, k)
                .is_some_and(|n| n.dot(&cyl.radial(&p)).abs() >= cos_max)
        })
        .collect();
    radial.dedup();
    let (Some(&first), Some(&last)) = (radial.first(), radial.last()) else {
        return vec![run];
    };
    let mut out = Vec::new();
    let mut from = first;
    for w in radial.windows(2) {
        if run[w[1]].0 - run[w[0]].0 > gap {
            out.push(&run[from..=w[0]]);
            from = w[1];
        }
    }
    out.push(&run[from..=last]);
    out
}

/// Whether the piece `p` lies on the axis of the accepted piece `k`: within the angle, and
/// both of `p`'s ends within the offset of `k`'s axis line (`k` is the longer, better
/// determined; a short piece's own axis may tilt by a few degrees).
pub(super) fn coaxial(k: &Piece, p: &Piece, config: &NetworkConfig) -> bool {
    let cos = k.cylinder.direction.dot(&p.cylinder.direction).abs();
    if cos < config.coaxial_angle.cos() {
        return false;
    }
    let offset = config.coaxial_offset * k.cylinder.radius.min(p.cylinder.radius);
    [p.start, p.end, (p.start + p.end) * 0.5]
        .iter()
        .all(|q| k.cylinder.offset(q).norm() <= offset)
}

/// The gap between two pieces' spans along `a`'s axis (negative when they overlap).
pub(super) fn gap_between(a: &Piece, b: &Piece) -> f64 {
    let d = a.cylinder.direction;
    let t = |p: &Vector3<f64>| p.dot(&d);
    let (a0, a1) = (t(&a.start).min(t(&a.end)), t(&a.start).max(t(&a.end)));
    let (b0, b1) = (t(&b.start).min(t(&b.end)), t(&b.start).max(t(&b.end)));
    (b0 - a1).max(a0 - b1)
}

/// The share of a piece's span along its axis that its inliers fill, in bins of
/// max(2 cm, r/2): nearly all of a pipe's (less a shadow or two), a fifth of the span of a
/// valve's two flange rims, which fit one cylinder with the valve between them.
pub(super) fn axial_fill(cloud: &Cloud, p: &Piece) -> f64 {
    let c = &p.cylinder;
    let bin = (0.5 * c.radius).max(0.02);
    let t0 = (p.start - c.point).dot(&c.direction);
    let t1 = (p.end - c.point).dot(&c.direction);
    let (lo, hi) = (t0.min(t1), t0.max(t1));
    let bins = (((hi - lo) / bin).ceil() as usize).max(1);
    let mut filled = vec![false; bins];
    for &k in &p.indices {
        let t = (cloud.point(k) + cloud.origin - c.point).dot(&c.direction);
        if (lo..=hi).contains(&t) {
            filled[(((t - lo) / bin) as usize).min(bins - 1)] = true;
        }
    }
    filled.iter().filter(|&&f| f).count() as f64 / bins as f64
}

/// How far a ring may lie beyond the facing ends of two pieces and still stand between them
/// (m): their ends move by the straight-part cut and the re-fit.
const RING_BETWEEN_TOLERANCE_M: f64 = 0.02;

/// Whether a ring (a flange, [`super::rings`]) cut from either piece stands between `a` and
/// `b` on `a`'s axis: they are two pipes bolted together, not one pipe found twice.
pub(super) fn ring_between(a: &Piece, b: &Piece) -> bool {
    let d = a.cylinder.direction;
    let t = |p: &Vector3<f64>| p.dot(&d);
    let (a0, a1) = (t(&a.start).min(t(&a.end)), t(&a.start).max(t(&a.end)));
    let (b0, b1) = (t(&b.start).min(t(&b.end)), t(&b.start).max(t(&b.end)));
    // The facing ends, in either order.
    let (lo, hi) = if b0 - a1 > a0 - b1 {
        (a1, b0)
    } else {
        (b1, a0)
    };
    let (lo, hi) = (
        lo.min(hi) - RING_BETWEEN_TOLERANCE_M,
        lo.max(hi) + RING_BETWEEN_TOLERANCE_M,
    );
    a.rings
        .iter()
        .chain(&b.rings)
        .any(|r| (lo..=hi).contains(&t(r)))
}

/// [`refit_among`] and then again on the straight part of the inliers only
/// ([`straight_span`]): an elbow's first centimetres beyond its tangent point are within the
/// noise of the straight pipe's surface and would lengthen the segment and pull its axis.
/// Also returns the extreme inliers of the first fit (before the straight part was cut), as
/// points on its axis.
pub(super) fn refit_straight(
    cloud: &Cloud,
    idx: &[usize],
    cyl: &Cylinder,
    warm: &[usize],
    config: &NetworkConfig,
) -> Option<(super::super::cylinder::CylinderFit, f64, [Vector3<f64>; 2])> {
    let (fit, coverage) = refit_warm(cloud, idx, cyl, warm, &config.cylinder)?;
    let c = fit.cylinder;
    let along = |k: usize| (cloud.point(k) + cloud.origin - c.point).dot(&c.direction);
    let (r0, r1) = fit
        .inlier_indices
        .par_iter()
        .map(|&k| along(k))
        .fold(
            || (f64::INFINITY, f64::NEG_INFINITY),
            |(a, b), t| (a.min(t), b.max(t)),
        )
        .reduce(
            || (f64::INFINITY, f64::NEG_INFINITY),
            |x, y| (x.0.min(y.0), x.1.max(y.1)),
        );
    let raw = [c.point + c.direction * r0, c.point + c.direction * r1];
    let Some((lo, hi)) = straight_span(cloud, &c, &fit.inlier_indices) else {
        return Some((fit, coverage, raw));
    };
    let kept: Vec<usize> = idx
        .par_iter()
        .copied()
        .filter(|&k| (lo..=hi).contains(&along(k)))
        .collect();
    // The inliers within the straight span: where it drops (nearly) none, the fit stands.
    let still: Vec<usize> = fit
        .inlier_indices
        .par_iter()
        .copied()
        .filter(|&k| (lo..=hi).contains(&along(k)))
        .collect();
    let dropped = fit.inlier_indices.len() - still.len();
    if kept.len() == fit.inlier_indices.len()
        || kept.len() < config.cylinder.min_inliers
        || (dropped as f64) <= NEGLIGIBLE_BENT_FRACTION * fit.inlier_indices.len() as f64
    {
        return Some((fit, coverage, raw));
    }
    match refit_warm(cloud, &kept, &c, &still, &config.cylinder) {
        Some((f, cov)) => Some((f, cov, raw)),
        None => Some((fit, coverage, raw)),
    }
}

/// A fraction of the inliers beyond the straight span so small that re-fitting without them
/// changes nothing measurable (a few centimetres of an elbow's band on a pipe metres long
/// would be more): the fit is kept as it is.
const NEGLIGIBLE_BENT_FRACTION: f64 = 0.005;

/// The span along `c`'s axis (relative to `c.point`) where the inliers `idx` are straight:
/// slabs of max(1.5 cm, r/5) along the axis, in each the shift of the cross-section's centre
/// by least squares (`e ≈ u·δ`, `u` the radial unit vector); a slab is bent when the shift is
/// significant (χ²₂ > 13.8, p = 0.001) and above 0.5 mm. From each end inward, the span
/// starts at the first straight slab within an elbow's reach. `None` with too few slabs.
pub(super) fn straight_span(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> Option<(f64, f64)> {
    let (e1, e2) = c.cross_section_basis();
    let w = (0.2 * c.radius).max(0.015);
    let rows: Vec<(f64, f64, f64, f64)> = idx
        .par_iter()
        .map(|&k| {
            let p = cloud.point(k) + cloud.origin;
            let off = c.offset(&p);
            let rho = off.norm().max(f64::MIN_POSITIVE);
            let t = (p - c.point).dot(&c.direction);
            (t, off.dot(&e1) / rho, off.dot(&e2) / rho, rho - c.radius)
        })
        .collect();
    let (t0, t1) = rows
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), r| {
            (a.min(r.0), b.max(r.0))
        });
    let slabs = ((t1 - t0) / w).ceil().max(1.0) as usize;
    if slabs < 4 {
        return None;
    }
    // Per slab: n, Σuuᵀ (3), Σue (2), Σe².
    let mut acc = vec![[0.0f64; 7]; slabs];
    for &(t, ux, uy, e) in &rows {
        let s = (((t - t0) / w) as usize).min(slabs - 1);
        let a = &mut acc[s];
        a[0] += 1.0;
        a[1] += ux * ux;
        a[2] += ux * uy;
        a[3] += uy * uy;
        a[4] += ux * e;
        a[5] += uy * e;
        a[6] += e * e;
    }
    // A slab with less than half the typical slab's inliers cannot tell: where an elbow
    // begins, the band keeps only the few of its points that still lie near the straight
    // surface (its sides near the neutral plane), and they look straight. The more points a
    // scan has, the more such slabs pass a fixed count.
    let mut counts: Vec<f64> = acc.iter().map(|a| a[0]).filter(|&n| n > 0.0).collect();
    let typical = if counts.is_empty() {
        0.0
    } else {
        upper_median(&mut counts)
    };
    // Some(bent) for a slab with enough points to tell.
    let bent: Vec<Option<bool>> = acc
        .iter()
        .map(|a| {
            if a[0] < 12.0f64.max(0.5 * typical) {
                return None;
            }
            let det = a[1] * a[3] - a[2] * a[2];
            if det <= 1e-9 * a[0] * a[0] {
                return None;
            }
            let dx = (a[3] * a[4] - a[2] * a[5]) / det;
            let dy = (a[1] * a[5] - a[2] * a[4]) / det;
            let rss = (a[6] - dx * a[4] - dy * a[5]).max(0.0);
            let s2 = rss / (a[0] - 2.0);
            let chi2 = (dx * (a[1] * dx + a[2] * dy) + dy * (a[2] * dx + a[3] * dy)) / s2;
            Some(chi2 > 13.8 && dx.hypot(dy) > 0.5e-3)
        })
        .collect();
    // From each end inward, past the bent (and unknown) slabs to the first straight one; a
    // bent tail longer than an elbow's reach (max(15 cm, 3 r)) is not an elbow's: a support
    // or bracket touching the pipe bends one stretch, and the pipe goes on beyond it.
    let reach = ((0.15f64).max(3.0 * c.radius) / w).ceil() as usize;
    let tail = |order: &mut dyn Iterator<Item = usize>| -> Option<usize> {
        let mut skipped = 0;
        for s in order {
            match bent[s] {
                Some(false) => return (skipped <= reach).then_some(s),
                _ => skipped += 1,
            }
        }
        None
    };
    let hi = tail(&mut (0..slabs).rev()).unwrap_or(slabs - 1);
    let lo = tail(&mut (0..slabs)).unwrap_or(0);
    if lo >= hi {
        return None;
    }
    Some((t0 + lo as f64 * w, t0 + (hi + 1) as f64 * w))
}
