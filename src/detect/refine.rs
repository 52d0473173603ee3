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

/// Fewest normals sampled per round (small ellipses).
const MIN_NORMALS: f64 = 24.0;
/// Rounds of edge search and direct fit at most; they stop earlier once the centre moves by
/// less than [`CENTRE_SETTLED_PX`] and the window has settled.
const MAX_ROUNDS: usize = 5;
/// The centre has settled when a round moves it by less than this (px).
const CENTRE_SETTLED_PX: f64 = 0.01;
/// The window has settled when the next one differs from it by at most this fraction.
const WINDOW_SETTLED_FRACTION: f64 = 0.25;
/// Fewest edge points a round must find (and at least half its normals).
const MIN_EDGE_POINTS: usize = 8;
/// The first round's half-window (px), and its limit as a fraction of the semi-minor axis: the
/// plate's edge lies 0.3 radius outside the disc.
const FIRST_SEARCH_PX: f64 = 2.0;
const FIRST_SEARCH_OF_MINOR: f64 = 0.35;
/// Later rounds' half-window in edge widths: the derivative peak of a blurred step falls to a
/// quarter of its height at ±1.67 widths, and the window holds that with a margin.
const SEARCH_EDGE_WIDTHS: f64 = 2.5;
/// Later rounds' half-window at least this (px).
const MIN_LATER_SEARCH_PX: f64 = 1.0;
/// Any half-window within these (px), and at most this fraction of the semi-minor axis (short
/// of the disc's far side).
const MIN_SEARCH_PX: f64 = 0.8;
const MAX_SEARCH_PX: f64 = 12.0;
const MAX_SEARCH_OF_MINOR: f64 = 0.9;

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
    /// The geometric fit; its centre σ assumes independent edge points until
    /// [`correlate_centre_std`] replaces it.
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
/// [`correlate_centre_std`] then gives the centre σ its edge points' correlation.
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
    let mut search = FIRST_SEARCH_PX.min((FIRST_SEARCH_OF_MINOR * e.b).max(MIN_SEARCH_PX));
    for round in 0..MAX_ROUNDS {
        let count = perimeter(&e).round().clamp(MIN_NORMALS, MAX_NORMALS) as usize;
        profiles = profile_edges(img, &e, polarity, search, min_slope, count);
        let too_few = |p: &Profiles| p.points.len() < MIN_EDGE_POINTS || p.points.len() * 2 < count;
        if round == 0 && too_few(&profiles) {
            // A blurred edge's derivative may be flat over the first window, its maximum at the
            // window's end (no point): try once with the widest window.
            let wide = (MAX_SEARCH_OF_MINOR * e.b).clamp(MIN_SEARCH_PX, MAX_SEARCH_PX);
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
        let wanted = (SEARCH_EDGE_WIDTHS * width)
            .max(MIN_LATER_SEARCH_PX)
            .min((MAX_SEARCH_OF_MINOR * e.b).clamp(MIN_SEARCH_PX, MAX_SEARCH_PX));
        let settled = (wanted - search).abs() <= WINDOW_SETTLED_FRACTION * search;
        if round > 0 && moved < CENTRE_SETTLED_PX && settled {
            break;
        }
        search = wanted;
    }
    let fit = fit_ellipse_geometric(&profiles.points, Some(e))?;
    let shape_px = shape_harmonics(&fit.ellipse, &profiles.points).unwrap_or(0.0);
    Some(Refined {
        fit,
        profiles,
        shape_px,
    })
}

/// Replaces the refined fit's centre σ (from independent edge-point errors) by the one that
/// accounts for their correlation: neighbouring normals share pixels through the bicubic
/// interpolation. The costliest part of a refinement, so the validation calls it only for a
/// candidate it accepts.
pub fn correlate_centre_std(r: &mut Refined) {
    let (rho, reach) = profile_correlation(&r.profiles, &r.fit.ellipse, edge_width(&r.profiles));
    if let Some(std) = centre_std_correlated(&r.fit.ellipse, &r.profiles.points, rho, reach) {
        r.fit.centre_std_px = std;
    }
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
/// left out). Returns (offset along the normal, weight) pairs, merged into bins of `bin` px or
/// wider, so that there are at most about `max_bins` (the pair sums of
/// [`EdgeCorrelation::pair`] are quadratic in their number).
fn edge_influence(w: f64, search: f64, bin: f64, max_bins: usize) -> Vec<(f64, f64)> {
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
    let span = (hi - lo + 2) as f64 * STEP_PX;
    let bin = bin.max((span / max_bins.max(1) as f64 / bin).ceil() * bin);
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
        let centre = (t / bin).round() * bin;
        match bins.iter_mut().find(|b| b.0 == centre) {
            Some(b) => b.1 += u,
            None => bins.push((centre, u)),
        }
    }
    bins.retain(|b| b.1 != 0.0);
    bins
}

/// The correlation of the errors of two edge points from white pixel noise:
/// `Σ_ab u_a·u_b·ρ(|q_i(a) − q_j(b)|) / Σ_ab u_a·u_b·ρ(|a − b|)` over the samples of the two
/// profiles, `u` the [`edge_influence`] of a sample, `q_i(a)` the sample at offset `a` along
/// normal `i` and `ρ` [`bicubic_noise_correlation`].
struct EdgeCorrelation {
    /// The influence bins (offset along the normal, weight).
    u: Vec<(f64, f64)>,
    /// The denominator: a profile with itself.
    own: f64,
    /// Farthest a point may be from another and still share a pixel with it (px): the
    /// interpolation's 4 px support plus both profiles' farthest samples.
    reach: f64,
}

impl EdgeCorrelation {
    /// For edges of width `width` searched over ±`search` px, the influence merged into bins of
    /// `bin` px (or wider, at most about `max_bins` of them). `None` where the edge estimate
    /// depends on no sample (no correlation to speak of).
    fn new(width: f64, search: f64, bin: f64, max_bins: usize) -> Option<Self> {
        let u = edge_influence(width.max(0.2), search, bin, max_bins);
        let farthest = u.iter().map(|a| a.0.abs()).fold(0.0, f64::max);
        let mut c = Self {
            u,
            own: 1.0,
            reach: 2.0 * farthest + 4.0,
        };
        let y = Vector2::new(0.0, 1.0);
        let own = c.pair(Vector2::zeros(), y, y);
        (own > 0.0).then(|| {
            c.own = own;
            c
        })
    }

    /// The correlation of the edge points `d` apart (`p_i − p_j`) found along unit normals `ni`
    /// and `nj`, pair by pair over the samples.
    fn pair(&self, d: Vector2<f64>, ni: Vector2<f64>, nj: Vector2<f64>) -> f64 {
        if d.norm() > self.reach {
            return 0.0;
        }
        let mut sum = 0.0;
        for a in &self.u {
            let da = d + ni * a.0;
            for b in &self.u {
                sum += a.1 * b.1 * bicubic_noise_correlation((da - nj * b.0).norm());
            }
        }
        sum / self.own
    }

    /// [`Self::pair`] for parallel profiles (equal normals, `d` across them) every `TABLE_STEP`
    /// px from 0 to 4 px, beyond which the interpolations share nothing.
    fn parallel_table(&self) -> Vec<f64> {
        let y = Vector2::new(0.0, 1.0);
        (0..=TABLE_LEN)
            .map(|k| self.pair(Vector2::new(TABLE_STEP * k as f64, 0.0), y, y))
            .collect()
    }
}

/// Step of the parallel profiles' correlation table (px).
const TABLE_STEP: f64 = 0.05;
/// Entries of that table after the first: it ends at 4 px.
const TABLE_LEN: usize = 80;

/// Linear interpolation in [`EdgeCorrelation::parallel_table`] at distance `x` px; 0 at 4 px
/// and beyond.
fn table_lookup(table: &[f64], x: f64) -> f64 {
    let x = x / TABLE_STEP;
    let k = x.floor() as usize;
    if k + 1 >= table.len() {
        return 0.0;
    }
    let f = x - k as f64;
    table[k] * (1.0 - f) + table[k + 1] * f
}

/// The correlation of the errors of the edge points along normals `i` and `j` of `p` (edges of
/// width `width`, fit `e`): [`EdgeCorrelation::pair`], zero for points farther apart than the
/// interpolation reaches. Where the profiles run parallel (the farthest sample within a quarter
/// of the ellipse's least radius of curvature, `b²/a`) it depends only on the points' distance
/// and is read from a table; on small or strongly blurred discs the profiles converge inside the
/// disc, share more, and the sum is taken pair by pair. Returns the correlation and how many
/// positions apart along the contour two points may be and still correlate (for
/// [`centre_std_correlated`]): the pair-by-pair case looks at every pair (two sides of a thin
/// ellipse may be close), the tabulated case within the arc that a 4 px chord may span.
fn profile_correlation<'a>(
    p: &'a Profiles,
    e: &Ellipse,
    width: f64,
) -> (Box<dyn Fn(usize, usize) -> f64 + 'a>, usize) {
    let all = p.points.len() / 2;
    let Some(c) = EdgeCorrelation::new(width, p.search, 0.5, 12) else {
        return (Box::new(|_, _| 0.0), 0);
    };
    let curvature_radius = e.b * e.b / e.a;
    let farthest = 0.5 * (c.reach - 4.0);
    if farthest.max(0.5) <= 0.25 * curvature_radius {
        let table = c.parallel_table();
        // A chord of 4 px spans an arc of at most 2ρ·asin(2/ρ) on a curve whose radius of
        // curvature is at least ρ (Schur's comparison theorem), and neighbouring normals are
        // at least 2π·b/sampled apart along the contour (equal steps of the eccentric angle).
        let arc = 2.0 * curvature_radius * (2.0 / curvature_radius).min(1.0).asin();
        let spacing = std::f64::consts::TAU * e.b / p.sampled.max(1) as f64;
        let reach = ((arc / spacing).ceil() as usize).min(all);
        let lookup =
            move |i: usize, j: usize| table_lookup(&table, (p.points[i] - p.points[j]).norm());
        (Box::new(lookup), reach)
    } else {
        let direct =
            move |i: usize, j: usize| c.pair(p.points[i] - p.points[j], p.normals[i], p.normals[j]);
        (Box::new(direct), all)
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use crate::robust::standard_normal as gaussian;

    /// The profiles `refine` would see on `e` (one normal per pixel of perimeter, every edge
    /// found), the points moved along their normals by noise of 0.05 px.
    fn profiles_on(e: &Ellipse, search: f64, seed: u64) -> Profiles {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let count = perimeter(e).round().clamp(MIN_NORMALS, MAX_NORMALS) as usize;
        let mut p = Profiles {
            sampled: count,
            search,
            ..Profiles::default()
        };
        for k in 0..count {
            let phi = std::f64::consts::TAU * (k as f64 + 0.5) / count as f64;
            let (q, n) = point_normal(e, phi);
            p.points.push(q + n * (0.05 * gaussian(&mut rng)));
            p.normals.push(n);
        }
        p
    }

    /// The centre σ with `rho` taken over `reach` positions.
    fn centre_std(
        e: &Ellipse,
        p: &Profiles,
        rho: impl Fn(usize, usize) -> f64,
        reach: usize,
    ) -> f64 {
        centre_std_correlated(e, &p.points, rho, reach).unwrap()
    }

    /// Where `profile_correlation` tabulates (windows short against the least radius of
    /// curvature), the table gives each pair's correlation to within 0.05 of the pair-by-pair
    /// sum (1 is a point with itself; measured at most 0.03, on the most curved case, where the
    /// normals of neighbouring points converge most), the pairs it leaves out share nothing, and
    /// the centre σ is within 2 % of the one with every pair summed (measured ≤ 0.8 %).
    #[test]
    fn tabulated_correlation_matches_the_pair_by_pair_sum() {
        // (ellipse, edge width, search): least radius of curvature 12, 10, 4 and 34 px.
        let cases = [
            (Ellipse::new(50.0, 50.0, 12.0, 12.0, 0.0), 0.6, 1.5),
            (Ellipse::new(80.0, 60.0, 40.0, 20.0, 0.4), 0.8, 2.0),
            (Ellipse::new(20.0, 30.0, 9.0, 6.0, -1.1), 0.5, 1.0),
            (Ellipse::new(300.0, 200.0, 60.0, 45.0, 2.0), 1.5, 3.75),
        ];
        for (case, (e, width, search)) in cases.iter().enumerate() {
            let p = profiles_on(e, *search, case as u64);
            let c = EdgeCorrelation::new(*width, p.search, 0.5, 12).unwrap();
            let (tabulated, reach) = profile_correlation(&p, e, *width);
            let n = p.points.len();
            assert!(reach < n / 2, "case {case}: not the tabulated branch");
            let direct =
                |i: usize, j: usize| c.pair(p.points[i] - p.points[j], p.normals[i], p.normals[j]);
            let (mut worst, mut beyond, mut largest) = (0.0f64, 0.0f64, 0.0f64);
            for i in 0..n {
                for step in 1..=n / 2 {
                    let j = (i + step) % n;
                    let exact = direct(i, j);
                    if step <= reach {
                        worst = worst.max((tabulated(i, j) - exact).abs());
                        largest = largest.max(exact);
                    } else {
                        beyond = beyond.max(exact.abs());
                    }
                }
            }
            let tab = centre_std(e, &p, &tabulated, reach);
            let every = centre_std(e, &p, direct, n / 2);
            let independent = centre_std(e, &p, |_, _| 0.0, 0);
            let what = format!(
                "case {case}: reach {reach} of {n}, largest {largest:.2}, worst {worst:.2e}, beyond {beyond:.2e}, \
                 σ {tab:.5} vs {every:.5} (independent {independent:.5})"
            );
            eprintln!("{what}");
            // The neighbours do correlate (else the comparison says nothing) …
            assert!(largest > 0.2 && every > 1.15 * independent, "{what}");
            // … and the table follows the sum.
            assert!(worst < 0.05, "{what}");
            assert!(beyond < 1e-9, "{what}");
            assert!((tab / every - 1.0).abs() < 0.02, "{what}");
        }
    }

    /// The influence bins, merged to at most about 12 on wide windows (blurred edges) so that
    /// the pair sums stay cheap, change the centre σ by less than 5 % against one bin per sample
    /// (measured ≤ 3 %; the 0.5 px bins of narrow windows ≤ 2.3 %).
    #[test]
    fn wide_bins_keep_the_centre_sigma() {
        // (ellipse, edge width, search): blur σ 3 and 2 px on discs of 15 and 18 px, and a
        // 2.5 px disc.
        let cases = [
            (Ellipse::new(50.0, 50.0, 15.0, 15.0, 0.0), 3.0, 7.5),
            (Ellipse::new(50.0, 50.0, 25.0, 18.0, 0.3), 2.0, 5.0),
            (Ellipse::new(50.0, 50.0, 3.0, 2.5, 0.3), 0.7, 1.75),
        ];
        for (case, (e, width, search)) in cases.iter().enumerate() {
            let p = profiles_on(e, *search, 10 + case as u64);
            let n = p.points.len();
            let sigma = |bin: f64, max_bins: usize| {
                let c = EdgeCorrelation::new(*width, p.search, bin, max_bins).unwrap();
                let rho = |i: usize, j: usize| {
                    c.pair(p.points[i] - p.points[j], p.normals[i], p.normals[j])
                };
                (c.u.len(), centre_std(e, &p, rho, n / 2))
            };
            let fine = sigma(STEP_PX, 1000);
            let binned = sigma(0.5, 12);
            let what = format!(
                "case {case}: {} bins vs {}: σ {:.5} vs {:.5}",
                binned.0, fine.0, binned.1, fine.1
            );
            eprintln!("{what}");
            assert!(binned.0 <= 13 && fine.0 > binned.0, "{what}");
            assert!((binned.1 / fine.1 - 1.0).abs() < 0.05, "{what}");
        }
    }
}
