//! Paper Algorithm 3: the image of each target's true centre from its matched views, without
//! any object-space knowledge (docs/math.md §3.4): per view k a partner view l (step 3: average
//! convergence angle above 20°, then the least determinant of the covariance of the two-view
//! triangulated centre, Beder & Steffen 2006), the plane of the circle from the two conics
//! (Quan 1996), that plane cut with view k's cone (eqs. 3–4), the centre of the cut (eq. 5)
//! projected into view k.

use nalgebra::{Matrix3, Matrix3x4, Point3, Vector2, Vector4};
use serde::{Deserialize, Serialize};

use std::collections::HashMap;

use crate::geometry::quan::{ConicOnPlane, conic_plane};
use crate::geometry::triangulation::{Observation, triangulate_dlt};

/// Options of Algorithm 3.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EccentricityConfig {
    /// Least convergence angle of a partner view (degrees), default 20 (paper step 3a).
    pub min_convergence_deg: f64,
    /// When no view converges by `min_convergence_deg`, the widest partner is still used if it
    /// converges by at least this much (degrees), default 3 (targets seen in two neighbouring
    /// frames only: their plane is still good enough for the correction); below, the view keeps its fitted
    /// centre.
    pub fallback_convergence_deg: f64,
    /// Views whose ellipse is flatter than this minor/major ratio are not used as partners
    /// (near edge-on conics are ill-conditioned, math §3.4), default 0.2.
    pub min_axis_ratio: f64,
    /// A correction larger than this many times the eccentricity bound of the ellipse (plus 0.5
    /// px) means the plane is wrong (e.g. a mismatched partner): the view keeps its fitted
    /// centre. Default 3.
    pub max_correction_ratio: f64,
}

impl Default for EccentricityConfig {
    fn default() -> Self {
        EccentricityConfig {
            min_convergence_deg: 20.0,
            fallback_convergence_deg: 3.0,
            min_axis_ratio: 0.2,
            max_correction_ratio: 3.0,
        }
    }
}

/// One view of a target as Algorithm 3 needs it, in undistorted pixels.
#[derive(Clone, Copy, Debug)]
pub struct ConicView {
    /// `K [R | t]`.
    pub p: Matrix3x4<f64>,
    /// The projection centre.
    pub eye: Point3<f64>,
    /// The ellipse's point conic.
    pub conic: Matrix3<f64>,
    /// The ellipse centre.
    pub centre: Vector2<f64>,
    /// Minor/major axis ratio.
    pub axis_ratio: f64,
    /// Upper estimate of the eccentricity (px), see [`eccentricity_bound`].
    pub bound: f64,
    /// Whether the view may serve as a partner (e.g. false for views a robust triangulation
    /// rejected; they are still corrected).
    pub eligible: bool,
}

/// A corrected centre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correction {
    /// The image of the circle's centre (undistorted px).
    pub centre: Vector2<f64>,
    /// The partner view (index into the target's views).
    pub partner: usize,
    /// The circle's plane from the pair, `n·X + d = 0`.
    pub plane: Vector4<f64>,
    /// Convergence angle of the pair at the target (degrees).
    pub convergence_deg: f64,
    /// Minor/major axis ratio of the conic this view's cone cuts from the plane
    /// ([`ConicOnPlane::roundness`]): about 1 for a circular target, the shape's own ratio for
    /// anything else. `None` with a fallback partner (converging by less than
    /// [`EccentricityConfig::min_convergence_deg`]), whose plane is too loosely tilted to judge.
    pub roundness: Option<f64>,
}

/// Upper estimate of the eccentricity of an ellipse with semi-axes `a ≥ b` seen by a camera of
/// principal distance `c` (px): a circle of radius r at distance Z tilted by α images with
/// `a ≈ c r / Z`, `b ≈ a cos α` and eccentricity `≈ c r² sin 2α / (2 Z²)` (math §3.1), which is
/// `b·sqrt(a² − b²) / c`. Off-axis views add a little; callers scale it.
#[must_use]
pub fn eccentricity_bound(a: f64, b: f64, c: f64) -> f64 {
    if c > 0.0 {
        b * (a * a - b * b).max(0.0).sqrt() / c
    } else {
        0.0
    }
}

/// Angle (degrees) between the rays from `x` to two eyes.
fn convergence_deg(x: &Point3<f64>, e1: &Point3<f64>, e2: &Point3<f64>) -> f64 {
    let (r1, r2) = (e1 - x, e2 - x);
    let c = r1.dot(&r2) / (r1.norm() * r2.norm()).max(1e-300);
    c.clamp(-1.0, 1.0).acos().to_degrees()
}

/// A pair's cameras, the circle's plane and an anchor point on it.
type PairPlane = (PairCameras, Vector4<f64>, Point3<f64>);

/// The cameras of two views `(k, l)` in a frame where the pair is consistent:
/// `(P_k, O_k, P_l, O_l)`.
pub type PairCameras = (Matrix3x4<f64>, Point3<f64>, Matrix3x4<f64>, Point3<f64>);

/// The partner of every view (paper Algorithm 3 step 3): among views `l` with `available(k, l)`
/// converging with it by more than the threshold at the target's centre `x`, the one whose
/// two-view triangulation is least uncertain — the least determinant of the Beder–Steffen
/// covariance, evaluated at `x` as `(N_k + N_l)⁻¹` with `N = Jᵀ J` of each view's projection
/// (math §5.1), so that all pairs cost one 3×3 determinant each. `None` where no view
/// qualifies.
#[must_use]
pub fn partners(
    views: &[ConicView],
    x: &Point3<f64>,
    config: &EccentricityConfig,
    available: &dyn Fn(usize, usize) -> bool,
) -> Vec<Option<(usize, f64)>> {
    let normals: Vec<Option<Matrix3<f64>>> = views.iter().map(|v| normal_matrix(v, x)).collect();
    (0..views.len())
        .map(|k| {
            let nk = normals[k]?;
            let mut best: Option<(usize, f64, f64)> = None; // (l, det, angle)
            let mut widest: Option<(usize, f64)> = None;
            for (l, v) in views.iter().enumerate() {
                if l == k || !v.eligible || v.axis_ratio < config.min_axis_ratio || !available(k, l)
                {
                    continue;
                }
                let Some(nl) = normals[l] else { continue };
                let angle = convergence_deg(x, &views[k].eye, &v.eye);
                if widest.is_none_or(|(_, a)| angle > a) {
                    widest = Some((l, angle));
                }
                if angle <= config.min_convergence_deg {
                    continue;
                }
                let det = (nk + nl).determinant();
                if det <= 0.0 {
                    continue;
                }
                let cov_det = 1.0 / det;
                if best.is_none_or(|(_, d, _)| cov_det < d) {
                    best = Some((l, cov_det, angle));
                }
            }
            match (best, widest) {
                (Some((l, _, angle)), _) => Some((l, angle)),
                (None, Some((l, angle))) if angle >= config.fallback_convergence_deg => {
                    Some((l, angle))
                }
                _ => None,
            }
        })
        .collect()
}

/// `JᵀJ` of one view's projection at `x` (rank 2).
fn normal_matrix(v: &ConicView, x: &Point3<f64>) -> Option<Matrix3<f64>> {
    let h = v.p * Vector4::new(x.x, x.y, x.z, 1.0);
    if h.z.abs() < 1e-300 {
        return None;
    }
    let m = v.p.fixed_view::<3, 3>(0, 0);
    let r1 = (m.row(0) * h.z - m.row(2) * h.x) / (h.z * h.z);
    let r2 = (m.row(1) * h.z - m.row(2) * h.y) / (h.z * h.z);
    Some(r1.transpose() * r1 + r2.transpose() * r2)
}

/// Algorithm 3 for one target: every view's corrected centre (`None` where no partner
/// qualifies or the plane is rejected; such views keep their fitted centre). `x` is the target's
/// triangulated centre (step 1), used for the convergence angles and the covariances;
/// `available(k, l)` says whether `pair(k, l)` can give the two views' cameras in a frame of
/// their own (steps 4a–b run there: the plane from the two conics, then view k's cone cut by
/// it, anchored at the two-view triangulation of the ellipse centres; the result is a pixel
/// of view k, whatever the frame).
#[must_use]
pub fn correct_target(
    views: &[ConicView],
    x: &Point3<f64>,
    config: &EccentricityConfig,
    available: &dyn Fn(usize, usize) -> bool,
    pair: &dyn Fn(usize, usize) -> Option<PairCameras>,
) -> Vec<Option<Correction>> {
    let chosen = partners(views, x, config, available);
    let mut planes: HashMap<(usize, usize), Option<PairPlane>> = HashMap::new();
    (0..views.len())
        .map(|k| {
            let (l, convergence_deg) = chosen[k]?;
            let key = (k.min(l), k.max(l));
            let (cams, plane, anchor) = planes
                .entry(key)
                .or_insert_with(|| {
                    let cams = pair(key.0, key.1)?;
                    let (i, j) = (&views[key.0], &views[key.1]);
                    let plane =
                        conic_plane(&cams.0, &i.conic, &cams.1, &cams.2, &j.conic, &cams.3)?.plane;
                    let anchor = triangulate_dlt(&[
                        Observation {
                            p: cams.0,
                            xy: i.centre,
                        },
                        Observation {
                            p: cams.2,
                            xy: j.centre,
                        },
                    ])?;
                    Some((cams, plane, anchor))
                })
                .as_ref()?;
            let p_k = if k == key.0 { cams.0 } else { cams.2 };
            // The in-plane conic, built once for the centre and the roundness.
            let cut = ConicOnPlane::new(&p_k, &views[k].conic, plane, anchor);
            let (_, centre) = cut.centre()?;
            let allowed = config.max_correction_ratio * views[k].bound + 0.5;
            ((centre - views[k].centre).norm() <= allowed).then_some(Correction {
                centre,
                partner: l,
                plane: *plane,
                convergence_deg,
                // A fallback partner's narrow pair leaves the plane's tilt loose.
                roundness: (convergence_deg > config.min_convergence_deg)
                    .then(|| cut.roundness())
                    .flatten(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::conic::{Ellipse, conic_of_circle};
    use crate::geometry::pose::camera_centre;
    use crate::geometry::triangulation::camera_matrix;
    use crate::sim::lab::look_at;
    use nalgebra::Vector3;

    /// Exact conics of one circle in 12 views around it: every view's corrected centre is the
    /// projection of the true centre to 1e-6 px, although the ellipse centres are pixels away.
    #[test]
    fn exact_conics_give_the_true_projected_centre() {
        let k = Matrix3::new(3000.0, 0.0, 1920.0, 0.0, 3000.0, 1080.0, 0.0, 0.0, 1.0);
        let centre = Vector3::new(0.1, -0.05, 0.0);
        let normal = Vector3::new(0.1, 0.2, -1.0).normalize();
        let radius = 0.05;
        let mut views = Vec::new();
        let mut truth = Vec::new();
        for s in 0..12 {
            let phi = f64::from(s) * 0.5;
            let eye =
                nalgebra::Point3::new(1.2 * phi.cos(), 0.9 * phi.sin(), -1.0 - 0.1 * f64::from(s));
            let pose = look_at(&eye, &nalgebra::Point3::from(centre), &Vector3::y(), 0.0);
            let conic = conic_of_circle(&k, &pose, &centre, &normal, radius).unwrap();
            let e = Ellipse::from_conic(&conic).unwrap();
            let p = camera_matrix(&k, &pose);
            let h = p * Vector4::new(centre.x, centre.y, centre.z, 1.0);
            truth.push(Vector2::new(h.x / h.z, h.y / h.z));
            views.push(ConicView {
                p,
                eye: camera_centre(&pose),
                conic: e.to_conic(),
                centre: e.centre(),
                axis_ratio: e.b / e.a,
                bound: eccentricity_bound(e.a, e.b, 3000.0),
                eligible: true,
            });
        }
        let pair = |k: usize, l: usize| Some((views[k].p, views[k].eye, views[l].p, views[l].eye));
        let corrections = correct_target(
            &views,
            &nalgebra::Point3::from(centre),
            &EccentricityConfig::default(),
            &|_, _| true,
            &pair,
        );
        let mut largest_eccentricity: f64 = 0.0;
        for (k, c) in corrections.iter().enumerate() {
            let c = c.expect("every view has a partner");
            assert!(c.convergence_deg > 20.0);
            assert!(
                (c.centre - truth[k]).norm() < 1e-6,
                "view {k}: {} vs {}",
                c.centre,
                truth[k]
            );
            largest_eccentricity = largest_eccentricity.max((views[k].centre - truth[k]).norm());
        }
        assert!(
            largest_eccentricity > 1.0,
            "the test needs visible eccentricity: {largest_eccentricity}"
        );
    }

    #[test]
    fn eccentricity_bound_matches_the_on_axis_formula() {
        // r = 0.05 m at Z = 1 m tilted 45°, c = 3000: e = c r² sin 2α / (2 (Z² − r² sin² α)).
        let (c, r, z, alpha) = (3000.0, 0.05f64, 1.0f64, 45f64.to_radians());
        let a = c * r / z;
        let b = a * alpha.cos();
        let exact = c * r * r * (2.0 * alpha).sin() / (2.0 * (z * z - r * r * alpha.sin().powi(2)));
        let bound = eccentricity_bound(a, b, c);
        assert!((bound - exact).abs() / exact < 0.01, "{bound} vs {exact}");
    }
}
