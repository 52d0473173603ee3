//! Precise sub-pixel edge points of a candidate ellipse and the validation of the result.
//!
//! Around the current ellipse, the grey profile along the normal is sampled by bicubic
//! interpolation every 0.2 px over ±`search` px; the edge is the maximum of the profile's
//! derivative in the candidate's polarity, located to sub-pixel precision by a parabola through
//! the three samples around it. The geometric fit of these points gives the next ellipse; two or
//! three rounds converge. Profiles without a clear edge of the right polarity (occlusion, the
//! frame border, clutter) give no point, which the validation counts as missing support.

use nalgebra::Vector2;

use super::fit::{EllipseFit, fit_ellipse_geometric};
use super::image::GrayImage;
use crate::geometry::conic::Ellipse;

/// Step of the normal profiles (px).
const STEP_PX: f64 = 0.25;
/// Most normals sampled per round (large ellipses: the centre is already determined to a few
/// thousandths of a pixel).
const MAX_NORMALS: f64 = 360.0;

/// One round's edge points and what the profiles saw.
#[derive(Clone, Debug, Default)]
pub struct Profiles {
    /// Edge points found.
    pub points: Vec<Vector2<f64>>,
    /// Normals sampled.
    pub sampled: usize,
    /// Grey levels just inside the edge, per point found.
    pub inside: Vec<f64>,
    /// Grey levels just outside.
    pub outside: Vec<f64>,
    /// Peak derivative per point found (grey levels per px, in the polarity's sense).
    pub strength: Vec<f64>,
}

/// Unit outward normal of the ellipse at parameter φ, and the point.
fn point_normal(e: &Ellipse, phi: f64) -> (Vector2<f64>, Vector2<f64>) {
    let (s, c) = e.theta.sin_cos();
    let (nx, ny) = (e.b * phi.cos(), e.a * phi.sin());
    let nn = (nx * nx + ny * ny).sqrt();
    (
        e.point(phi),
        Vector2::new(c * nx - s * ny, s * nx + c * ny) / nn,
    )
}

/// Samples `count` normals around `e` and finds the edge on each.
#[must_use]
pub fn profile_edges(
    img: &GrayImage,
    e: &Ellipse,
    polarity: f64,
    search: f64,
    min_slope: f64,
    count: usize,
) -> Profiles {
    let mut out = Profiles {
        sampled: count,
        ..Default::default()
    };
    let steps = (search / STEP_PX).round() as isize;
    let n = (2 * steps + 1) as usize;
    let mut prof = vec![0.0; n + 2];
    'normals: for k in 0..count {
        // Equal steps of the eccentric angle, then adjusted to arc length would be nicer; equal
        // eccentric angle weights the flat sides less, which the fit does not mind.
        let phi = std::f64::consts::TAU * (k as f64 + 0.5) / count as f64;
        let (p, nrm) = point_normal(e, phi);
        for (j, slot) in prof.iter_mut().enumerate() {
            let t = (j as isize - steps - 1) as f64 * STEP_PX;
            let q = p + nrm * t;
            match img.bicubic(q.x, q.y) {
                Some(v) => *slot = v,
                None => continue 'normals,
            }
        }
        // Central-difference derivative, in the polarity's sense (positive at the edge).
        let mut best = (f64::NEG_INFINITY, 0usize);
        for j in 1..=n {
            let d = polarity * (prof[j + 1] - prof[j - 1]) / (2.0 * STEP_PX);
            if d > best.0 {
                best = (d, j);
            }
        }
        let (peak, j) = best;
        if peak < min_slope || j == 1 || j == n {
            continue;
        }
        let d = |j: usize| polarity * (prof[j + 1] - prof[j - 1]) / (2.0 * STEP_PX);
        // Centroid of the derivative peak (samples above a quarter of the peak, contiguous):
        // for a symmetric blur this is the edge, and it does not lock to the pixel grid as a
        // parabola through three samples does.
        let floor = 0.25 * peak;
        let (mut lo, mut hi) = (j, j);
        while lo > 1 && d(lo - 1) >= floor {
            lo -= 1;
        }
        while hi < n && d(hi + 1) >= floor {
            hi += 1;
        }
        let (mut sw, mut st) = (0.0, 0.0);
        for k in lo..=hi {
            let wk = d(k) - floor;
            sw += wk;
            st += wk * k as f64;
        }
        let t = (st / sw - (steps + 1) as f64) * STEP_PX;
        out.points.push(p + nrm * t);
        out.inside.push(prof[0]);
        out.outside.push(prof[n + 1]);
        out.strength.push(peak);
    }
    out
}

/// The outcome of refining a candidate.
#[derive(Clone, Debug)]
pub struct Refined {
    /// The geometric fit.
    pub fit: EllipseFit,
    /// The last round's profiles.
    pub profiles: Profiles,
}

/// Refines `start` by rounds of normal profiles (one normal per pixel of perimeter, 24 to 360):
/// intermediate rounds move the ellipse by the direct least-squares fit of the edge points
/// (unbiased on complete contours, and cheap) until the centre moves less than 0.01 px (at most
/// four rounds); the last round's points get the robust geometric fit.
#[must_use]
pub fn refine(img: &GrayImage, start: &Ellipse, polarity: f64, min_slope: f64) -> Option<Refined> {
    let mut e = *start;
    let mut profiles = Profiles::default();
    for round in 0..4 {
        // Search ±2 px around the estimate at first, then ±1 px; never beyond 0.35 of the
        // semi-minor axis (the plate edge lies 0.3 radius outside the disc).
        let search: f64 = if round == 0 { 2.0 } else { 1.0 };
        let search = search.min((0.35 * e.b).max(0.8));
        let perimeter = std::f64::consts::PI
            * (3.0 * (e.a + e.b) - ((3.0 * e.a + e.b) * (e.a + 3.0 * e.b)).sqrt());
        let count = perimeter.round().clamp(24.0, MAX_NORMALS) as usize;
        profiles = profile_edges(img, &e, polarity, search, min_slope, count);
        if profiles.points.len() < 8 || profiles.points.len() * 2 < count {
            return None;
        }
        let next = crate::geometry::conic::fit_ellipse_direct(&profiles.points)?;
        let moved = (next.centre() - e.centre()).norm();
        e = next;
        if moved < 0.01 && round > 0 {
            break;
        }
    }
    let fit = fit_ellipse_geometric(&profiles.points, Some(e))?;
    Some(Refined { fit, profiles })
}

fn median(v: &[f64]) -> f64 {
    let mut a = v.to_vec();
    a.sort_by(f64::total_cmp);
    if a.is_empty() {
        f64::NAN
    } else {
        a[a.len() / 2]
    }
}

/// Median grey levels just inside and just outside, and the median edge slope.
#[must_use]
pub fn levels(p: &Profiles) -> (f64, f64, f64) {
    (median(&p.inside), median(&p.outside), median(&p.strength))
}

/// Spread of the grey levels well inside the ellipse (on the ellipse scaled by 0.6), relative
/// to nothing: standard deviation in grey levels; `None` if it cannot be sampled.
#[must_use]
pub fn interior_spread(img: &GrayImage, e: &Ellipse) -> Option<f64> {
    let inner = Ellipse {
        a: 0.6 * e.a,
        b: 0.6 * e.b,
        ..*e
    };
    let n = 32;
    let mut v = Vec::with_capacity(n + 1);
    v.push(img.bicubic(e.cx, e.cy)?);
    for k in 0..n {
        let p = inner.point(std::f64::consts::TAU * k as f64 / n as f64);
        v.push(img.bicubic(p.x, p.y)?);
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    Some((v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt())
}
