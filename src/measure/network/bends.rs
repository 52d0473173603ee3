//! Where a straight pipe's surface bends away beyond its end: the tangent point of an elbow
//! (a torus) or of a concentric reducer (a cone), found on the points near the end
//! ([`super::ends`]).

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use crate::robust::upper_median;

/// A cloud point near a segment's end, in the end's frame ([`super::ends`] gathers them,
/// the bends and the faces read them).
#[derive(Clone, Copy, Debug)]
pub(super) struct EndPoint {
    /// Axial offset beyond the end (m; negative before it).
    pub axial: f64,
    /// Residual from the straight pipe's surface (m; positive outside).
    pub off_surface: f64,
    /// The radial unit vector in the cross-section basis.
    pub radial: [f64; 2],
    /// |normal · axis|: 0 for a normal radial to the pipe, 1 for one along its axis.
    pub along_axis: f64,
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

/// What a bend beyond the end is fitted to: the surface points (within 15 mm of the straight
/// surface, normals within 60° of radial; `[t, e, x, y]`: axial offset, residual, position in
/// the cross-section) in axial order, the straight part's noise `σ²`, the truncation `c²`
/// (`c = max(3σ, 2 mm)`: points of a support, a flange or the next leg saturate), and the
/// straight pipe's truncated cost of the first `k` points (`prefix[k]`).
struct Evidence {
    surface: Vec<[f64; 4]>,
    sigma2: f64,
    c2: f64,
    prefix: Vec<f64>,
}

impl Evidence {
    /// The evidence of the end points `pts`; `None` with too few points to tell or when
    /// (nearly) nothing runs on beyond the end: an elbow's or a reducer's surface runs on
    /// within centimetres of the straight one; where nothing does, the pipe ends there and no
    /// bend is sought (the grids below are most of the time the ends take).
    fn new(pts: &[EndPoint], radius: f64, tail: f64) -> Option<Evidence> {
        let cos30 = 30f64.to_radians().cos();
        let mut surface: Vec<[f64; 4]> = pts
            .iter()
            .filter(|p| {
                p.off_surface.abs() <= 0.015 && p.along_axis <= (1.0 - cos30 * cos30).sqrt()
            })
            .map(|p| {
                let rho = radius + p.off_surface;
                [p.axial, p.off_surface, p.radial[0] * rho, p.radial[1] * rho]
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
        let count =
            |from: f64, to: f64| surface.iter().filter(|p| p[0] > from && p[0] <= to).count();
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
        let mut prefix = Vec::with_capacity(surface.len() + 1);
        prefix.push(0.0);
        for p in &surface {
            prefix.push(prefix[prefix.len() - 1] + (p[1] * p[1]).min(c2));
        }
        Some(Evidence {
            surface,
            sigma2,
            c2,
            prefix,
        })
    }

    /// The straight pipe's truncated cost of every point.
    fn straight_cost(&self) -> f64 {
        self.prefix[self.surface.len()]
    }
}

/// A bend's tangent point beyond the end ([`super::ends::end_of`]): the elbow's
/// ([`elbow_tangent`]) or the concentric reducer's ([`cone_tangent`]), whichever explains the
/// points better, when it explains them significantly better than the straight pipe alone
/// (by 25 σ², σ from the straight part). One-sided views make the two alike (a cone seen
/// from one side narrows like an elbow bending away): fitted as an elbow, a reducer's end
/// came out 3–4 cm early.
pub(super) fn bend_tangent(pts: &[EndPoint], radius: f64, tail: f64) -> Option<f64> {
    let ev = Evidence::new(pts, radius, tail)?;
    let elbow = elbow_tangent(&ev, radius, tail);
    let cone = cone_tangent(&ev, tail);
    let (te, cost) = match (elbow, cone) {
        (Some(e), Some(c)) => {
            if c.1 <= e.1 {
                c
            } else {
                e
            }
        }
        (e, c) => e.or(c)?,
    };
    (ev.straight_cost() - cost > 25.0 * ev.sigma2).then_some(te)
}

/// The tangent point of an elbow beyond the end and its truncated cost: the surface points
/// beyond the tangent point `te` lie on a torus, the elbow's surface — its centre line a
/// circle of radius `R` leaving the axis at `te` toward the bend direction `θ`, its tube the
/// pipe's radius. `te`, `θ` and `R` minimise the truncated squared residuals over a grid
/// refined once.
///
/// A parabola (`δ = s²/2R`) fits only the first centimetres past the tangent: on the
/// elbow's inside the surface leaves the straight one `R/(R − r)` times faster than the
/// centre line, on its outside `R/(R + r)` times slower, and a free parabola fitted to both
/// put the tangent 1.5–2.6 cm early on photogrammetric clouds.
fn elbow_tangent(ev: &Evidence, radius: f64, tail: f64) -> Option<(f64, f64)> {
    let (surface, prefix, c2) = (&ev.surface, &ev.prefix, ev.c2);
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
    let te_max = ELBOW_TANGENT_BEYOND_END_M;
    // Coarse grid (θ 15°, te 4 mm, every bend radius), then around its best (θ 2.5°,
    // te 1 mm, the neighbouring radii). Ties go to the lowest index: the same answer on any
    // thread count.
    let best_of = |grid: Vec<(f64, usize, f64)>| -> Option<(f64, (f64, usize, f64))> {
        grid.into_par_iter()
            .map(|(theta, k, te)| (cost(theta, BEND_RADII[k] * radius, te), (theta, k, te)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
    };
    let te_steps = ((te_max - te_min) / COARSE_TANGENT_STEP_M).floor() as usize;
    let coarse: Vec<(f64, usize, f64)> = (0..COARSE_BEND_DIRECTIONS)
        .flat_map(|i| {
            (0..BEND_RADII.len()).flat_map(move |k| {
                (0..=te_steps).map(move |j| {
                    (
                        (i as f64 * COARSE_BEND_DIRECTION_DEG).to_radians(),
                        k,
                        te_min + j as f64 * COARSE_TANGENT_STEP_M,
                    )
                })
            })
        })
        .collect();
    let (_, (theta0, k0, te0)) = best_of(coarse)?;
    let fine: Vec<(f64, usize, f64)> = (-FINE_STEPS..=FINE_STEPS)
        .flat_map(|i| {
            (k0.saturating_sub(1)..(k0 + 2).min(BEND_RADII.len())).flat_map(move |k| {
                (-FINE_STEPS..=FINE_STEPS).map(move |j| {
                    (
                        theta0 + (f64::from(i) * FINE_BEND_DIRECTION_DEG).to_radians(),
                        k,
                        (te0 + f64::from(j) * FINE_TANGENT_STEP_M).clamp(te_min, te_max),
                    )
                })
            })
        })
        .collect();
    let (best, (_, _, te)) = best_of(fine)?;
    Some((te, best))
}

/// The elbow's tangent is sought up to this far beyond the end (m): the straight-part cut
/// leaves the end within a few centimetres of where the surface leaves the straight pipe.
const ELBOW_TANGENT_BEYOND_END_M: f64 = 0.05;
/// The coarse grid of [`elbow_tangent`]: bend directions every 15° (24 around the axis) and
/// tangent points every 4 mm, at every radius of [`BEND_RADII`].
const COARSE_BEND_DIRECTIONS: usize = 24;
const COARSE_BEND_DIRECTION_DEG: f64 = 15.0;
const COARSE_TANGENT_STEP_M: f64 = 0.004;
/// The fine grid around the coarse grid's best: ±4 steps of 2.5° and of 1 mm (a coarse cell
/// and a half each way), at the best radius and its two neighbours.
const FINE_STEPS: i32 = 4;
const FINE_BEND_DIRECTION_DEG: f64 = 2.5;
const FINE_TANGENT_STEP_M: f64 = 0.001;

/// Gentlest cone of a concentric reducer (the radius's change per unit length): ASME B16.9's
/// gentlest, 2 × 1½ and 3 × 2½ inch, narrow by 0.08–0.09; a straight pipe's noise fits a
/// slope near 0.
const MIN_CONE_SLOPE: f64 = 0.04;
/// Steepest (45°): a swage or a reducing flange's face is a face ([`super::ends`]).
const MAX_CONE_SLOPE: f64 = 1.0;
/// Step of the tangent's coarse grid (m); the fine grid is a tenth of it.
const CONE_STEP_M: f64 = 0.002;
/// Lengths of a reducer's cone tried (m): ASME B16.9's run from 38 mm (1 × ½ inch) to 0.2 m
/// (12-inch sizes); the surface beyond is the smaller (or larger) pipe, at a constant offset.
const CONE_LENGTHS_M: [f64; 14] = [
    0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.09, 0.1, 0.12, 0.14, 0.16, 0.18, 0.2,
];

/// The tangent point of a concentric reducer beyond the end and its truncated cost: beyond
/// the tangent `te` the surface leaves the straight one linearly over the cone's length
/// `l`, `e = s·min(t − te, l)` at every azimuth (a cone on the pipe's axis, narrowing for
/// `s < 0`, widening for `s > 0`, then the next pipe at a constant offset). For each `te` and
/// `l`, `s` by least squares on the points beyond, once more on those within the truncation
/// of the first; the `te` of the smallest truncated cost on a 2 mm grid, then on a 0.2 mm
/// grid around it.
fn cone_tangent(ev: &Evidence, tail: f64) -> Option<(f64, f64)> {
    let (surface, prefix, c2) = (&ev.surface, &ev.prefix, ev.c2);
    let fit = |te: f64, l: f64| -> Option<(f64, f64)> {
        let from = surface.partition_point(|p| p[0] <= te);
        let beyond = &surface[from..];
        let g = |t: f64| (t - te).min(l);
        let slope = |keep: &dyn Fn(f64, f64) -> bool| {
            let (mut sgg, mut sge) = (0.0, 0.0);
            for p in beyond {
                let x = g(p[0]);
                if keep(x, p[1]) {
                    sgg += x * x;
                    sge += x * p[1];
                }
            }
            (sgg > 0.0).then(|| sge / sgg)
        };
        let s0 = slope(&|_, _| true)?;
        let s = slope(&|x, e| (e - s0 * x).powi(2) <= c2)?;
        if !(MIN_CONE_SLOPE..=MAX_CONE_SLOPE).contains(&s.abs()) {
            return None;
        }
        let cost = prefix[from]
            + beyond
                .iter()
                .map(|p| (p[1] - s * g(p[0])).powi(2).min(c2))
                .sum::<f64>();
        Some((te, cost))
    };
    let best = |grid: Vec<(f64, f64)>| {
        grid.into_par_iter()
            .filter_map(|(te, l)| fit(te, l).map(|(te, cost)| (te, l, cost)))
            .min_by(|a, b| a.2.total_cmp(&b.2).then(a.0.total_cmp(&b.0)))
    };
    let (te_min, te_max) = (-tail, ELBOW_CONTINUATION_M);
    let steps = ((te_max - te_min) / CONE_STEP_M).floor() as usize;
    let coarse: Vec<(f64, f64)> = (0..=steps)
        .flat_map(|j| {
            CONE_LENGTHS_M
                .iter()
                .map(move |&l| (te_min + j as f64 * CONE_STEP_M, l))
        })
        .collect();
    let (te0, l0, _) = best(coarse)?;
    let fine: Vec<(f64, f64)> = (-10..=10)
        .map(|j| {
            (
                (te0 + j as f64 * 0.1 * CONE_STEP_M).clamp(te_min, te_max),
                l0,
            )
        })
        .collect();
    best(fine).map(|(te, _, cost)| (te, cost))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
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
            (q.z <= 0.1 && rho >= 0.5 * r && rho <= r + 0.1).then(|| EndPoint {
                axial: q.z,
                off_surface: rho - r,
                radial: [q.x / rho, q.y / rho],
                along_axis: n.z.abs(),
            })
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
        assert_eq!(bend_tangent(&straight, r, 0.15), None);
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
        let found = bend_tangent(&pts, r, 0.15).expect("an elbow");
        assert!((found - te).abs() < 3e-3, "{found}");
    }

    /// End points of a 3-inch pipe (r 44.45 mm, 0.7 mm noise) straight up to −2 cm, then a
    /// concentric reducer's cone to 2 inches (r 30.15 mm) over 7.6 cm (ASME B16.9's 3 × 2), a
    /// 2-inch pipe beyond it; seen from one side only (azimuths within ±75°, as one laser
    /// station sees it). The tangent where the cone begins within 3 mm, as a cone's, not an
    /// elbow's: an elbow bending away from the station fits such points too, and had put the
    /// end 3–4 cm early.
    #[test]
    fn a_reducer_s_tangent_is_where_its_cone_begins() {
        let (r, small, te, cone) = (0.04445, 0.03015, -0.02, 0.076);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut pts = Vec::new();
        for i in 0..500 {
            let t = -0.15 + 0.25 * (i as f64 + 0.5) / 500.0;
            let rho = if t <= te {
                r
            } else if t <= te + cone {
                r + (small - r) * (t - te) / cone
            } else {
                small
            };
            for k in 0..30 {
                let psi = (-75.0 + 150.0 * (k as f64 + 0.5) / 30.0f64).to_radians();
                let e = rho + (rng.random::<f64>() - 0.5) * 0.7e-3 * 12f64.sqrt() - r;
                // The cone's normal tilts toward the axis by its half angle.
                let tilt = if t > te && t <= te + cone {
                    ((r - small) / cone).atan().sin()
                } else {
                    0.0
                };
                pts.push(EndPoint {
                    axial: t,
                    off_surface: e,
                    radial: [psi.cos(), psi.sin()],
                    along_axis: tilt,
                });
            }
        }
        let found = bend_tangent(&pts, r, 0.15).expect("a reducer");
        assert!((found - te).abs() < 3e-3, "{found}");
    }
}
