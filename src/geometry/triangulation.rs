//! Multi-view triangulation of one point: linear (DLT, Hartley & Zisserman §12.2) and iterative
//! refinement of the reprojection error (Gauss–Newton), for cameras given as 3×4 matrices
//! acting on the coordinates the observations are in (ideal normalised coordinates for
//! `[R | t]`, undistorted pixels for `K [R | t]`).

use nalgebra::{
    DMatrix, Matrix2x3, Matrix3, Matrix3x4, Point3, SMatrix, Vector2, Vector3, Vector4,
};

use super::Rigid3;

/// One observation of a point: a camera matrix and the observed coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Observation {
    /// The camera `P`, mapping homogeneous world points to homogeneous observations.
    pub p: Matrix3x4<f64>,
    /// The observation (in the coordinates `P` produces).
    pub xy: Vector2<f64>,
}

impl Observation {
    /// An observation in ideal normalised coordinates of a camera at `cam_from_world`.
    #[must_use]
    pub fn normalized(cam_from_world: &Rigid3, xy: Vector2<f64>) -> Self {
        Observation {
            p: camera_matrix(&Matrix3::identity(), cam_from_world),
            xy,
        }
    }
}

/// `P = K [R | t]`.
#[must_use]
pub fn camera_matrix(k: &Matrix3<f64>, cam_from_world: &Rigid3) -> Matrix3x4<f64> {
    let r = cam_from_world.rotation.to_rotation_matrix();
    let mut rt = Matrix3x4::zeros();
    rt.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
    rt.set_column(3, &cam_from_world.translation.vector);
    k * rt
}

/// Depth-like value of a point in front of camera `P` (positive in front, for `P = K[R|t]` with
/// `det(M) > 0`).
#[must_use]
pub fn depth(p: &Matrix3x4<f64>, x: &Point3<f64>) -> f64 {
    let m = p.fixed_view::<3, 3>(0, 0);
    let w = (p * Vector4::new(x.x, x.y, x.z, 1.0)).z;
    w * m.determinant().signum() / m.row(2).norm()
}

/// Linear triangulation: the null vector of the stacked `[x]× P X = 0` rows (two per view), each
/// view's rows scaled by the norm of `P`'s third row, solved by SVD in a conditioned frame
/// (origin at the mean camera centre, unit mean distance) so that world coordinates far from
/// the origin do not ruin the precision. `None` with fewer than two views, a point at infinity,
/// or non-finite input.
#[must_use]
pub fn triangulate_dlt(obs: &[Observation]) -> Option<Point3<f64>> {
    if obs.len() < 2 {
        return None;
    }
    // Conditioning: X = s·X' + m with m the mean camera centre, s the mean distance from it.
    let centres: Vec<Vector3<f64>> = obs
        .iter()
        .filter_map(|o| {
            let m = o.p.fixed_view::<3, 3>(0, 0).into_owned();
            m.try_inverse().map(|mi| -(mi * o.p.column(3)))
        })
        .collect();
    let (m, s) = if centres.len() == obs.len() {
        let m = centres.iter().sum::<Vector3<f64>>() / centres.len() as f64;
        let s = centres.iter().map(|c| (c - m).norm()).sum::<f64>() / centres.len() as f64;
        (m, if s > 0.0 && s.is_finite() { s } else { 1.0 })
    } else {
        (Vector3::zeros(), 1.0)
    };
    let mut t = nalgebra::Matrix4::identity() * s;
    t[(3, 3)] = 1.0;
    t.fixed_view_mut::<3, 1>(0, 3).copy_from(&m);
    let mut a = DMatrix::zeros(2 * obs.len(), 4);
    for (k, o) in obs.iter().enumerate() {
        let p = o.p * t;
        let scale = 1.0 / p.row(2).norm();
        let r0 = (p.row(2) * o.xy.x - p.row(0)) * scale;
        let r1 = (p.row(2) * o.xy.y - p.row(1)) * scale;
        a.row_mut(2 * k).copy_from(&r0);
        a.row_mut(2 * k + 1).copy_from(&r1);
    }
    if !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    let (idx, _) = svd.singular_values.argmin();
    let x = v_t.row(idx).transpose();
    let x = t * Vector4::new(x[0], x[1], x[2], x[3]);
    (x[3].abs() > 1e-12 * x.norm()).then(|| Point3::new(x[0] / x[3], x[1] / x[3], x[2] / x[3]))
}

/// Reprojection of `x` through `P` and its Jacobian with respect to `x`.
fn project_with_jacobian(
    p: &Matrix3x4<f64>,
    x: &Point3<f64>,
) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
    let h = p * Vector4::new(x.x, x.y, x.z, 1.0);
    if h.z.abs() < 1e-300 {
        return None;
    }
    let iz = 1.0 / h.z;
    let uv = Vector2::new(h.x * iz, h.y * iz);
    let m: SMatrix<f64, 3, 3> = p.fixed_view::<3, 3>(0, 0).into_owned();
    let j = Matrix2x3::from_rows(&[
        (m.row(0) - m.row(2) * uv.x) * iz,
        (m.row(1) - m.row(2) * uv.y) * iz,
    ]);
    Some((uv, j))
}

/// Gauss–Newton refinement of the sum of squared reprojection errors from `initial`
/// (at most 20 iterations, stops when the step is below 1e-12 of the point's scale).
#[must_use]
pub fn triangulate_refine(obs: &[Observation], initial: Point3<f64>) -> Option<Point3<f64>> {
    let mut x = initial;
    for _ in 0..20 {
        let mut jtj = Matrix3::zeros();
        let mut jtr = Vector3::zeros();
        for o in obs {
            let (uv, j) = project_with_jacobian(&o.p, &x)?;
            let r = uv - o.xy;
            jtj += j.transpose() * j;
            jtr += j.transpose() * r;
        }
        let step = jtj.try_inverse()? * jtr;
        x -= step;
        if !x.coords.iter().all(|v| v.is_finite()) {
            return None;
        }
        if step.norm() <= 1e-12 * (1.0 + x.coords.norm()) {
            break;
        }
    }
    Some(x)
}

/// DLT followed by Gauss–Newton refinement; `None` when the point is not in front of every
/// camera.
#[must_use]
pub fn triangulate(obs: &[Observation]) -> Option<Point3<f64>> {
    let x = triangulate_refine(obs, triangulate_dlt(obs)?)?;
    obs.iter().all(|o| depth(&o.p, &x) > 0.0).then_some(x)
}

/// The mean reprojection error (RMS over views) of `x`.
#[must_use]
pub fn reprojection_rms(obs: &[Observation], x: &Point3<f64>) -> f64 {
    let sum: f64 = obs
        .iter()
        .map(|o| {
            project_with_jacobian(&o.p, x)
                .map_or(f64::INFINITY, |(uv, _)| (uv - o.xy).norm_squared())
        })
        .sum();
    (sum / obs.len().max(1) as f64).sqrt()
}

/// The covariance of a triangulated point for isotropic image noise of σ = 1 (the cofactor
/// matrix), in the Jacobian form of Beder & Steffen (2006), math §5.1:
/// `Σ = (Σ_k J_kᵀ J_k)⁻¹` with `J_k = ∂π(P_k X)/∂X` at `x`.
#[must_use]
pub fn covariance(obs: &[Observation], x: &Point3<f64>) -> Option<Matrix3<f64>> {
    let mut n = Matrix3::zeros();
    for o in obs {
        let (_, j) = project_with_jacobian(&o.p, x)?;
        n += j.transpose() * j;
    }
    n.try_inverse()
}

/// Roundness `sqrt(λ_min / λ_max)` of a covariance (math §5.3): 1 for a sphere, → 0 for a
/// needle; two rays at equal distances meeting at angle α give `min(sin, cos)(α/2)`.
#[must_use]
pub fn roundness(cov: &Matrix3<f64>) -> f64 {
    let e = cov.symmetric_eigen().eigenvalues;
    let (lo, hi) = (e.min(), e.max());
    if hi > 0.0 && lo >= 0.0 {
        (lo / hi).sqrt()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn looking_at_origin(rng: &mut ChaCha8Rng) -> Rigid3 {
        let centre = Vector3::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
            -4.0,
        );
        let forward = (-centre).normalize();
        let rot = UnitQuaternion::face_towards(&forward, &Vector3::y());
        let world_from_cam = Isometry3::from_parts(Translation3::from(centre), rot);
        world_from_cam.inverse()
    }

    #[test]
    fn exact_observations_give_the_point_to_rounding() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..100 {
            let x = Point3::new(
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
            );
            let obs: Vec<_> = (0..rng.random_range(2..6))
                .map(|_| {
                    let pose = looking_at_origin(&mut rng);
                    let pc = pose * x;
                    Observation::normalized(&pose, Vector2::new(pc.x / pc.z, pc.y / pc.z))
                })
                .collect();
            let t = triangulate(&obs).unwrap();
            assert!(
                (t - x).norm() < 1e-9 * (1.0 + x.coords.norm()),
                "{t} vs {x}"
            );
            assert!(reprojection_rms(&obs, &t) < 1e-12);
        }
    }

    #[test]
    fn refinement_beats_dlt_under_noise_with_unequal_depths() {
        // With noise, the DLT minimises an algebraic error; the refined point has the smaller
        // reprojection error by construction.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let x = Point3::new(0.1, 0.2, 0.3);
        let obs: Vec<_> = (0..5)
            .map(|_| {
                let pose = looking_at_origin(&mut rng);
                let pc = pose * x;
                let noise =
                    Vector2::new(rng.random_range(-1e-3..1e-3), rng.random_range(-1e-3..1e-3));
                Observation::normalized(&pose, Vector2::new(pc.x / pc.z, pc.y / pc.z) + noise)
            })
            .collect();
        let dlt = triangulate_dlt(&obs).unwrap();
        let refined = triangulate(&obs).unwrap();
        assert!(reprojection_rms(&obs, &refined) <= reprojection_rms(&obs, &dlt));
    }

    #[test]
    fn roundness_of_two_symmetric_rays_is_min_sin_cos_of_half_the_angle() {
        // Two cameras at distance 2 from the point, rays meeting at angle α.
        for deg in [10.0f64, 40.0, 90.0, 120.0] {
            let a = deg.to_radians();
            let x = Point3::new(0.0, 0.0, 0.0);
            let obs: Vec<Observation> = [-1.0, 1.0]
                .iter()
                .map(|s| {
                    let eye = Vector3::new(s * 2.0 * (a / 2.0).sin(), 0.0, -2.0 * (a / 2.0).cos());
                    let rot = UnitQuaternion::face_towards(&(-eye), &Vector3::y());
                    let pose = Isometry3::from_parts(Translation3::from(eye), rot).inverse();
                    Observation::normalized(&pose, Vector2::zeros())
                })
                .collect();
            let r = roundness(&covariance(&obs, &x).unwrap());
            let expected = (a / 2.0).sin().min((a / 2.0).cos());
            assert!((r - expected).abs() < 1e-9, "α {deg}°: {r} vs {expected}");
        }
    }

    #[test]
    fn one_view_or_behind_is_none() {
        let pose = Isometry3::identity();
        let o = Observation::normalized(&pose, Vector2::new(0.1, 0.1));
        assert!(triangulate_dlt(&[o]).is_none());
        // Two cameras whose rays meet behind both.
        let a = Observation::normalized(
            &Isometry3::translation(0.5, 0.0, 0.0),
            Vector2::new(-0.1, 0.0),
        );
        let b = Observation::normalized(
            &Isometry3::translation(-0.5, 0.0, 0.0),
            Vector2::new(0.1, 0.0),
        );
        assert!(triangulate(&[a, b]).is_none());
    }
}
