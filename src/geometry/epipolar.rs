//! Epipolar geometry: the fundamental matrix of two cameras, and point-to-epipolar-line
//! distances (docs/math.md §4.2).

use nalgebra::{Matrix3, Matrix3x4, Point3, Vector2, Vector3};

use super::Rigid3;
use super::pose::skew;

/// The fundamental matrix `F` with `x2ᵀ F x1 = 0` for cameras `K1 [R1|t1]`, `K2 [R2|t2]`:
/// `F = K2⁻ᵀ [t]× R K1⁻¹` with `(R, t)` the pose of camera 2 relative to camera 1. `None` if a
/// calibration matrix is singular.
#[must_use]
pub fn fundamental_from_poses(
    k1: &Matrix3<f64>,
    cam1_from_world: &Rigid3,
    k2: &Matrix3<f64>,
    cam2_from_world: &Rigid3,
) -> Option<Matrix3<f64>> {
    let rel = cam2_from_world * cam1_from_world.inverse();
    let r = rel.rotation.to_rotation_matrix();
    let e = skew(&rel.translation.vector) * r.matrix();
    Some(k2.try_inverse()?.transpose() * e * k1.try_inverse()?)
}

/// The fundamental matrix of two general cameras: `F = [e2]× P2 P1⁺` with `e2 = P2·O1`.
#[allow(non_snake_case)]
#[must_use]
pub fn fundamental_from_cameras(
    P1: &Matrix3x4<f64>,
    O1: &Point3<f64>,
    P2: &Matrix3x4<f64>,
) -> Option<Matrix3<f64>> {
    let pinv = P1.pseudo_inverse(1e-15).ok()?;
    let e2 = P2 * nalgebra::Vector4::new(O1.x, O1.y, O1.z, 1.0);
    Some(skew(&e2) * P2 * pinv)
}

/// The four relative poses `(R, t)`, `|t| = 1`, of an essential matrix `E = [t]× R`
/// (Hartley & Zisserman §9.6.2): `R ∈ {U W Vᵀ, U Wᵀ Vᵀ}`, `t = ±u3`, with `det R = +1`.
/// Any matrix is first projected onto the essential manifold by its SVD.
#[must_use]
pub fn decompose_essential(e: &Matrix3<f64>) -> Option<[(Matrix3<f64>, Vector3<f64>); 4]> {
    let svd = e.svd(true, true);
    let (mut u, mut v_t) = (svd.u?, svd.v_t?);
    // Order singular values descending (nalgebra does not promise an order).
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    u = Matrix3::from_columns(&[u.column(idx[0]), u.column(idx[1]), u.column(idx[2])]);
    v_t = Matrix3::from_rows(&[v_t.row(idx[0]), v_t.row(idx[1]), v_t.row(idx[2])]);
    if u.determinant() < 0.0 {
        u = -u;
    }
    if v_t.determinant() < 0.0 {
        v_t = -v_t;
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let (r1, r2) = (u * w * v_t, u * w.transpose() * v_t);
    let t: Vector3<f64> = u.column(2).into_owned();
    if !t.iter().all(|x| x.is_finite()) {
        return None;
    }
    Some([(r1, t), (r1, -t), (r2, t), (r2, -t)])
}

/// Distance of `x2` from the epipolar line `F·x1` (px).
#[must_use]
pub fn distance_to_line(f: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let l = f * Vector3::new(x1.x, x1.y, 1.0);
    let n = (l.x * l.x + l.y * l.y).sqrt();
    if n > 0.0 {
        (l.x * x2.x + l.y * x2.y + l.z).abs() / n
    } else {
        f64::INFINITY
    }
}

/// The symmetric epipolar distance of paper eq. 2:
/// `D = sqrt(d(x2, F x1)² + d(x1, Fᵀ x2)²)`.
#[must_use]
pub fn symmetric_distance(f: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    symmetric_distance_squared(f, x1, x2).sqrt()
}

/// `D²` of [`symmetric_distance`], without the square root.
#[must_use]
pub fn symmetric_distance_squared(f: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let h1 = Vector3::new(x1.x, x1.y, 1.0);
    let h2 = Vector3::new(x2.x, x2.y, 1.0);
    let l2 = f * h1;
    let l1 = f.transpose() * h2;
    let e = h2.dot(&l2);
    let (n2, n1) = (l2.x * l2.x + l2.y * l2.y, l1.x * l1.x + l1.y * l1.y);
    if n1 <= 0.0 || n2 <= 0.0 {
        return f64::INFINITY;
    }
    e * e * (1.0 / n2 + 1.0 / n1)
}

/// The Sampson distance squared: `e² / (|F x1|₁₂² + |Fᵀ x2|₁₂²)`.
#[must_use]
pub fn sampson_squared(f: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>) -> f64 {
    let h1 = Vector3::new(x1.x, x1.y, 1.0);
    let h2 = Vector3::new(x2.x, x2.y, 1.0);
    let l2 = f * h1;
    let l1 = f.transpose() * h2;
    let e = h2.dot(&l2);
    let d = l2.x * l2.x + l2.y * l2.y + l1.x * l1.x + l1.y * l1.y;
    if d > 0.0 { e * e / d } else { f64::INFINITY }
}

#[cfg(test)]
mod essential_tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn one_of_the_four_poses_is_the_true_one() {
        let rel = Isometry3::from_parts(
            Translation3::new(0.6, -0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.1, -0.4, 0.2),
        );
        let r = *rel.rotation.to_rotation_matrix().matrix();
        let t = rel.translation.vector;
        let e = skew(&t) * r * 3.7;
        let four = decompose_essential(&e).unwrap();
        let tn = t.normalize();
        assert!(
            four.iter()
                .any(|(rr, tt)| (rr - r).norm() < 1e-12 && (tt - tn).norm() < 1e-12)
        );
        for (rr, _) in four {
            assert!((rr.determinant() - 1.0).abs() < 1e-12);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::triangulation::camera_matrix;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn both_fundamental_forms_agree_and_project_points_onto_their_lines() {
        let k = Matrix3::new(1000.0, 0.0, 320.0, 0.0, 1000.0, 240.0, 0.0, 0.0, 1.0);
        let a = Isometry3::from_parts(
            Translation3::new(0.1, 0.0, 3.0),
            UnitQuaternion::from_euler_angles(0.0, 0.1, 0.0),
        );
        let b = Isometry3::from_parts(
            Translation3::new(-0.4, 0.1, 3.2),
            UnitQuaternion::from_euler_angles(0.05, -0.2, 0.02),
        );
        let f1 = fundamental_from_poses(&k, &a, &k, &b).unwrap();
        let (pa, pb) = (camera_matrix(&k, &a), camera_matrix(&k, &b));
        let f2 =
            fundamental_from_cameras(&pa, &crate::geometry::pose::camera_centre(&a), &pb).unwrap();
        let (f1, f2) = (f1 / f1.norm(), f2 / f2.norm());
        assert!((f1 - f2).norm() < 1e-9 || (f1 + f2).norm() < 1e-9);
        let x = nalgebra::Vector4::new(0.2, -0.1, 0.5, 1.0);
        let (ha, hb) = (pa * x, pb * x);
        let (xa, xb) = (
            Vector2::new(ha.x / ha.z, ha.y / ha.z),
            Vector2::new(hb.x / hb.z, hb.y / hb.z),
        );
        assert!(symmetric_distance(&f1, &xa, &xb) < 1e-9);
        assert!(sampson_squared(&f1, &xa, &xb) < 1e-18);
        // 1 px off perpendicular to the line: distance 1 in that image.
        let l = f1 * Vector3::new(xa.x, xa.y, 1.0);
        let n = Vector2::new(l.x, l.y).normalize();
        assert!((distance_to_line(&f1, &xa, &(xb + n)) - 1.0).abs() < 1e-9);
    }
}
