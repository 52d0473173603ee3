//! Robust multi-view triangulation (paper Algorithm 1 step 3 and Algorithm 2 step 6; docs/math.md
//! §4.3): least median of squared reprojection errors over view pairs; the inlier views; the
//! point refined on them.

use nalgebra::{Point3, Vector2, Vector4};

use super::{LmedsConfig, lower_median, robust_sigma};
use crate::geometry::triangulation::{Observation, depth, triangulate, triangulate_dlt};

/// A robustly triangulated point.
#[derive(Clone, Debug, PartialEq)]
pub struct RobustPoint {
    /// The point, refined on the inlier views.
    pub point: Point3<f64>,
    /// Which observations are inliers.
    pub inliers: Vec<bool>,
    /// Robust σ of the reprojection errors (px), or the a-priori σ for few views.
    pub sigma: f64,
}

/// Squared reprojection error of `x` in `o` (∞ behind the camera).
#[must_use]
pub fn reprojection_squared(o: &Observation, x: &Point3<f64>) -> f64 {
    let h = o.p * Vector4::new(x.x, x.y, x.z, 1.0);
    if depth(&o.p, x) <= 0.0 || h.z == 0.0 {
        return f64::INFINITY;
    }
    (Vector2::new(h.x / h.z, h.y / h.z) - o.xy).norm_squared()
}

/// LMedS's robust σ beyond this many a-priori σ means its median fell among outliers.
const BREAKDOWN_FACTOR: f64 = 3.0;

/// Triangulates robustly. With five or more views: every view pair (at most 66; beyond 12
/// views, 3n pairs spread over the sequence — LMedS needs 17 pairs for 99 % confidence at 50 %
/// outliers, math §4.3) proposes a point, the one with the least
/// median squared reprojection error wins, views within `inlier_sigmas` robust σ are inliers.
/// See [`triangulate_robust_bounded`] for a variant that also survives the loss of a majority.
/// With fewer views the median is meaningless: the point from all views, then leave-one-out —
/// a view is an outlier when its error exceeds `√χ²₀.₉₇₅,₂·prior_sigma` and dropping it brings
/// the others within that bound. `None` when no pair triangulates in front of its cameras.
#[must_use]
pub fn triangulate_robust(
    obs: &[Observation],
    prior_sigma: f64,
    config: &LmedsConfig,
) -> Option<RobustPoint> {
    robust_impl(obs, prior_sigma, config, false)
}

/// [`triangulate_robust`], and when LMedS's robust σ exceeds three a-priori σ — no majority
/// agrees, e.g. two targets chained into one track as 4 + 4 + 2 views, and the median fell
/// among outliers (LMedS breaks down beyond 50 %) — the point most views agree with within
/// `√χ²₀.₉₇₅,₂·prior_sigma`. Needs an honest `prior_sigma` (e.g. the reprojection σ of the
/// SfM features with the same poses).
#[must_use]
pub fn triangulate_robust_bounded(
    obs: &[Observation],
    prior_sigma: f64,
    config: &LmedsConfig,
) -> Option<RobustPoint> {
    robust_impl(obs, prior_sigma, config, true)
}

fn robust_impl(
    obs: &[Observation],
    prior_sigma: f64,
    config: &LmedsConfig,
    bounded: bool,
) -> Option<RobustPoint> {
    let n = obs.len();
    if n < 2 {
        return None;
    }
    let cut_prior = (super::SQRT_CHI2_975_2DOF * prior_sigma).powi(2);
    if n < 5 {
        let all = triangulate(obs)?;
        let errs: Vec<f64> = obs.iter().map(|o| reprojection_squared(o, &all)).collect();
        if errs.iter().all(|e| *e <= cut_prior) || n == 2 {
            let inliers = errs.iter().map(|e| *e <= cut_prior || n == 2).collect();
            return Some(RobustPoint {
                point: all,
                inliers,
                sigma: prior_sigma,
            });
        }
        // Leave out each view in turn; keep the choice that leaves the most views within the
        // bound (then the smallest error).
        let mut best: Option<(usize, f64, RobustPoint)> = None;
        for out in 0..n {
            let rest: Vec<Observation> = (0..n).filter(|&k| k != out).map(|k| obs[k]).collect();
            let Some(x) = triangulate(&rest) else {
                continue;
            };
            let errs: Vec<f64> = obs.iter().map(|o| reprojection_squared(o, &x)).collect();
            let inliers: Vec<bool> = errs.iter().map(|e| *e <= cut_prior).collect();
            let count = inliers.iter().filter(|b| **b).count();
            let sum: f64 = errs
                .iter()
                .zip(&inliers)
                .filter(|(_, i)| **i)
                .map(|(e, _)| e)
                .sum();
            if count >= 2
                && best
                    .as_ref()
                    .is_none_or(|(c, s, _)| count > *c || (count == *c && sum < *s))
            {
                best = Some((
                    count,
                    sum,
                    RobustPoint {
                        point: x,
                        inliers,
                        sigma: prior_sigma,
                    },
                ));
            }
        }
        return best.map(|(_, _, p)| p);
    }
    let pairs: Vec<(usize, usize)> = if n <= 12 {
        (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .collect()
    } else {
        // Pairs spread over the sequence: each view with views a quarter, a third and half
        // the sequence away.
        (0..n)
            .flat_map(|i| {
                [n / 4, n / 3, n / 2]
                    .into_iter()
                    .map(move |d| (i, (i + d.max(1)) % n))
            })
            .collect()
    };
    let mut best: Option<(Point3<f64>, f64)> = None;
    // Consensus under the a-priori bound: (point, count, sum of squares), for the breakdown case.
    let mut consensus: Option<(Point3<f64>, usize, f64)> = None;
    let mut res = vec![0.0; n];
    for (i, j) in pairs {
        let Some(x) = triangulate_dlt(&[obs[i], obs[j]]) else {
            continue;
        };
        if depth(&obs[i].p, &x) <= 0.0 || depth(&obs[j].p, &x) <= 0.0 {
            continue;
        }
        let (mut count, mut sum) = (0usize, 0.0);
        for (k, o) in obs.iter().enumerate() {
            res[k] = reprojection_squared(o, &x);
            if res[k] <= cut_prior {
                count += 1;
                sum += res[k];
            }
        }
        if consensus
            .as_ref()
            .is_none_or(|(_, c, s)| count > *c || (count == *c && sum < *s))
        {
            consensus = Some((x, count, sum));
        }
        let med = lower_median(&mut res);
        if med.is_finite() && best.is_none_or(|(_, b)| med < b) {
            best = Some((x, med));
        }
    }
    let (mut x0, med) = best?;
    let mut sigma = robust_sigma(med, n, 2).max(1e-9);
    let mut cut = (config.inlier_sigmas * sigma).powi(2).max(cut_prior);
    if bounded
        && sigma > BREAKDOWN_FACTOR * prior_sigma
        && let Some((x, count, _)) = consensus
        && count >= 2
    {
        (x0, sigma, cut) = (x, prior_sigma, cut_prior);
    }
    let inlier_obs: Vec<Observation> = obs
        .iter()
        .filter(|o| reprojection_squared(o, &x0) <= cut)
        .copied()
        .collect();
    let x = triangulate(&inlier_obs).unwrap_or(x0);
    let inliers = obs
        .iter()
        .map(|o| reprojection_squared(o, &x) <= cut)
        .collect();
    Some(RobustPoint {
        point: x,
        inliers,
        sigma,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::triangulation::camera_matrix;
    use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn views(rng: &mut ChaCha8Rng, n: usize, x: &Point3<f64>, noise: f64) -> Vec<Observation> {
        let k = Matrix3::new(2000.0, 0.0, 960.0, 0.0, 2000.0, 540.0, 0.0, 0.0, 1.0);
        (0..n)
            .map(|_| {
                let eye = Vector3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-1.0..1.0),
                    -4.0,
                );
                let rot = UnitQuaternion::face_towards(&(x.coords - eye), &Vector3::y());
                let pose = Isometry3::from_parts(Translation3::from(eye), rot).inverse();
                let p = camera_matrix(&k, &pose);
                let h = p * Vector4::new(x.x, x.y, x.z, 1.0);
                let jitter =
                    Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)) * noise;
                let uv = Vector2::new(h.x / h.z, h.y / h.z) + jitter;
                Observation { p, xy: uv }
            })
            .collect()
    }

    #[test]
    fn bad_views_are_dropped() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let x = Point3::new(0.1, -0.2, 0.3);
        for n in [3usize, 4, 6, 12, 40] {
            let mut obs = views(&mut rng, n, &x, 0.1);
            // One view (two when many) moved by 25 px.
            let bad: Vec<usize> = if n >= 12 { vec![1, n - 2] } else { vec![1] };
            for &b in &bad {
                obs[b].xy += Vector2::new(25.0, -10.0);
            }
            let r = triangulate_robust(&obs, 0.2, &LmedsConfig::default()).unwrap();
            for (k, inl) in r.inliers.iter().enumerate() {
                assert_eq!(*inl, !bad.contains(&k), "n {n}: view {k}");
            }
            assert!(
                (r.point - x).norm() < 2e-3,
                "n {n}: {}",
                (r.point - x).norm()
            );
        }
    }

    #[test]
    fn two_views_are_both_inliers() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let x = Point3::new(0.0, 0.0, 0.0);
        let obs = views(&mut rng, 2, &x, 0.0);
        let r = triangulate_robust(&obs, 0.5, &LmedsConfig::default()).unwrap();
        assert_eq!(r.inliers, vec![true, true]);
        assert!((r.point - x).norm() < 1e-9);
    }
}
