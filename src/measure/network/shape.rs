//! Whether a candidate's points are a round surface: how its normals turn with the points
//! about the axis and how the points depart from the circle, per azimuth bin.

use super::super::cloud::Cloud;
use super::super::cylinder::{Cylinder, filled_arc};
use crate::robust::upper_median;

/// The arc the normals of the points `idx` fill about `c`'s axis (each normal turned outward).
pub(super) fn normal_arc(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> f64 {
    let (e1, e2) = c.cross_section_basis();
    filled_arc(idx.iter().map(|&k| {
        let (n, _) = cloud.local(k);
        let radial = c.offset(&(cloud.point(k) + cloud.origin));
        let n = if n.dot(&radial) < 0.0 { -n } else { n };
        n.dot(&e2).atan2(n.dot(&e1))
    }))
}

/// How the normals turn with the points about `c`'s axis: per 10° bin of the points'
/// azimuths (with at least 5 points), the azimuth of their mean outward normal; the median
/// over neighbouring bins of the normal's turn per turn of the points. 1 on a cylinder (the
/// normal is the radial direction), near 0 on a box's faces (one normal per face), whatever
/// the noise. `None` with fewer than three filled bins.
pub(super) fn normal_turn(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> Option<f64> {
    const BINS: usize = 36;
    let (e1, e2) = c.cross_section_basis();
    let mut sums = [(0usize, 0.0f64, 0.0f64); BINS];
    for &k in idx {
        let (n, _) = cloud.local(k);
        let radial = c.offset(&(cloud.point(k) + cloud.origin));
        let n = if n.dot(&radial) < 0.0 { -n } else { n };
        let a = radial.dot(&e2).atan2(radial.dot(&e1));
        let b =
            (((a / std::f64::consts::TAU).rem_euclid(1.0) * BINS as f64) as usize).min(BINS - 1);
        let nn = (n.dot(&e1), n.dot(&e2));
        let norm = nn.0.hypot(nn.1).max(f64::MIN_POSITIVE);
        sums[b].0 += 1;
        sums[b].1 += nn.0 / norm;
        sums[b].2 += nn.1 / norm;
    }
    let angle = |b: usize| (sums[b].0 >= 5).then(|| sums[b].2.atan2(sums[b].1));
    let step = std::f64::consts::TAU / BINS as f64;
    let mut slopes: Vec<f64> = (0..BINS)
        .filter_map(|b| {
            let (x, y) = (angle(b)?, angle((b + 1) % BINS)?);
            let turn = (y - x + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            Some(turn / step)
        })
        .collect();
    if slopes.len() < 2 {
        return None;
    }
    Some(upper_median(&mut slopes))
}

/// The points' systematic departure from the circle (m): per 10° bin of their azimuths about
/// `c`'s axis (with at least 5 points) the mean residual; the RMS of those means less what
/// the noise alone gives them (`σ²/n` per bin, σ the residuals' robust scale). A pipe's is
/// a tenth of a millimetre; two thin conduits side by side, a box's edge or a strip of a
/// larger curve depart by millimetres.
pub(super) fn shape_departure(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> f64 {
    const BINS: usize = 36;
    let (e1, e2) = c.cross_section_basis();
    let mut sums = [(0usize, 0.0f64); BINS];
    let mut abs = Vec::with_capacity(idx.len());
    for &k in idx {
        let p = cloud.point(k) + cloud.origin;
        let off = c.offset(&p);
        let a = off.dot(&e2).atan2(off.dot(&e1));
        let b =
            (((a / std::f64::consts::TAU).rem_euclid(1.0) * BINS as f64) as usize).min(BINS - 1);
        let e = off.norm() - c.radius;
        sums[b].0 += 1;
        sums[b].1 += e;
        abs.push(e.abs());
    }
    if abs.is_empty() {
        return f64::INFINITY;
    }
    let sigma = 1.4826 * upper_median(&mut abs);
    let (mut m2, mut noise, mut bins) = (0.0, 0.0, 0usize);
    for &(n, sum) in sums.iter().filter(|s| s.0 >= 5) {
        let mean = sum / n as f64;
        m2 += mean * mean;
        noise += sigma * sigma / n as f64;
        bins += 1;
    }
    if bins == 0 {
        return f64::INFINITY;
    }
    ((m2 - noise) / bins as f64).max(0.0).sqrt()
}

/// The median angle between the normals of the points `idx` and `c`'s radial direction (rad).
pub(super) fn normal_deviation(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> f64 {
    let mut angles: Vec<f64> = idx
        .iter()
        .map(|&k| {
            let (n, _) = cloud.local(k);
            let radial = c.radial(&(cloud.point(k) + cloud.origin));
            n.dot(&radial).abs().min(1.0).acos()
        })
        .collect();
    if angles.is_empty() {
        return std::f64::consts::FRAC_PI_2;
    }
    upper_median(&mut angles)
}
