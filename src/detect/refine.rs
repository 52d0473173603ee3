//! Precise sub-pixel edge points of a candidate ellipse, the geometric fit and its centre's σ.
//!
//! Around the current ellipse, the grey profile along the normal is sampled by bicubic
//! interpolation every 0.25 px over ±`search` px; the edge is the centroid of the profile's
//! derivative peak in the candidate's polarity (the contiguous samples above a quarter of the
//! peak). The fit of these points gives the next ellipse, and their contrast and peak slope the
//! edge width that sets the next window (±2.5 widths); a few rounds converge. Profiles without a
//! clear edge of the right polarity (occlusion, the frame border, clutter) give no point, which
//! the validation counts as missing support. The centre's σ accounts for the correlation of
//! neighbouring edge points, which share pixels ([`centre_std_correlated`]).

use nalgebra::Vector2;

use super::fit::{EllipseFit, centre_std_correlated, fit_ellipse_geometric, shape_harmonics};
use super::image::GrayImage;
use super::image::bicubic_noise_correlation;
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
    /// Unit outward normal along which each point was found.
    pub normals: Vec<Vector2<f64>>,
    /// Normals sampled.
    pub sampled: usize,
    /// Half-length of the searched profiles (px).
    pub search: f64,
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
        search,
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
        out.normals.push(nrm);
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
    /// Amplitude of the residual harmonics no ellipse has (px): see [`shape_harmonics`].
    pub shape_px: f64,
}

/// Refines `start` by rounds of normal profiles (one normal per pixel of perimeter, 24 to 360):
/// intermediate rounds move the ellipse by the direct least-squares fit of the edge points
/// (unbiased on complete contours, and cheap) until the centre moves less than 0.01 px (at most
/// five rounds); the last round's points get the robust geometric fit.
///
/// The first round searches ±2 px (never beyond 0.35 of the semi-minor axis: the plate edge
/// lies 0.3 radius outside the disc; the widest window once if that finds too few edges); later
/// rounds search ±2.5 edge widths (at least ±1 px, at most 0.9 of the semi-minor axis and
/// 12 px), the width estimated from the last round's contrast and peak slope. A blurred edge's
/// derivative is a wide bump: a window narrower than the bump would leave the centroid near the
/// window's middle, wherever the edge is, and hide that error from the fit's residuals.
#[must_use]
pub fn refine(img: &GrayImage, start: &Ellipse, polarity: f64, min_slope: f64) -> Option<Refined> {
    let mut e = *start;
    let mut profiles = Profiles::default();
    let mut search = 2.0f64.min((0.35 * e.b).max(0.8));
    for round in 0..5 {
        let count = perimeter(&e).round().clamp(24.0, MAX_NORMALS) as usize;
        profiles = profile_edges(img, &e, polarity, search, min_slope, count);
        let too_few = |p: &Profiles| p.points.len() < 8 || p.points.len() * 2 < count;
        if round == 0 && too_few(&profiles) {
            // A blurred edge's derivative may be flat over the first window, its maximum at the
            // window's end (no point): try once with the widest window.
            let wide = (0.9 * e.b).clamp(0.8, 12.0);
            if wide > search {
                search = wide;
                profiles = profile_edges(img, &e, polarity, search, min_slope, count);
            }
        }
        if too_few(&profiles) {
            return None;
        }
        let next = crate::geometry::conic::fit_ellipse_direct(&profiles.points)?;
        let moved = (next.centre() - e.centre()).norm();
        e = next;
        let width = edge_width(&profiles);
        // The derivative peak of a blurred step falls to a quarter of its height at ±1.67 edge
        // widths: the window holds that with a margin (±2.5 widths, at least ±1 px), short of
        // the disc's far side (0.9 b).
        let wanted = (2.5 * width).max(1.0).min((0.9 * e.b).clamp(0.8, 12.0));
        let settled = (wanted - search).abs() <= 0.25 * search;
        if round > 0 && moved < 0.01 && settled {
            break;
        }
        search = wanted;
    }
    let mut fit = fit_ellipse_geometric(&profiles.points, Some(e))?;
    // Neighbouring normals share pixels through the bicubic interpolation: their edge points'
    // errors are correlated, which the independent-error σ ignores.
    let rho = profile_correlation(&profiles, edge_width(&profiles));
    let reach = (profiles.points.len() / 2).min(
        ((8.0 + 4.0 * profiles.search) * profiles.sampled as f64 / perimeter(&fit.ellipse)).ceil()
            as usize,
    );
    if let Some(std) = centre_std_correlated(&fit.ellipse, &profiles.points, rho, reach) {
        fit.centre_std_px = std;
    }
    let shape_px = shape_harmonics(&fit.ellipse, &profiles.points).unwrap_or(0.0);
    Some(Refined {
        fit,
        profiles,
        shape_px,
    })
}

/// Ramanujan's approximation of an ellipse's perimeter (px).
fn perimeter(e: &Ellipse) -> f64 {
    std::f64::consts::PI * (3.0 * (e.a + e.b) - ((3.0 * e.a + e.b) * (e.a + 3.0 * e.b)).sqrt())
}

/// How a profile's samples move its edge point: the linearised centroid estimator of
/// [`profile_edges`] on a blurred step of width `w` searched over ±`search` px. The edge
/// `t̂ = Σ (d_k − f)·t_k / W` over the samples `K` whose derivative `d_k` (a central difference)
/// exceeds the floor `f`, `W = Σ (d_k − f)`; a sample `v_j` enters `d_{j−1}` and `d_{j+1}`, so
/// `∂t̂/∂v_j = (t_{j−1}·[j−1 ∈ K] − t_{j+1}·[j+1 ∈ K]) / (2·Δ·W)` (the floor's own dependence
/// left out). Returns (offset along the normal, weight) pairs, merged into 0.5 px bins.
fn edge_influence(w: f64, search: f64) -> Vec<(f64, f64)> {
    let steps = (search / STEP_PX).round() as isize;
    let d = |k: isize| (-0.5 * (k as f64 * STEP_PX / w).powi(2)).exp();
    let floor = 0.25;
    let (mut lo, mut hi) = (0isize, 0isize);
    while lo > -steps && d(lo - 1) >= floor {
        lo -= 1;
    }
    while hi < steps && d(hi + 1) >= floor {
        hi += 1;
    }
    let total: f64 = (lo..=hi).map(|k| d(k) - floor).sum();
    let in_k = |k: isize| (lo..=hi).contains(&k);
    let mut bins: Vec<(f64, f64)> = Vec::new();
    for j in lo - 1..=hi + 1 {
        let mut u = 0.0;
        if in_k(j - 1) {
            u += (j - 1) as f64 * STEP_PX;
        }
        if in_k(j + 1) {
            u -= (j + 1) as f64 * STEP_PX;
        }
        let u = u / (2.0 * STEP_PX * total);
        let t = j as f64 * STEP_PX;
        let centre = (t / 0.5).round() * 0.5;
        match bins.iter_mut().find(|b| b.0 == centre) {
            Some(b) => b.1 += u,
            None => bins.push((centre, u)),
        }
    }
    bins.retain(|b| b.1 != 0.0);
    bins
}

/// The correlation of the errors of the edge points along normals `i` and `j` from white pixel
/// noise: `Σ_ab u_a·u_b·ρ(|q_i(a) − q_j(b)|) / Σ_ab u_a·u_b·ρ(|a − b|)` over the samples of the
/// two profiles, `u` the [`edge_influence`] of a sample and `ρ` [`bicubic_noise_correlation`].
/// Where the profiles run parallel (discs much larger than the window) this comes down to the
/// correlation of interpolations the points' distance apart; on small discs the profiles
/// converge inside the disc and share more.
fn profile_correlation(p: &Profiles, width: f64) -> impl Fn(usize, usize) -> f64 + '_ {
    let u = edge_influence(width.max(0.2), p.search);
    let own: f64 = u
        .iter()
        .flat_map(|a| {
            u.iter()
                .map(move |b| a.1 * b.1 * bicubic_noise_correlation(a.0 - b.0))
        })
        .sum();
    let reach = u.iter().map(|a| a.0.abs()).fold(0.0, f64::max);
    move |i, j| {
        let (pi, ni, pj, nj) = (p.points[i], p.normals[i], p.points[j], p.normals[j]);
        // Profiles farther apart than the interpolation's reach share nothing.
        if own <= 0.0 || (pi - pj).norm() > 2.0 * reach + 4.0 {
            return 0.0;
        }
        let mut sum = 0.0;
        for a in &u {
            let qi = pi + ni * a.0;
            for b in &u {
                sum += a.1 * b.1 * bicubic_noise_correlation((qi - pj - nj * b.0).norm());
            }
        }
        sum / own
    }
}

/// Edge width (σ of a Gaussian blur, px) from the profiles: a blurred step of contrast C and
/// width w has a peak slope C/(√(2π)·w). The contrast is read at the ends of the search window,
/// so a window narrower than the edge underestimates it, and the width with it; the rounds of
/// [`refine`] widen the window until it settles.
#[must_use]
pub fn edge_width(p: &Profiles) -> f64 {
    let (inner, outer, slope) = levels(p);
    let w = (outer - inner).abs() / ((2.0 * std::f64::consts::PI).sqrt() * slope.max(1e-9));
    if w.is_finite() {
        w.clamp(0.2, 20.0)
    } else {
        0.5
    }
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
