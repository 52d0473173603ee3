//! The fundamental matrix by least median of squares (paper Algorithm 1 step 2; docs/math.md
//! §4.1–4.2): normalised 7- or 8-point samples (Hartley 1997) drawn from distinct buckets
//! (Zhang 1998), scored by the median squared symmetric epipolar distance; inliers within 2.5
//! robust σ; then a linear least-squares fit on the inliers and a nonlinear refinement of the
//! Sampson error over the 7 degrees of freedom of F (orthonormal representation, Bartoli &
//! Sturm 2004), inliers re-evaluated once.

use nalgebra::{DMatrix, Matrix3, SMatrix, SVector, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::{BucketSampler, CHI2_MEDIAN_1DOF, Estimator, LmedsConfig, lmeds, lower_median};
use crate::geometry::epipolar::{sampson_squared, symmetric_distance_squared};

/// Minimal solver used inside LMedS.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MinimalSolver {
    /// Seven points, up to three solutions (fewer samples needed).
    #[default]
    SevenPoint,
    /// Eight points, linear, rank 2 enforced.
    EightPoint,
}

/// Options.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FundamentalConfig {
    /// Minimal solver, default the 7-point method.
    pub solver: MinimalSolver,
    /// LMedS options.
    pub lmeds: LmedsConfig,
    /// Buckets per side for the sampler, default 8 (Zhang's 8 × 8).
    pub buckets: usize,
    /// Fewest correspondences, default 15.
    pub min_points: usize,
    /// Refine on the inliers, default true.
    pub refine: bool,
    /// LMedS scores its samples on at most this many correspondences (an evenly strided
    /// subset; the median of 300 residuals is within a few per cent of the full one), default
    /// 300; the inliers, the refinement and σ_ij use all of them. 0: no limit.
    pub max_scored: usize,
}

impl Default for FundamentalConfig {
    fn default() -> Self {
        FundamentalConfig {
            solver: MinimalSolver::SevenPoint,
            lmeds: LmedsConfig::default(),
            buckets: 8,
            min_points: 15,
            refine: true,
            max_scored: 300,
        }
    }
}

/// A robust fundamental matrix.
#[derive(Clone, Debug)]
pub struct FundamentalEstimate {
    /// `F` with `x2ᵀ F x1 = 0`, unit Frobenius norm.
    pub f: Matrix3<f64>,
    /// Inlier flags per correspondence.
    pub inliers: Vec<bool>,
    /// Robust σ of LMedS (of the symmetric distance).
    pub lmeds_sigma: f64,
    /// σ_ij of paper eq. 2: the standard deviation of the symmetric epipolar distance `D` over
    /// the inliers, estimated robustly as `sqrt(median(D²) / 0.4549)` (an inlier's D² is close
    /// to a scaled χ²(1), whose median is 0.4549), so that `D ≤ σ_ij·√χ²₀.₉₇₅,₂` keeps 99.3 %
    /// of true pairs (math §4.2).
    pub sigma: f64,
    /// RMS of D over the inliers.
    pub rms: f64,
    /// Samples LMedS drew.
    pub samples: usize,
}

/// Hartley's normalisation: centroid to the origin, mean distance √2.
fn normalizer(points: &[Vector2<f64>]) -> Matrix3<f64> {
    let n = points.len().max(1) as f64;
    let c = points.iter().fold(Vector2::zeros(), |a, p| a + p) / n;
    let d = points.iter().map(|p| (p - c).norm()).sum::<f64>() / n;
    let s = if d > 0.0 {
        std::f64::consts::SQRT_2 / d
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0)
}

fn apply(t: &Matrix3<f64>, p: &Vector2<f64>) -> Vector2<f64> {
    let h = t * Vector3::new(p.x, p.y, 1.0);
    Vector2::new(h.x / h.z, h.y / h.z)
}

/// Rows `x2ᵀ F x1 = 0` of the linear system in the 9 entries of F (row-major).
fn design(p1: &[Vector2<f64>], p2: &[Vector2<f64>], idx: &[usize]) -> DMatrix<f64> {
    let rows = idx.len().max(9);
    let mut a = DMatrix::zeros(rows, 9);
    for (r, &i) in idx.iter().enumerate() {
        let (x1, x2) = (p1[i], p2[i]);
        let row = [
            x2.x * x1.x,
            x2.x * x1.y,
            x2.x,
            x2.y * x1.x,
            x2.y * x1.y,
            x2.y,
            x1.x,
            x1.y,
            1.0,
        ];
        for (c, v) in row.into_iter().enumerate() {
            a[(r, c)] = v;
        }
    }
    a
}

/// The right singular vectors of `a` for its smallest singular values (columns of V), at most
/// `k`.
fn null_vectors(a: &DMatrix<f64>, k: usize) -> Vec<SVector<f64, 9>> {
    let svd = a.clone().svd(false, true);
    let Some(v_t) = svd.v_t else {
        return Vec::new();
    };
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&x, &y| svd.singular_values[x].total_cmp(&svd.singular_values[y]));
    order
        .iter()
        .take(k)
        .map(|&r| SVector::<f64, 9>::from_iterator(v_t.row(r).iter().copied()))
        .collect()
}

fn to_matrix(v: &SVector<f64, 9>) -> Matrix3<f64> {
    Matrix3::new(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8])
}

/// Sets the smallest singular value to zero.
fn rank2(f: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = f.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return *f;
    };
    let mut s = svd.singular_values;
    let (k, _) = s.argmin();
    s[k] = 0.0;
    u * Matrix3::from_diagonal(&s) * v_t
}

fn unit(f: Matrix3<f64>) -> Option<Matrix3<f64>> {
    let n = f.norm();
    (n > 0.0 && n.is_finite()).then(|| f / n)
}

/// Real roots of `a x³ + b x² + c x + d`.
fn cubic_roots(a: f64, b: f64, c: f64, d: f64) -> Vec<f64> {
    if a.abs() < 1e-14 * (b.abs() + c.abs() + d.abs()).max(1e-300) {
        // Quadratic.
        if b.abs() < 1e-300 {
            return if c.abs() > 1e-300 {
                vec![-d / c]
            } else {
                vec![]
            };
        }
        let disc = c * c - 4.0 * b * d;
        if disc < 0.0 {
            return vec![];
        }
        let s = disc.sqrt();
        return vec![(-c + s) / (2.0 * b), (-c - s) / (2.0 * b)];
    }
    let (b, c, d) = (b / a, c / a, d / a);
    let q = (3.0 * c - b * b) / 9.0;
    let r = (9.0 * b * c - 27.0 * d - 2.0 * b * b * b) / 54.0;
    let disc = q * q * q + r * r;
    let shift = -b / 3.0;
    if disc > 0.0 {
        let s = (r + disc.sqrt()).cbrt();
        let t = (r - disc.sqrt()).cbrt();
        vec![shift + s + t]
    } else {
        let theta = if q < 0.0 {
            (r / (-q * q * q).sqrt()).clamp(-1.0, 1.0).acos()
        } else {
            0.0
        };
        let m = 2.0 * (-q).max(0.0).sqrt();
        (0..3)
            .map(|k| shift + m * ((theta + 2.0 * std::f64::consts::PI * f64::from(k)) / 3.0).cos())
            .collect()
    }
}

/// The normalised 8-point method on the points `idx` (at least 8): linear least squares, rank 2
/// enforced, denormalised.
#[must_use]
pub fn eight_point(
    p1: &[Vector2<f64>],
    p2: &[Vector2<f64>],
    idx: &[usize],
) -> Option<Matrix3<f64>> {
    if idx.len() < 8 {
        return None;
    }
    let sub1: Vec<_> = idx.iter().map(|&i| p1[i]).collect();
    let sub2: Vec<_> = idx.iter().map(|&i| p2[i]).collect();
    let (t1, t2) = (normalizer(&sub1), normalizer(&sub2));
    let n1: Vec<_> = sub1.iter().map(|p| apply(&t1, p)).collect();
    let n2: Vec<_> = sub2.iter().map(|p| apply(&t2, p)).collect();
    let all: Vec<usize> = (0..idx.len()).collect();
    let v = null_vectors(&design(&n1, &n2, &all), 1);
    let f = rank2(&to_matrix(v.first()?));
    unit(t2.transpose() * f * t1)
}

/// The normalised 7-point method: the two-dimensional null space `F1, F2` and the real roots α
/// of `det(α F1 + (1 − α) F2) = 0`; up to three solutions.
#[must_use]
pub fn seven_point(p1: &[Vector2<f64>], p2: &[Vector2<f64>], idx: &[usize]) -> Vec<Matrix3<f64>> {
    if idx.len() != 7 {
        return Vec::new();
    }
    let sub1: Vec<_> = idx.iter().map(|&i| p1[i]).collect();
    let sub2: Vec<_> = idx.iter().map(|&i| p2[i]).collect();
    let (t1, t2) = (normalizer(&sub1), normalizer(&sub2));
    let n1: Vec<_> = sub1.iter().map(|p| apply(&t1, p)).collect();
    let n2: Vec<_> = sub2.iter().map(|p| apply(&t2, p)).collect();
    let all: Vec<usize> = (0..7).collect();
    let v = null_vectors(&design(&n1, &n2, &all), 2);
    if v.len() < 2 {
        return Vec::new();
    }
    let (f1, f2) = (to_matrix(&v[0]), to_matrix(&v[1]));
    let g = |a: f64| (f1 * a + f2 * (1.0 - a)).determinant();
    // Cubic through four evaluations: g(α) = c3 α³ + c2 α² + c1 α + c0.
    let (g0, g1, gm, g2) = (g(0.0), g(1.0), g(-1.0), g(2.0));
    let c0 = g0;
    let c2 = (g1 + gm) / 2.0 - c0;
    let c3 = (g2 - 2.0 * g1 + c0 - 2.0 * c2) / 6.0;
    let c1 = g1 - c0 - c2 - c3;
    cubic_roots(c3, c2, c1, c0)
        .into_iter()
        .filter_map(|a| unit(t2.transpose() * (f1 * a + f2 * (1.0 - a)) * t1))
        .collect()
}

/// The estimator LMedS works on.
struct FundamentalProblem<'a> {
    p1: &'a [Vector2<f64>],
    p2: &'a [Vector2<f64>],
    solver: MinimalSolver,
}

impl Estimator for FundamentalProblem<'_> {
    type Model = Matrix3<f64>;
    const SAMPLE_SIZE: usize = 7;
    fn len(&self) -> usize {
        self.p1.len()
    }
    fn fit(&self, sample: &[usize]) -> Vec<Matrix3<f64>> {
        match self.solver {
            MinimalSolver::SevenPoint => seven_point(self.p1, self.p2, sample),
            MinimalSolver::EightPoint => Vec::new(),
        }
    }
    fn residual_squared(&self, f: &Matrix3<f64>, i: usize) -> f64 {
        symmetric_distance_squared(f, &self.p1[i], &self.p2[i])
    }
}

/// The 8-point variant (a separate type: the sample size is a constant of the estimator).
struct EightPointProblem<'a>(FundamentalProblem<'a>);

impl Estimator for EightPointProblem<'_> {
    type Model = Matrix3<f64>;
    const SAMPLE_SIZE: usize = 8;
    fn len(&self) -> usize {
        self.0.p1.len()
    }
    fn fit(&self, sample: &[usize]) -> Vec<Matrix3<f64>> {
        eight_point(self.0.p1, self.0.p2, sample)
            .into_iter()
            .collect()
    }
    fn residual_squared(&self, f: &Matrix3<f64>, i: usize) -> f64 {
        self.0.residual_squared(f, i)
    }
}

/// Levenberg–Marquardt on the Sampson errors of the inliers over F's 7 degrees of freedom:
/// `F = U diag(1, s, 0) Vᵀ`, `U ← U exp([δu]×)`, `V ← V exp([δv]×)`, `s ← s + δs`.
fn refine_sampson(
    f: &Matrix3<f64>,
    p1: &[Vector2<f64>],
    p2: &[Vector2<f64>],
    idx: &[usize],
) -> Matrix3<f64> {
    let svd = f.svd(true, true);
    let (Some(mut u), Some(v_t)) = (svd.u, svd.v_t) else {
        return *f;
    };
    let mut v = v_t.transpose();
    let sv = svd.singular_values;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| sv[b].total_cmp(&sv[a]));
    let perm = |m: &Matrix3<f64>| {
        Matrix3::from_columns(&[
            m.column(order[0]).into_owned(),
            m.column(order[1]).into_owned(),
            m.column(order[2]).into_owned(),
        ])
    };
    u = perm(&u);
    v = perm(&v);
    if u.determinant() < 0.0 {
        u = -u;
    }
    let mut s = sv[order[1]] / sv[order[0]].max(1e-300);
    let build = |u: &Matrix3<f64>, v: &Matrix3<f64>, s: f64| {
        u * Matrix3::from_diagonal(&Vector3::new(1.0, s, 0.0)) * v.transpose()
    };
    let residuals = |f: &Matrix3<f64>| -> Vec<f64> {
        idx.iter()
            .map(|&i| {
                let e = Vector3::new(p2[i].x, p2[i].y, 1.0)
                    .dot(&(f * Vector3::new(p1[i].x, p1[i].y, 1.0)));
                sampson_squared(f, &p1[i], &p2[i]).sqrt() * e.signum()
            })
            .collect()
    };
    let exp = |w: Vector3<f64>| nalgebra::Rotation3::from_scaled_axis(w).into_inner();
    let cost = |f: &Matrix3<f64>| residuals(f).iter().map(|r| r * r).sum::<f64>();
    let mut current = cost(&build(&u, &v, s));
    let mut lambda = 1e-3;
    for _ in 0..20 {
        let f0 = build(&u, &v, s);
        let r0 = residuals(&f0);
        let mut j = DMatrix::zeros(idx.len(), 7);
        let h = 1e-7;
        for k in 0..7 {
            let mut d = SVector::<f64, 7>::zeros();
            d[k] = h;
            let fk = build(
                &(u * exp(Vector3::new(d[0], d[1], d[2]))),
                &(v * exp(Vector3::new(d[3], d[4], d[5]))),
                s + d[6],
            );
            let rk = residuals(&fk);
            for r in 0..idx.len() {
                j[(r, k)] = (rk[r] - r0[r]) / h;
            }
        }
        let jtj: SMatrix<f64, 7, 7> = SMatrix::from_iterator((j.transpose() * &j).iter().copied());
        let jtr: SVector<f64, 7> = SVector::from_iterator(
            (j.transpose() * DMatrix::from_vec(idx.len(), 1, r0))
                .iter()
                .copied(),
        );
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jtj;
            for k in 0..7 {
                a[(k, k)] += lambda * jtj[(k, k)].max(1e-12);
            }
            let Some(step) = a.try_inverse().map(|inv| -(inv * jtr)) else {
                break;
            };
            let (u2, v2, s2) = (
                u * exp(Vector3::new(step[0], step[1], step[2])),
                v * exp(Vector3::new(step[3], step[4], step[5])),
                s + step[6],
            );
            let c2 = cost(&build(&u2, &v2, s2));
            if c2 < current {
                let done = current - c2 < 1e-12 * current;
                (u, v, s, current) = (u2, v2, s2, c2);
                lambda = (lambda * 0.3).max(1e-12);
                improved = !done;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let f = build(&u, &v, s);
    f / f.norm()
}

/// Estimates F from correspondences `p1[i] ↔ p2[i]` (pixels), robustly.
///
/// `None` with fewer than `min_points` correspondences or when no sample gives a model.
#[must_use]
pub fn estimate_fundamental(
    p1: &[Vector2<f64>],
    p2: &[Vector2<f64>],
    config: &FundamentalConfig,
    seed: u64,
) -> Option<FundamentalEstimate> {
    if p1.len() != p2.len() || p1.len() < config.min_points.max(8) {
        return None;
    }
    let stride = if config.max_scored > 0 {
        p1.len().div_ceil(config.max_scored)
    } else {
        1
    };
    let (s1, s2): (Vec<Vector2<f64>>, Vec<Vector2<f64>>) = if stride > 1 {
        (
            p1.iter().step_by(stride).copied().collect(),
            p2.iter().step_by(stride).copied().collect(),
        )
    } else {
        (p1.to_vec(), p2.to_vec())
    };
    let mut sampler = BucketSampler::new(&s1, config.buckets);
    let problem = FundamentalProblem {
        p1: &s1,
        p2: &s2,
        solver: config.solver,
    };
    let result = match config.solver {
        MinimalSolver::SevenPoint => lmeds(&problem, &mut sampler, &config.lmeds, seed)?,
        MinimalSolver::EightPoint => lmeds(
            &EightPointProblem(problem),
            &mut sampler,
            &config.lmeds,
            seed,
        )?,
    };
    let mut f = result.model;
    let mut cut = (config.lmeds.inlier_sigmas * result.sigma).powi(2);
    let mut inliers: Vec<bool> = (0..p1.len())
        .map(|i| symmetric_distance_squared(&f, &p1[i], &p2[i]) <= cut)
        .collect();
    if config.refine {
        // Refine on the inliers and re-evaluate them, twice: the LMedS model (from a minimal
        // sample, scored on a subset) selects slightly biased inliers the first time.
        for _ in 0..2 {
            let idx: Vec<usize> = (0..p1.len()).filter(|&i| inliers[i]).collect();
            let Some(linear) = eight_point(p1, p2, &idx) else {
                break;
            };
            let refined = refine_sampson(&linear, p1, p2, &idx);
            // Keep the refinement if it lowers the criterion it minimises (the inliers'
            // Sampson error); the linear fit can land in a worse basin on bad data.
            let cost = |f: &Matrix3<f64>| {
                idx.iter()
                    .map(|&i| sampson_squared(f, &p1[i], &p2[i]))
                    .sum::<f64>()
            };
            if cost(&refined) > cost(&f) {
                break;
            }
            f = refined;
            // The robust σ of the refined model over all points, for the cut.
            let mut r: Vec<f64> = (0..p1.len())
                .map(|i| symmetric_distance_squared(&f, &p1[i], &p2[i]))
                .collect();
            let sigma = super::robust_sigma(lower_median(&mut r), p1.len(), 7);
            cut = (config.lmeds.inlier_sigmas * sigma).powi(2);
            inliers = (0..p1.len())
                .map(|i| symmetric_distance_squared(&f, &p1[i], &p2[i]) <= cut)
                .collect();
        }
    }
    let mut d2: Vec<f64> = (0..p1.len())
        .filter(|&i| inliers[i])
        .map(|i| symmetric_distance_squared(&f, &p1[i], &p2[i]))
        .collect();
    let count = d2.len();
    if count < 8 {
        return None;
    }
    let rms = (d2.iter().sum::<f64>() / count as f64).sqrt();
    let sigma = (lower_median(&mut d2) / CHI2_MEDIAN_1DOF).sqrt();
    Some(FundamentalEstimate {
        f,
        inliers,
        lmeds_sigma: result.sigma,
        sigma,
        rms,
        samples: result.samples,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::epipolar::fundamental_from_poses;
    use crate::geometry::triangulation::camera_matrix;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector4};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use crate::robust::standard_normal as gaussian;

    /// True F, points in both images, which are true correspondences.
    type Scene = (
        Matrix3<f64>,
        Vec<Vector2<f64>>,
        Vec<Vector2<f64>>,
        Vec<bool>,
    );

    /// Two views of a 3-D point field, noise σ px, a fraction of gross outliers.
    fn scene(rng: &mut ChaCha8Rng, n: usize, noise: f64, outliers: f64) -> Scene {
        let k = Matrix3::new(1500.0, 0.0, 960.0, 0.0, 1500.0, 540.0, 0.0, 0.0, 1.0);
        let a = Isometry3::from_parts(Translation3::new(0.0, 0.0, 4.0), UnitQuaternion::identity());
        let b = Isometry3::from_parts(
            Translation3::new(-0.8, 0.1, 4.1),
            UnitQuaternion::from_euler_angles(0.02, 0.25, -0.03),
        );
        let (pa, pb) = (camera_matrix(&k, &a), camera_matrix(&k, &b));
        let (mut p1, mut p2, mut good) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..n {
            let x = Vector4::new(
                rng.random_range(-1.5..1.5),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                1.0,
            );
            let (ha, hb) = (pa * x, pb * x);
            let mut u1 = Vector2::new(ha.x / ha.z, ha.y / ha.z)
                + Vector2::new(gaussian(rng), gaussian(rng)) * noise;
            let mut u2 = Vector2::new(hb.x / hb.z, hb.y / hb.z)
                + Vector2::new(gaussian(rng), gaussian(rng)) * noise;
            let bad = rng.random_bool(outliers);
            if bad {
                u1 = Vector2::new(rng.random_range(0.0..1920.0), rng.random_range(0.0..1080.0));
                u2 = Vector2::new(rng.random_range(0.0..1920.0), rng.random_range(0.0..1080.0));
            }
            p1.push(u1);
            p2.push(u2);
            good.push(!bad);
        }
        (
            fundamental_from_poses(&k, &a, &k, &b).unwrap(),
            p1,
            p2,
            good,
        )
    }

    #[test]
    fn minimal_solvers_are_exact_on_exact_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (f, p1, p2, _) = scene(&mut rng, 20, 0.0, 0.0);
        let f = f / f.norm();
        let e8 = eight_point(&p1, &p2, &(0..20).collect::<Vec<_>>()).unwrap();
        assert!((e8 - f).norm() < 1e-8 || (e8 + f).norm() < 1e-8);
        let seven = seven_point(&p1, &p2, &[0, 3, 5, 8, 11, 14, 19]);
        assert!(
            seven
                .iter()
                .any(|m| (m - f).norm() < 1e-7 || (m + f).norm() < 1e-7),
            "{} solutions",
            seven.len()
        );
    }

    #[test]
    fn thirty_percent_outliers_are_found_and_sigma_is_consistent() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for solver in [MinimalSolver::SevenPoint, MinimalSolver::EightPoint] {
            let (_, p1, p2, good) = scene(&mut rng, 300, 0.5, 0.3);
            let cfg = FundamentalConfig {
                solver,
                ..Default::default()
            };
            let est = estimate_fundamental(&p1, &p2, &cfg, 9).unwrap();
            // Every gross outlier (random pixels: far from its epipolar line in practice) is
            // out, and ≥ 97 % of the true correspondences are in (2.5 σ keeps 98.8 % in theory).
            let true_in = (0..300).filter(|&i| good[i] && est.inliers[i]).count();
            let true_total = good.iter().filter(|g| **g).count();
            let false_in = (0..300).filter(|&i| !good[i] && est.inliers[i]).count();
            assert!(
                true_in as f64 >= 0.97 * true_total as f64,
                "{solver:?}: {true_in}/{true_total}"
            );
            assert!(false_in <= 3, "{solver:?}: {false_in} outliers kept");
            // The symmetric distance of an inlier with σ = 0.5 px per coordinate in both images
            // behaves like 2σ·|z| for near-parallel views: σ_ij ≈ 1 px.
            assert!(
                (0.8..1.3).contains(&est.sigma),
                "{solver:?}: σ_ij {}",
                est.sigma
            );
            // The estimate is close to the truth: mean symmetric distance of exact points.
            let (_, q1, q2, _) = scene(&mut ChaCha8Rng::seed_from_u64(77), 50, 0.0, 0.0);
            let err = (0..50)
                .map(|i| symmetric_distance_squared(&est.f, &q1[i], &q2[i]).sqrt())
                .sum::<f64>()
                / 50.0;
            assert!(
                err < 0.5,
                "{solver:?}: mean distance of exact points {err} px"
            );
        }
    }

    #[test]
    fn too_few_points_is_none() {
        let p = vec![Vector2::new(1.0, 2.0); 10];
        assert!(estimate_fundamental(&p, &p, &FundamentalConfig::default(), 1).is_none());
    }

    #[test]
    fn cubic_roots_are_right() {
        let mut r = cubic_roots(1.0, -6.0, 11.0, -6.0);
        r.sort_by(f64::total_cmp);
        assert!(
            (r[0] - 1.0).abs() < 1e-9 && (r[1] - 2.0).abs() < 1e-9 && (r[2] - 3.0).abs() < 1e-9
        );
        assert_eq!(cubic_roots(1.0, 0.0, 1.0, 0.0).len(), 1);
    }
}
