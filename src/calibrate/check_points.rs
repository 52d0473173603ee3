//! Check points: the adjusted targets compared with coordinates from another instrument (a
//! total station, a laser tracker, an industrial photogrammetry system), the way industrial
//! photogrammetry verifies a calibration in object space (VDI/VDE 2634 part 1 compares lengths;
//! here the whole network after a 7-parameter similarity, as Luhmann et al., *Close-Range
//! Photogrammetry and 3D Imaging*, §7.2, check-point RMS).
//!
//! No id correspondence is needed: the check points are associated by geometry. Every
//! point's triangles with pairs of its nearest neighbours are described by their two side
//! ratios (invariant to a similarity); a triangle of the targets and a triangle of the check
//! points with the same ratios propose a similarity; each proposal is scored by how many
//! targets it brings within tolerance of a check point (mutually nearest), and the best
//! consensus, refined by least squares on all its pairs, wins. Proper rotations only.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Point3, Vector3};
use serde::Serialize;

use crate::adjust::{Similarity, similarity_from_points};

/// Why check points could not be evaluated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CheckPointError {
    /// A 7-parameter similarity needs four points to have a residual.
    #[error(
        "{found} check point(s): a 7-parameter similarity needs at least 4 (3 determine it, the 4th checks it)"
    )]
    TooFew {
        /// Points given.
        found: usize,
    },
    /// Fewer than four targets could be associated.
    #[error(
        "only {found} of the {points} check points could be associated with the {targets} adjusted targets by their geometry (4 needed): are they of this lab, in metres?"
    )]
    NoAssociation {
        /// Pairs found.
        found: usize,
        /// Check points given.
        points: usize,
        /// Adjusted targets.
        targets: usize,
    },
}

/// A check point compared with its target.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CheckPointResult {
    /// The check point's id.
    pub id: String,
    /// The adjusted target it was associated with (index into the network's targets).
    pub target: usize,
    /// Check point minus transformed target (m).
    pub residual_m: [f64; 3],
    /// Length of the residual (m).
    pub distance_m: f64,
    /// The target's σ per axis after the similarity (m), if its covariance is known.
    pub target_std_m: Option<[f64; 3]>,
}

/// The object-space accuracy of the adjusted targets.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CheckPointReport {
    /// Per associated check point.
    pub points: Vec<CheckPointResult>,
    /// Check points that found no target.
    pub unassociated: Vec<String>,
    /// RMS of the 3D distances (m).
    pub rms_m: f64,
    /// Median distance (m).
    pub median_m: f64,
    /// Largest distance (m).
    pub max_m: f64,
    /// The RMS distance the targets' covariances and the check points' σ predict (m), after
    /// the similarity's 7 parameters: `sqrt((1 − 7/(3n))·mean(s²·tr Σᵢ + 3σ_c²))`.
    pub predicted_rms_m: Option<f64>,
    /// The residuals in units of their own σ: `sqrt(Σ dᵢᵀ(s²RΣᵢRᵀ + σ_c²I)⁻¹dᵢ / (3n − 7))`, 1
    /// when the targets' covariances are right. Unlike the RMS it is not dominated by the few
    /// weakly determined targets (three or four views) whose σ are largest.
    pub normalized_rms: Option<f64>,
    /// The similarity's scale (metres per SfM unit).
    pub scale: f64,
    /// Its rotation (w, x, y, z).
    pub rotation_wxyz: [f64; 4],
    /// Its translation (m).
    pub translation_m: [f64; 3],
}

/// Tolerance of the association as a fraction of the check points' median nearest-neighbour
/// spacing.
const TOLERANCE: f64 = 0.2;
/// Neighbours of each point its triangles are built from.
const NEIGHBOURS: usize = 6;
/// Relative tolerance of two triangles' side ratios.
const RATIO_TOLERANCE: f64 = 0.02;

/// Compares the adjusted `targets` (SfM frame; `covariance` per target in SfM units², when
/// known) with `check` points `(id, metric coordinates)` of σ `check_sigma_m` per axis.
///
/// # Errors
///
/// [`CheckPointError`] for fewer than four check points, or fewer than four associated.
pub fn check_points(
    targets: &[Vector3<f64>],
    covariance: Option<&[Matrix3<f64>]>,
    check: &[(String, Point3<f64>)],
    check_sigma_m: f64,
) -> Result<CheckPointReport, CheckPointError> {
    if check.len() < 4 {
        return Err(CheckPointError::TooFew { found: check.len() });
    }
    // Survey coordinates are large: work around the first check point.
    let origin = check[0].1.coords;
    let to: Vec<Vector3<f64>> = check.iter().map(|(_, p)| p.coords - origin).collect();
    let no_association = |found| CheckPointError::NoAssociation {
        found,
        points: check.len(),
        targets: targets.len(),
    };
    if targets.len() < 4 {
        return Err(no_association(0));
    }
    let tol = TOLERANCE * median_spacing(&to);
    let pairs = associate(targets, &to, tol);
    if pairs.len() < 4 {
        return Err(no_association(pairs.len()));
    }
    let from: Vec<Vector3<f64>> = pairs.iter().map(|&(t, _)| targets[t]).collect();
    let onto: Vec<Vector3<f64>> = pairs.iter().map(|&(_, c)| to[c]).collect();
    let sim = similarity_from_points(&from, &onto).ok_or_else(|| no_association(pairs.len()))?;
    let rot = *sim.rotation.to_rotation_matrix().matrix();
    let metric_cov = |t: usize| {
        covariance
            .and_then(|cov| cov.get(t))
            .map(|s| rot * s * rot.transpose() * (sim.scale * sim.scale))
    };
    // Σ dᵀ C⁻¹ d over the pairs, when every target has a covariance.
    let chi2: Option<f64> = pairs
        .iter()
        .map(|&(t, c)| {
            let d = to[c] - sim.apply(&targets[t]);
            let m = metric_cov(t)? + Matrix3::identity() * (check_sigma_m * check_sigma_m);
            Some(d.dot(&(m.try_inverse()? * d)))
        })
        .sum();
    let mut points: Vec<CheckPointResult> = pairs
        .iter()
        .map(|&(t, c)| {
            let r = to[c] - sim.apply(&targets[t]);
            let target_std_m = metric_cov(t).map(|m| [0, 1, 2].map(|k| m[(k, k)].max(0.0).sqrt()));
            CheckPointResult {
                id: check[c].0.clone(),
                target: t,
                residual_m: r.into(),
                distance_m: r.norm(),
                target_std_m,
            }
        })
        .collect();
    points.sort_by(|a, b| a.id.cmp(&b.id));
    let associated: std::collections::HashSet<usize> = pairs.iter().map(|&(_, c)| c).collect();
    let unassociated = (0..check.len())
        .filter(|c| !associated.contains(c))
        .map(|c| check[c].0.clone())
        .collect();
    let n = points.len();
    let mut d: Vec<f64> = points.iter().map(|p| p.distance_m).collect();
    d.sort_by(f64::total_cmp);
    let rms_m = (d.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
    let median_m = if n % 2 == 1 {
        d[n / 2]
    } else {
        0.5 * (d[n / 2 - 1] + d[n / 2])
    };
    let predicted_rms_m = covariance.map(|_| {
        let mean: f64 = points
            .iter()
            .map(|p| {
                p.target_std_m
                    .map_or(0.0, |s| s.iter().map(|x| x * x).sum())
                    + 3.0 * check_sigma_m * check_sigma_m
            })
            .sum::<f64>()
            / n as f64;
        ((1.0 - 7.0 / (3.0 * n as f64)).max(0.0) * mean).sqrt()
    });
    let normalized_rms = chi2.map(|c| (c / (3 * n).saturating_sub(7).max(1) as f64).sqrt());
    let q = sim.rotation.into_inner();
    Ok(CheckPointReport {
        normalized_rms,
        points,
        unassociated,
        rms_m,
        median_m,
        max_m: d[n - 1],
        predicted_rms_m,
        scale: sim.scale,
        rotation_wxyz: [q.w, q.i, q.j, q.k],
        translation_m: (sim.translation + origin).into(),
    })
}

/// Median distance of each point to its nearest neighbour.
fn median_spacing(p: &[Vector3<f64>]) -> f64 {
    let mut nearest: Vec<f64> = p
        .iter()
        .enumerate()
        .map(|(i, a)| {
            p.iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, b)| (a - b).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    nearest.sort_by(f64::total_cmp);
    nearest[nearest.len() / 2]
}

/// The `k` nearest neighbours of every point (brute force: a lab has hundreds of targets).
fn neighbours(p: &[Vector3<f64>], k: usize) -> Vec<Vec<usize>> {
    p.iter()
        .enumerate()
        .map(|(i, a)| {
            let mut d: Vec<(f64, usize)> = p
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(j, b)| ((a - b).norm_squared(), j))
                .collect();
            d.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            d.into_iter().take(k).map(|(_, j)| j).collect()
        })
        .collect()
}

/// Ordered triangles `(p, q, r)` of each point with two of its neighbours, described by
/// `(|pr|/|pq|, |qr|/|pq|)`.
fn triangles(p: &[Vector3<f64>], nb: &[Vec<usize>]) -> Vec<([usize; 3], [f64; 2])> {
    let mut out = Vec::new();
    for (i, list) in nb.iter().enumerate() {
        for &q in list {
            for &r in list {
                if q == r {
                    continue;
                }
                let pq = (p[q] - p[i]).norm();
                if pq <= 0.0 {
                    continue;
                }
                out.push((
                    [i, q, r],
                    [(p[r] - p[i]).norm() / pq, (p[r] - p[q]).norm() / pq],
                ));
            }
        }
    }
    out
}

/// Consensus association (module docs): `(target, check point)` pairs.
fn associate(targets: &[Vector3<f64>], to: &[Vector3<f64>], tol: f64) -> Vec<(usize, usize)> {
    let entries: Vec<[f64; 3]> = to.iter().map(|v| [v.x, v.y, v.z]).collect();
    let Ok(tree) = ImmutableKdTree::<f64, 3>::new_from_slice(&entries) else {
        return Vec::new();
    };
    let k = NEIGHBOURS.min(targets.len() - 1).min(to.len() - 1);
    let mut from_tri = triangles(targets, &neighbours(targets, k));
    // Each target's own triangles: a few per target are enough to seed.
    from_tri.dedup_by_key(|(v, _)| v[0]);
    let mut to_tri = triangles(to, &neighbours(to, k));
    to_tri.sort_by(|a, b| a.1[0].total_cmp(&b.1[0]));
    let nearest = |x: &Vector3<f64>| {
        let nb = tree
            .query(&[x.x, x.y, x.z])
            .nearest_n::<SquaredEuclidean<f64>>(std::num::NonZero::<usize>::MIN)
            .execute();
        nb.first().map(|n| (n.distance.sqrt(), n.item as usize))
    };
    let consensus = |sim: &Similarity| -> (Vec<(usize, usize)>, f64) {
        let mut claims: Vec<(f64, usize, usize)> = targets
            .iter()
            .enumerate()
            .filter_map(|(t, x)| {
                let (d, c) = nearest(&sim.apply(x))?;
                (d <= tol).then_some((d, t, c))
            })
            .collect();
        claims.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut used = vec![false; to.len()];
        let mut pairs = Vec::new();
        let mut ss = 0.0;
        for (d, t, c) in claims {
            if !used[c] {
                used[c] = true;
                pairs.push((t, c));
                ss += d * d;
            }
        }
        (pairs, ss)
    };
    let mut best: (Vec<(usize, usize)>, f64) = (Vec::new(), f64::INFINITY);
    // Only a consensus that pairs every point of the smaller set ends the search: on a
    // periodic field (a dot grid) an alignment shifted by one row pairs nearly as many.
    let enough = targets.len().min(to.len());
    'seeds: for (v, ratios) in &from_tri {
        let lo = to_tri.partition_point(|t| t.1[0] < ratios[0] * (1.0 - RATIO_TOLERANCE));
        for (w, r2) in to_tri[lo..]
            .iter()
            .take_while(|t| t.1[0] <= ratios[0] * (1.0 + RATIO_TOLERANCE))
        {
            if (r2[1] / ratios[1] - 1.0).abs() > RATIO_TOLERANCE {
                continue;
            }
            let a: Vec<Vector3<f64>> = v.iter().map(|&i| targets[i]).collect();
            let b: Vec<Vector3<f64>> = w.iter().map(|&i| to[i]).collect();
            let Some(sim) = similarity_from_points(&a, &b) else {
                continue;
            };
            let (pairs, ss) = consensus(&sim);
            if pairs.len() > best.0.len() || (pairs.len() == best.0.len() && ss < best.1) {
                best = (pairs, ss);
                if best.0.len() >= enough {
                    break 'seeds;
                }
            }
        }
    }
    // Refine on the whole consensus (a triangle's similarity carries its three points' noise).
    for _ in 0..3 {
        if best.0.len() < 3 {
            break;
        }
        let a: Vec<Vector3<f64>> = best.0.iter().map(|&(t, _)| targets[t]).collect();
        let b: Vec<Vector3<f64>> = best.0.iter().map(|&(_, c)| to[c]).collect();
        let Some(sim) = similarity_from_points(&a, &b) else {
            break;
        };
        let next = consensus(&sim);
        if next.0.len() < best.0.len() {
            break;
        }
        best = next;
    }
    best.0.sort_unstable();
    best.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;
    use rand::{Rng, SeedableRng};

    fn corner(n: usize, rng: &mut rand_chacha::ChaCha8Rng) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|k| match k % 3 {
                0 => Vector3::new(rng.random_range(0.0..2.0), rng.random_range(0.0..2.0), 0.0),
                1 => Vector3::new(0.0, rng.random_range(0.0..2.0), rng.random_range(0.0..2.0)),
                _ => Vector3::new(rng.random_range(0.0..2.0), 0.0, rng.random_range(0.0..2.0)),
            })
            .collect()
    }

    /// Shuffled check points in a survey frame (another scale, rotation, a large offset), with
    /// noise and two points the network does not have: every true pair found, the similarity
    /// and the RMS as constructed.
    #[test]
    fn shuffled_points_in_another_frame_are_associated_and_compared() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let truth = corner(120, &mut rng);
        let (s, q, t) = (
            0.37,
            UnitQuaternion::from_euler_angles(0.4, -1.2, 2.0),
            Vector3::new(-3.0, 7.0, 1.5),
        );
        // The network in an SfM frame: x_sfm = (q⁻¹ (x − t)) / s, with 1 mm of noise.
        let targets: Vec<Vector3<f64>> = truth
            .iter()
            .map(|x| {
                let noisy = x + Vector3::new(
                    rng.random_range(-1e-3..1e-3),
                    rng.random_range(-1e-3..1e-3),
                    rng.random_range(-1e-3..1e-3),
                );
                q.inverse() * (noisy - t) / s
            })
            .collect();
        let offset = Vector3::new(500_000.0, 5_600_000.0, 100.0);
        let mut check: Vec<(String, Point3<f64>)> = truth
            .iter()
            .enumerate()
            .skip(1)
            .map(|(k, x)| (format!("P{k}"), Point3::from(x + offset)))
            .collect();
        check.push((
            "X1".into(),
            Point3::from(Vector3::new(5.0, 5.0, 5.0) + offset),
        ));
        check.reverse();
        let report = check_points(&targets, None, &check, 0.0).unwrap();
        assert_eq!(report.points.len(), 119);
        assert_eq!(report.unassociated, vec!["X1".to_string()]);
        for p in &report.points {
            assert_eq!(p.id, format!("P{}", p.target));
        }
        assert!(
            (report.scale * (1.0 / s) - 1.0).abs() < 1e-3,
            "{}",
            report.scale
        );
        // Uniform noise of ±1 mm per axis: RMS distance 1 mm (√3 × 1/√3 mm).
        assert!(
            report.rms_m > 0.8e-3 && report.rms_m < 1.05e-3,
            "{}",
            report.rms_m
        );
        assert!(report.max_m < 1.8e-3 && report.median_m < report.max_m);
    }

    /// A flat dot grid (8 × 10 at 25 mm, BoofCV's regular target) is periodic: a similarity
    /// shifted by one row pairs 72 of its 80 dots as well as the true one pairs 80. The
    /// association must take the whole grid, not the first alignment that pairs nine tenths,
    /// also with targets off the grid in the network.
    #[test]
    fn periodic_grid_is_associated_whole_not_shifted_by_a_row() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let grid: Vec<Vector3<f64>> = (0..80)
            .map(|k| Vector3::new(f64::from(k % 8) * 0.025, f64::from(k / 8) * 0.025, 0.0))
            .collect();
        let q = UnitQuaternion::from_euler_angles(0.3, 0.2, -0.7);
        let mut targets: Vec<Vector3<f64>> = grid
            .iter()
            .map(|x| {
                let noisy = x + Vector3::new(
                    rng.random_range(-2e-4..2e-4),
                    rng.random_range(-2e-4..2e-4),
                    rng.random_range(-2e-4..2e-4),
                );
                q * noisy * 3.1
            })
            .collect();
        // Two targets off the grid (a pebble, a screw head), as on the real video.
        targets.push(q * Vector3::new(0.6, -0.3, -0.4) * 3.1);
        targets.push(q * Vector3::new(0.1, 0.2, 0.0) * 3.1);
        let check: Vec<(String, Point3<f64>)> = grid
            .iter()
            .enumerate()
            .map(|(k, x)| (k.to_string(), Point3::from(*x)))
            .collect();
        let report = check_points(&targets, None, &check, 0.0).unwrap();
        assert!(report.unassociated.is_empty(), "{:?}", report.unassociated);
        assert_eq!(report.points.len(), 80);
        // The residuals are the noise (±0.2 mm uniform per axis: 0.2 mm RMS distance).
        assert!(report.rms_m < 0.25e-3, "{}", report.rms_m);
    }

    #[test]
    fn too_few_or_foreign_points_are_refused() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
        let targets = corner(30, &mut rng);
        let three: Vec<(String, Point3<f64>)> = targets[..3]
            .iter()
            .enumerate()
            .map(|(k, x)| (k.to_string(), Point3::from(*x)))
            .collect();
        assert_eq!(
            check_points(&targets, None, &three, 0.0),
            Err(CheckPointError::TooFew { found: 3 })
        );
        let foreign: Vec<(String, Point3<f64>)> = (0..20)
            .map(|k| {
                let k = f64::from(k);
                (
                    k.to_string(),
                    Point3::new(k * 0.31, (k * 1.7).sin(), k * k * 0.01),
                )
            })
            .collect();
        let err = check_points(&targets, None, &foreign, 0.0).unwrap_err();
        assert!(
            matches!(err, CheckPointError::NoAssociation { .. }),
            "{err}"
        );
    }
}
