//! The SfM stand-in's own bundle adjustment, written for the simulator and independent of
//! `crate::adjust` (which it helps to judge): what an SfM program does with its features after
//! registration — COLMAP's global bundle adjustment of poses, points and one SIMPLE_RADIAL
//! camera (`f` and `k`, principal point fixed at the image centre, as COLMAP's default
//! `ba_refine_principal_point = false`), Cauchy loss of scale 1 px, then the observations with
//! a reprojection error above 4 px removed (COLMAP's `filter_max_reproj_error`) and the
//! adjustment repeated. Its poses therefore absorb the errors of its camera, as COLMAP's do.
//!
//! Levenberg–Marquardt on the reduced camera system (points eliminated by their 3×3 blocks,
//! Triggs et al., *Bundle Adjustment — A Modern Synthesis*, §6.1); the 7-dof gauge is left to
//! the damping.

use nalgebra::{DMatrix, DVector, Matrix2x3, Matrix3, Matrix3x6, Point3, Vector2, Vector3};

use crate::geometry::Rigid3;

/// One observation: frame, point, measured pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BundleObservation {
    /// Frame index.
    pub frame: usize,
    /// Point index.
    pub point: usize,
    /// Measured pixel.
    pub uv: Vector2<f64>,
}

/// A SIMPLE_RADIAL camera: `u = f·(1 + k·r²)·x/z + cx`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimpleRadial {
    /// Focal length (px).
    pub f: f64,
    /// Principal point (px, COLMAP's convention: the first pixel's corner at 0).
    pub cx: f64,
    /// Principal point (px).
    pub cy: f64,
    /// Radial coefficient.
    pub k: f64,
}

/// A pixel with its Jacobians by the camera-frame point and by `(f, k)`.
type Projected = (Vector2<f64>, Matrix2x3<f64>, [Vector2<f64>; 2]);

impl SimpleRadial {
    /// The pixel of a camera-frame point, with its Jacobians by the point and by `(f, k)`.
    fn project(&self, p: &Vector3<f64>) -> Option<Projected> {
        if p.z <= 1e-9 {
            return None;
        }
        let m = Vector2::new(p.x / p.z, p.y / p.z);
        let r2 = m.norm_squared();
        let d = 1.0 + self.k * r2;
        let uv = Vector2::new(self.f * d * m.x + self.cx, self.f * d * m.y + self.cy);
        let dm = Matrix2x3::new(
            1.0 / p.z,
            0.0,
            -p.x / (p.z * p.z),
            0.0,
            1.0 / p.z,
            -p.y / (p.z * p.z),
        );
        let duv_dm =
            (nalgebra::Matrix2::identity() * d + m * m.transpose() * (2.0 * self.k)) * self.f;
        Some((uv, duv_dm * dm, [m * d, m * (self.f * r2)]))
    }
}

/// Cauchy weight `1 / (1 + (r/s)²)` (IRLS form of ρ = s²·ln(1 + (r/s)²)).
fn cauchy_weight(r2: f64, s: f64) -> f64 {
    1.0 / (1.0 + r2 / (s * s))
}

/// The adjustable state.
struct State {
    camera: SimpleRadial,
    poses: Vec<Rigid3>,
    points: Vec<Point3<f64>>,
}

impl State {
    fn cost(&self, obs: &[BundleObservation], s: f64) -> f64 {
        obs.iter()
            .map(|o| {
                let p = self.poses[o.frame] * self.points[o.point];
                self.camera.project(&p.coords).map_or(1e6, |(uv, _, _)| {
                    let r2 = (uv - o.uv).norm_squared();
                    s * s * (r2 / (s * s)).ln_1p()
                })
            })
            .sum()
    }
}

/// Adjusts `poses`, `points` and the camera's `f`, `k` to `observations` (robust LM). Returns
/// the final RMS reprojection error of the observations (px).
///
/// Kept whole (one function over 150 lines): one Levenberg–Marquardt loop (normal equations,
/// damping, step test) of the stand-in SfM, the simulator's own and independent of
/// [`crate::adjust`].
pub fn adjust(
    camera: &mut SimpleRadial,
    poses: &mut [Rigid3],
    points: &mut [Point3<f64>],
    observations: &[BundleObservation],
    iterations: usize,
) -> f64 {
    let loss_scale = 1.0;
    let mut state = State {
        camera: *camera,
        poses: poses.to_vec(),
        points: points.to_vec(),
    };
    let n_cam = 6 * poses.len() + 2;
    let mut by_point: Vec<Vec<usize>> = vec![Vec::new(); points.len()];
    for (k, o) in observations.iter().enumerate() {
        by_point[o.point].push(k);
    }
    let mut lambda = 1e-3;
    let mut cost = state.cost(observations, loss_scale);
    for _ in 0..iterations {
        // Normal equations: camera block A (dense), point blocks C_j, coupling B_j.
        let mut a = DMatrix::<f64>::zeros(n_cam, n_cam);
        let mut g_cam = DVector::<f64>::zeros(n_cam);
        let mut point_blocks = Vec::with_capacity(points.len());
        for (j, list) in by_point.iter().enumerate() {
            let mut c = Matrix3::<f64>::zeros();
            let mut g_pt = Vector3::<f64>::zeros();
            let mut couplings: Vec<(usize, nalgebra::SMatrix<f64, 8, 3>)> = Vec::new();
            for &k in list {
                let o = &observations[k];
                let pose = &state.poses[o.frame];
                let world = state.points[j].coords;
                let rotated = pose.rotation * world;
                let p = rotated + pose.translation.vector;
                let Some((uv, dp, dfk)) = state.camera.project(&p) else {
                    continue;
                };
                let r = uv - o.uv;
                let w = cauchy_weight(r.norm_squared(), loss_scale);
                // Pose: left perturbation of the whole transform, p ← exp(ω)·p + δt.
                let mut dpose = Matrix3x6::<f64>::zeros();
                dpose
                    .fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&(-crate::geometry::pose::skew(&p)));
                dpose
                    .fixed_view_mut::<3, 3>(0, 3)
                    .copy_from(&Matrix3::identity());
                let j_pose = dp * dpose; // 2×6
                let j_point = dp * pose.rotation.to_rotation_matrix().matrix(); // 2×3
                // Local camera Jacobian: 6 pose + f, k.
                let mut j_cam = nalgebra::SMatrix::<f64, 2, 8>::zeros();
                j_cam.fixed_view_mut::<2, 6>(0, 0).copy_from(&j_pose);
                j_cam.set_column(6, &dfk[0]);
                j_cam.set_column(7, &dfk[1]);
                let idx = |l: usize| {
                    if l < 6 {
                        6 * o.frame + l
                    } else {
                        n_cam - 8 + l
                    }
                };
                let jtj = j_cam.transpose() * j_cam * w;
                let jtr = j_cam.transpose() * r * w;
                for x in 0..8 {
                    g_cam[idx(x)] += jtr[x];
                    for y in 0..8 {
                        a[(idx(x), idx(y))] += jtj[(x, y)];
                    }
                }
                c += j_point.transpose() * j_point * w;
                g_pt += j_point.transpose() * r * w;
                couplings.push((o.frame, j_cam.transpose() * j_point * w));
            }
            point_blocks.push((c, g_pt, couplings));
        }
        // Damped solve with the points eliminated; retry with more damping on failure.
        let mut accepted = false;
        for _attempt in 0..10 {
            let mut s = a.clone();
            for d in 0..n_cam {
                s[(d, d)] += lambda * a[(d, d)].max(1e-9);
            }
            let mut rhs = -g_cam.clone();
            let mut inverses = Vec::with_capacity(point_blocks.len());
            for (c, g_pt, couplings) in &point_blocks {
                let mut cd = *c;
                for d in 0..3 {
                    cd[(d, d)] += lambda * c[(d, d)].max(1e-9);
                }
                let Some(ci) = cd.try_inverse() else {
                    inverses.push(None);
                    continue;
                };
                for (fa, ba) in couplings {
                    let bci = ba * ci; // 8×3
                    let ia = |l: usize| if l < 6 { 6 * fa + l } else { n_cam - 8 + l };
                    for x in 0..8 {
                        rhs[ia(x)] += (bci * g_pt)[x];
                    }
                    for (fb, bb) in couplings {
                        let ib = |l: usize| if l < 6 { 6 * fb + l } else { n_cam - 8 + l };
                        let m = bci * bb.transpose();
                        for x in 0..8 {
                            for y in 0..8 {
                                s[(ia(x), ib(y))] -= m[(x, y)];
                            }
                        }
                    }
                }
                inverses.push(Some(ci));
            }
            let Some(chol) = s.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let dx = chol.solve(&rhs);
            // Back-substitution and the trial state.
            let mut trial = State {
                camera: state.camera,
                poses: state.poses.clone(),
                points: state.points.clone(),
            };
            for (f, pose) in trial.poses.iter_mut().enumerate() {
                let w = Vector3::new(dx[6 * f], dx[6 * f + 1], dx[6 * f + 2]);
                let t = Vector3::new(dx[6 * f + 3], dx[6 * f + 4], dx[6 * f + 5]);
                let rotation = nalgebra::UnitQuaternion::from_scaled_axis(w);
                *pose = Rigid3::from_parts(
                    nalgebra::Translation3::from(rotation * pose.translation.vector + t),
                    rotation * pose.rotation,
                );
            }
            trial.camera.f += dx[n_cam - 2];
            trial.camera.k += dx[n_cam - 1];
            for (j, (c_inv, (_, g_pt, couplings))) in inverses.iter().zip(&point_blocks).enumerate()
            {
                let Some(ci) = c_inv else { continue };
                let mut rhs_pt = -g_pt;
                for (f, b) in couplings {
                    let mut dc = nalgebra::SVector::<f64, 8>::zeros();
                    for l in 0..6 {
                        dc[l] = dx[6 * f + l];
                    }
                    dc[6] = dx[n_cam - 2];
                    dc[7] = dx[n_cam - 1];
                    rhs_pt -= b.transpose() * dc;
                }
                trial.points[j] += ci * rhs_pt;
            }
            let trial_cost = trial.cost(observations, loss_scale);
            if trial_cost < cost {
                let relative = (cost - trial_cost) / cost.max(1e-300);
                state = trial;
                cost = trial_cost;
                lambda = (lambda / 3.0).max(1e-9);
                accepted = relative > 1e-9;
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            break;
        }
    }
    *camera = state.camera;
    poses.copy_from_slice(&state.poses);
    points.copy_from_slice(&state.points);
    let sq: f64 = observations
        .iter()
        .map(|o| reprojection_error(camera, &poses[o.frame], &points[o.point], &o.uv).powi(2))
        .sum();
    (sq / observations.len().max(1) as f64).sqrt()
}

/// The reprojection error of an observation (px); infinite behind the camera.
#[must_use]
pub fn reprojection_error(
    camera: &SimpleRadial,
    pose: &Rigid3,
    point: &Point3<f64>,
    uv: &Vector2<f64>,
) -> f64 {
    camera
        .project(&(pose * point).coords)
        .map_or(f64::INFINITY, |(p, _, _)| (p - uv).norm())
}

/// The similarity `x ↦ s·R·x + t` that maps `from` best onto `to` in the least-squares sense
/// (Umeyama, *Least-squares estimation of transformation parameters between two point
/// patterns*, 1991). `None` for fewer than three points or a degenerate configuration.
#[must_use]
pub fn umeyama(
    from: &[Point3<f64>],
    to: &[Point3<f64>],
) -> Option<(f64, Matrix3<f64>, Vector3<f64>)> {
    let n = from.len();
    if n < 3 || to.len() != n {
        return None;
    }
    let mean = |v: &[Point3<f64>]| v.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n as f64;
    let (mf, mt) = (mean(from), mean(to));
    let mut cov = Matrix3::zeros();
    let mut var = 0.0;
    for (a, b) in from.iter().zip(to) {
        let (da, db) = (a.coords - mf, b.coords - mt);
        cov += db * da.transpose();
        var += da.norm_squared();
    }
    cov /= n as f64;
    var /= n as f64;
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (u.determinant() * v_t.determinant()) < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = u * d * v_t;
    let trace = (0..3)
        .map(|k| svd.singular_values[k] * d[(k, k)])
        .sum::<f64>();
    if var <= 0.0 {
        return None;
    }
    let s = trace / var;
    Some((s, r, mt - r * mf * s))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// Exact observations of a random scene from perturbed poses and a wrong focal length:
    /// the adjustment brings the reprojection error to zero and the camera back to the truth.
    #[test]
    fn perturbed_poses_and_camera_converge_to_exact_observations() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let truth = SimpleRadial {
            f: 800.0,
            cx: 320.0,
            cy: 240.0,
            k: -0.05,
        };
        let points: Vec<Point3<f64>> = (0..300)
            .map(|_| {
                Point3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.5..0.5),
                )
            })
            .collect();
        let poses: Vec<Rigid3> = (0..8)
            .map(|k| {
                let a = 0.08 * f64::from(k) - 0.3;
                let rotation = UnitQuaternion::from_euler_angles(0.1 * a, a, 0.05);
                let centre = Vector3::new(-4.0 * a.sin(), 0.2, -4.0 * a.cos());
                Rigid3::from_parts(Translation3::from(-(rotation * centre)), rotation)
            })
            .collect();
        let mut obs = Vec::new();
        for (f, pose) in poses.iter().enumerate() {
            for (j, p) in points.iter().enumerate() {
                let (uv, _, _) = truth.project(&(pose * p).coords).unwrap();
                obs.push(BundleObservation {
                    frame: f,
                    point: j,
                    uv,
                });
            }
        }
        let mut camera = SimpleRadial {
            f: 820.0,
            k: 0.0,
            ..truth
        };
        let mut est_poses: Vec<Rigid3> = poses
            .iter()
            .map(|p| {
                let w = Vector3::new(rng.random_range(-1.0..1.0), 0.3, -0.2) * 2e-3;
                let rotation = UnitQuaternion::from_scaled_axis(w) * p.rotation;
                Rigid3::from_parts(
                    Translation3::from(p.translation.vector + Vector3::new(0.01, -0.01, 0.005)),
                    rotation,
                )
            })
            .collect();
        let mut est_points = points.clone();
        let rms = adjust(&mut camera, &mut est_poses, &mut est_points, &obs, 50);
        assert!(rms < 1e-6, "rms {rms}");
        assert!(
            (camera.f - 800.0).abs() < 1e-4 && (camera.k + 0.05).abs() < 1e-7,
            "{camera:?}"
        );
        // The points are the truth up to a similarity.
        let (s, r, t) = umeyama(&points, &est_points).unwrap();
        let worst = points
            .iter()
            .zip(&est_points)
            .map(|(a, b)| (r * a.coords * s + t - b.coords).norm())
            .fold(0.0, f64::max);
        assert!(worst < 1e-7, "{worst}");
    }

    #[test]
    fn umeyama_recovers_a_similarity() {
        let from: Vec<Point3<f64>> = (0..10)
            .map(|k| {
                let k = f64::from(k);
                Point3::new(k.sin(), (2.0 * k).cos(), 0.3 * k)
            })
            .collect();
        let r = *UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1)
            .to_rotation_matrix()
            .matrix();
        let t = Vector3::new(1.0, -2.0, 0.5);
        let to: Vec<Point3<f64>> = from
            .iter()
            .map(|p| Point3::from(r * p.coords * 2.5 + t))
            .collect();
        let (s, r2, t2) = umeyama(&from, &to).unwrap();
        assert!((s - 2.5).abs() < 1e-12 && (r2 - r).norm() < 1e-12 && (t2 - t).norm() < 1e-12);
    }
}
