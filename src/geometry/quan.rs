//! Quan (1996): the correspondence condition of two image conics and the plane of the 3D conic
//! they image (paper eq. 1; docs/math.md §2), and the centre of the conic cut from one view's
//! cone by that plane (paper Algorithm 3, eqs. 3–5; math §3.4).
//!
//! Symbols (local scope): `C1`, `C2` point conics; `P1`, `P2` 3×4 cameras in the conics' image
//! coordinates; `A = P1ᵀ C1 P1`, `B = P2ᵀ C2 P2` the 4×4 cones; `det(A + λB) = I1 λ⁴ + I2 λ³ +
//! I3 λ² + I4 λ + I5`; `Δ = I3² − 4 I2 I4`.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Point3, Vector2, Vector3, Vector4};

/// The cone `Pᵀ C P` of an image conic, scaled to unit Frobenius norm.
#[allow(non_snake_case)]
#[must_use]
pub fn cone(P: &Matrix3x4<f64>, C: &Matrix3<f64>) -> Matrix4<f64> {
    let a = P.transpose() * C * P;
    let n = a.norm();
    if n > 0.0 { a / n } else { a }
}

/// The coefficients `[I5, I4, I3, I2, I1]` of `det(A + λB)` by exact column expansion: the
/// coefficient of λᵏ is the sum over column subsets S with |S| = k of det(A with the columns in
/// S taken from B) — 16 determinants, real arithmetic only (math §2.2).
#[allow(non_snake_case)]
#[must_use]
pub fn invariants(A: &Matrix4<f64>, B: &Matrix4<f64>) -> [f64; 5] {
    let mut c = [0.0; 5];
    for mask in 0u32..16 {
        let mut m = *A;
        for col in 0..4 {
            if mask & (1 << col) != 0 {
                m.set_column(col, &B.column(col));
            }
        }
        c[mask.count_ones() as usize] += m.determinant();
    }
    c
}

/// Quan's correspondence condition, scale-normalised (math §2.2): with unit-norm cones,
/// `δ = (I3² − 4·I2·I4) / (I3² + 4·|I2·I4|)` ∈ [−1, 1]. Zero for two images of one planar conic;
/// invariant to the scale and sign of the conics and to any projective change of the world
/// frame. Necessary, not sufficient (tangent cones also give 0): rank candidates with it only
/// after the epipolar test.
#[allow(non_snake_case)]
#[must_use]
pub fn delta(
    P1: &Matrix3x4<f64>,
    C1: &Matrix3<f64>,
    P2: &Matrix3x4<f64>,
    C2: &Matrix3<f64>,
) -> f64 {
    delta_of_cones(&cone(P1, C1), &cone(P2, C2))
}

/// δ of [`delta`] for two cones already scaled to unit norm (e.g. computed once per ellipse).
#[allow(non_snake_case)]
#[must_use]
pub fn delta_of_cones(A: &Matrix4<f64>, B: &Matrix4<f64>) -> f64 {
    let [_, i4, i3, i2, _] = invariants(A, B);
    normalized_delta(i2, i3, i4)
}

/// `(I3² − 4·I2·I4) / (I3² + 4·|I2·I4|)`, 1 when both terms vanish.
fn normalized_delta(i2: f64, i3: f64, i4: f64) -> f64 {
    let den = i3 * i3 + 4.0 * (i2 * i4).abs();
    if den > 0.0 {
        (i3 * i3 - 4.0 * i2 * i4) / den
    } else {
        1.0
    }
}

/// The plane of a 3D conic recovered from two views.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConicPlane {
    /// The plane `(n, d)` with `|n| = 1`, `n·X + d = 0`, oriented so that `n·O1 + d > 0` (the
    /// normal points toward the cameras).
    pub plane: Vector4<f64>,
    /// Normalised correspondence condition δ of the pair.
    pub delta: f64,
    /// Rank-2 residual `|μ3| / |μ1|` of `A + λ0 B` (≈ 0 for a true pair, math §2.2).
    pub rank2_residual: f64,
}

/// The plane of the 3D conic seen as `C1` by `P1` and `C2` by `P2` (math §2.3): the rank-2
/// member `A + λ0 B` of the pencil splits into two planes; the true one has both camera
/// centres `O1`, `O2` (Euclidean) on the same side. `None` when the pencil has no real plane
/// pair (the conics do not correspond) or the configuration is degenerate.
#[allow(non_snake_case)]
#[must_use]
pub fn conic_plane(
    P1: &Matrix3x4<f64>,
    C1: &Matrix3<f64>,
    O1: &Point3<f64>,
    P2: &Matrix3x4<f64>,
    C2: &Matrix3<f64>,
    O2: &Point3<f64>,
) -> Option<ConicPlane> {
    let (A, B) = (cone(P1, C1), cone(P2, C2));
    let [_, i4, i3, i2, _] = invariants(&A, &B);
    if i2 == 0.0 || !i2.is_finite() {
        return None;
    }
    let delta = normalized_delta(i2, i3, i4);
    let lambda0 = -i3 / (2.0 * i2);
    let Q0 = A + B * lambda0;
    let eig = Q0.symmetric_eigen();
    let mut order: Vec<usize> = (0..4).collect();
    order.sort_by(|&a, &b| {
        eig.eigenvalues[b]
            .abs()
            .total_cmp(&eig.eigenvalues[a].abs())
    });
    let (m1, m2) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
    let rank2_residual = eig.eigenvalues[order[2]].abs() / m1.abs().max(1e-300);
    // The two largest must have opposite signs, or the planes are complex.
    if m1 * m2 >= 0.0 {
        return None;
    }
    let (mp, up, mn, un) = if m1 > 0.0 {
        (
            m1,
            eig.eigenvectors.column(order[0]),
            m2,
            eig.eigenvectors.column(order[1]),
        )
    } else {
        (
            m2,
            eig.eigenvectors.column(order[1]),
            m1,
            eig.eigenvectors.column(order[0]),
        )
    };
    let p = up * mp.sqrt() + un * (-mn).sqrt();
    let q = up * mp.sqrt() - un * (-mn).sqrt();
    let h1 = Vector4::new(O1.x, O1.y, O1.z, 1.0);
    let h2 = Vector4::new(O2.x, O2.y, O2.z, 1.0);
    let same_side = |pi: &Vector4<f64>| pi.dot(&h1) * pi.dot(&h2) > 0.0;
    let pi = match (same_side(&p), same_side(&q)) {
        (true, false) => p,
        (false, true) => q,
        _ => return None,
    };
    let n = Vector3::new(pi.x, pi.y, pi.z);
    let norm = n.norm();
    if norm < 1e-300 {
        return None;
    }
    let mut plane = pi / norm;
    if plane.dot(&h1) < 0.0 {
        plane = -plane;
    }
    Some(ConicPlane {
        plane,
        delta,
        rank2_residual,
    })
}

/// The conic cut from the cone of view `(P, C)` by `plane`, in an orthonormal basis of the
/// plane (math §3.4): `X = M·w` with `w = (s, t, 1)` and `anchor` projected onto the plane as
/// the origin; returns `M` and the in-plane conic `Mᵀ (Pᵀ C P) M`.
#[allow(non_snake_case)]
fn conic_on_plane(
    P: &Matrix3x4<f64>,
    C: &Matrix3<f64>,
    plane: &Vector4<f64>,
    anchor: &Point3<f64>,
) -> (nalgebra::Matrix4x3<f64>, Matrix3<f64>) {
    let n = Vector3::new(plane.x, plane.y, plane.z);
    let (u, v) = super::plane_basis(&n);
    // Project the anchor onto the plane.
    let x0 = anchor.coords - n * (n.dot(&anchor.coords) + plane.w);
    let mut M = nalgebra::Matrix4x3::zeros();
    M.fixed_view_mut::<3, 1>(0, 0).copy_from(&u);
    M.fixed_view_mut::<3, 1>(0, 1).copy_from(&v);
    M.fixed_view_mut::<3, 1>(0, 2).copy_from(&x0);
    M[(3, 2)] = 1.0;
    let A = P.transpose() * C * P;
    (M, M.transpose() * A * M)
}

/// The conic cut from the cone of view `(P, C)` by `plane`, in the plane (paper Algorithm 3
/// step 4b, math §3.4): the plane is parametrised `X = M·w` with an orthonormal basis and a
/// point `anchor` on it, and the in-plane conic is `Mᵀ A M` for the cone `A = Pᵀ C P`. Built
/// once, it gives the circle's centre ([`ConicOnPlane::centre`]) and its roundness
/// ([`ConicOnPlane::roundness`]).
#[allow(non_snake_case)]
#[derive(Clone, Copy, Debug)]
pub struct ConicOnPlane {
    P: Matrix3x4<f64>,
    M: nalgebra::Matrix4x3<f64>,
    conic: Matrix3<f64>,
}

impl ConicOnPlane {
    /// The cut of view `(P, C)`'s cone by `plane` through (the projection of) `anchor`.
    #[allow(non_snake_case)]
    #[must_use]
    pub fn new(
        P: &Matrix3x4<f64>,
        C: &Matrix3<f64>,
        plane: &Vector4<f64>,
        anchor: &Point3<f64>,
    ) -> Self {
        let (M, conic) = conic_on_plane(P, C, plane, anchor);
        ConicOnPlane { P: *P, M, conic }
    }

    /// The 3D centre of the conic (eqs. 3–5: the pole of the plane's line at infinity) and its
    /// projection through `P`.
    #[allow(non_snake_case)]
    #[must_use]
    pub fn centre(&self) -> Option<(Point3<f64>, Vector2<f64>)> {
        let Cpi = &self.conic;
        // Centre: adj(C_π)·(0, 0, 1)ᵀ (eq. 5 as cofactors).
        let (a, h, g) = (Cpi[(0, 0)], Cpi[(0, 1)], Cpi[(0, 2)]);
        let (b, f) = (Cpi[(1, 1)], Cpi[(1, 2)]);
        let w = Vector3::new(h * f - b * g, g * h - a * f, a * b - h * h);
        if w.z.abs() < 1e-300 {
            return None;
        }
        let w = w / w.z;
        let X = self.M * w;
        let X = Point3::new(X.x, X.y, X.z);
        let x = self.P * Vector4::new(X.x, X.y, X.z, 1.0);
        if x.z.abs() < 1e-300 {
            return None;
        }
        Some((X, Vector2::new(x.x / x.z, x.y / x.z)))
    }

    /// Its minor/major axis ratio in the plane, `sqrt(λ_min / λ_max)` of the quadratic part. 1
    /// for the image of a circle cut by the circle's own plane; a shape that is not a circle —
    /// a blot of paint an ellipse fits in the image — keeps its own ratio in every view.
    /// `None` when the cut is not an ellipse (the plane misses the cone's nappe or is parallel
    /// to a generator).
    #[must_use]
    pub fn roundness(&self) -> Option<f64> {
        let c = &self.conic;
        let q = nalgebra::Matrix2::new(c[(0, 0)], c[(0, 1)], c[(1, 0)], c[(1, 1)]);
        let e = q.symmetric_eigen().eigenvalues;
        let (lo, hi) = (e[0].abs().min(e[1].abs()), e[0].abs().max(e[1].abs()));
        // Both eigenvalues of one sign: an ellipse; the axes go as 1/sqrt(λ).
        (e[0] * e[1] > 0.0 && hi > 0.0 && hi.is_finite()).then(|| (lo / hi).sqrt())
    }
}

/// The 3D centre of the conic cut from the cone of view `(P, C)` by `plane`
/// ([`ConicOnPlane::centre`]) and its projection through `P`.
#[allow(non_snake_case)]
#[must_use]
pub fn conic_centre_on_plane(
    P: &Matrix3x4<f64>,
    C: &Matrix3<f64>,
    plane: &Vector4<f64>,
    anchor: &Point3<f64>,
) -> Option<(Point3<f64>, Vector2<f64>)> {
    ConicOnPlane::new(P, C, plane, anchor).centre()
}

/// Roundness of the conic cut from the cone of view `(P, C)` by `plane`
/// ([`ConicOnPlane::roundness`]).
#[allow(non_snake_case)]
#[must_use]
pub fn roundness_on_plane(
    P: &Matrix3x4<f64>,
    C: &Matrix3<f64>,
    plane: &Vector4<f64>,
    anchor: &Point3<f64>,
) -> Option<f64> {
    ConicOnPlane::new(P, C, plane, anchor).roundness()
}

/// The image of the circle's centre as the pole of the plane's vanishing line with respect to
/// the image conic (math §3.3): `x ≃ C⁻¹·M⁻ᵀ·n` for `P = [M | p4]` and plane normal `n`. Needs
/// only the plane's orientation.
#[allow(non_snake_case)]
#[must_use]
pub fn centre_by_vanishing_line(
    P: &Matrix3x4<f64>,
    C: &Matrix3<f64>,
    normal: &Vector3<f64>,
) -> Option<Vector2<f64>> {
    let M = P.fixed_view::<3, 3>(0, 0).into_owned();
    let l = M.try_inverse()?.transpose() * normal;
    let x = C.try_inverse()? * l;
    (x.z.abs() > 1e-300).then(|| Vector2::new(x.x / x.z, x.y / x.z))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::conic::{Ellipse, conic_of_circle};
    use crate::geometry::pose::camera_centre;
    use crate::geometry::triangulation::camera_matrix;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    struct Setup {
        k: Matrix3<f64>,
        poses: Vec<crate::geometry::Rigid3>,
        centre: Vector3<f64>,
        normal: Vector3<f64>,
        radius: f64,
    }

    fn setup(rng: &mut ChaCha8Rng) -> Setup {
        let k = Matrix3::new(3000.0, 0.0, 1920.0, 0.0, 3000.0, 1080.0, 0.0, 0.0, 1.0);
        let normal = Vector3::new(
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            -1.0,
        )
        .normalize();
        let centre = Vector3::new(
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.2..0.2),
        );
        let poses = (0..3)
            .map(|_| {
                let eye = Vector3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    -rng.random_range(2.0..4.0),
                );
                let rot = UnitQuaternion::face_towards(&(centre - eye), &Vector3::y());
                Isometry3::from_parts(Translation3::from(eye), rot).inverse()
            })
            .collect();
        Setup {
            k,
            poses,
            centre,
            normal,
            radius: 0.04,
        }
    }

    fn conic(s: &Setup, view: usize, centre: &Vector3<f64>) -> Matrix3<f64> {
        conic_of_circle(&s.k, &s.poses[view], centre, &s.normal, s.radius).unwrap()
    }

    #[test]
    fn invariants_match_the_polynomial_at_sample_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let a = Matrix4::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let b = Matrix4::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let c = invariants(&a, &b);
        for lambda in [-2.0, -0.5, 0.3, 1.7] {
            let direct = (a + b * lambda).determinant();
            let poly = c[0]
                + c[1] * lambda
                + c[2] * lambda.powi(2)
                + c[3] * lambda.powi(3)
                + c[4] * lambda.powi(4);
            assert!(
                (direct - poly).abs() < 1e-12 * (1.0 + direct.abs()),
                "{direct} vs {poly}"
            );
        }
    }

    #[test]
    fn delta_is_zero_for_true_pairs_and_clearly_not_for_others() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut wrong = Vec::new();
        for _ in 0..200 {
            let s = setup(&mut rng);
            let p: Vec<_> = s.poses.iter().map(|q| camera_matrix(&s.k, q)).collect();
            let d = delta(
                &p[0],
                &conic(&s, 0, &s.centre),
                &p[1],
                &conic(&s, 1, &s.centre),
            );
            assert!(d.abs() < 1e-8, "true pair δ = {d}");
            // A target 15 cm away on the same plane.
            let other = s.centre + s.normal.cross(&Vector3::x()).normalize() * 0.15;
            wrong.push(
                delta(
                    &p[0],
                    &conic(&s, 0, &s.centre),
                    &p[1],
                    &conic(&s, 1, &other),
                )
                .abs(),
            );
        }
        // Δ = 0 is necessary, not sufficient: a wrong pair can come close to 0 (tangent cones),
        // so only most of them are far from it.
        wrong.sort_by(f64::total_cmp);
        let near_zero = wrong.iter().filter(|d| **d < 1e-6).count();
        assert!(
            wrong[wrong.len() / 2] > 0.05,
            "median wrong |δ| {}",
            wrong[wrong.len() / 2]
        );
        assert!(near_zero <= 2, "{near_zero} wrong pairs with |δ| < 1e-6");
    }

    #[test]
    fn tangent_cones_give_zero_delta_but_not_rank_two() {
        // Move a wrong target along a line until δ changes sign, bisect to δ = 0: the pencil's
        // double member then has rank 3 (math §2.2), unlike a true pair.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut found = 0;
        for _ in 0..50 {
            let s = setup(&mut rng);
            let p: Vec<_> = s.poses.iter().map(|q| camera_matrix(&s.k, q)).collect();
            let o: Vec<_> = s.poses.iter().map(camera_centre).collect();
            let dir = s.normal.cross(&Vector3::x()).normalize();
            let c0 = conic(&s, 0, &s.centre);
            let f = |t: f64| delta(&p[0], &c0, &p[1], &conic(&s, 1, &(s.centre + dir * t)));
            let ts: Vec<f64> = (0..60).map(|k| 0.06 + f64::from(k) * 0.005).collect();
            let Some(w) = ts.windows(2).find(|w| f(w[0]) * f(w[1]) < 0.0) else {
                continue;
            };
            let (mut lo, mut hi) = (w[0], w[1]);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if f(lo) * f(mid) <= 0.0 {
                    hi = mid
                } else {
                    lo = mid
                }
            }
            let t = 0.5 * (lo + hi);
            assert!(f(t).abs() < 1e-6);
            if let Some(sol) = conic_plane(
                &p[0],
                &c0,
                &o[0],
                &p[1],
                &conic(&s, 1, &(s.centre + dir * t)),
                &o[1],
            ) {
                assert!(
                    sol.rank2_residual > 1e-4,
                    "tangent cone rank-2 residual {}",
                    sol.rank2_residual
                );
            }
            found += 1;
        }
        assert!(found > 3, "found {found} tangent configurations");
    }

    #[test]
    fn delta_is_invariant_to_conic_scale_and_projective_frame() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let s = setup(&mut rng);
        let p: Vec<_> = s.poses.iter().map(|q| camera_matrix(&s.k, q)).collect();
        let other = s.centre + Vector3::new(0.1, 0.05, 0.0);
        let (c1, c2) = (conic(&s, 0, &s.centre), conic(&s, 1, &other));
        let d0 = delta(&p[0], &c1, &p[1], &c2);
        let h =
            Matrix4::from_fn(|i, j| if i == j { 1.0 } else { 0.0 } + rng.random_range(-0.2..0.2));
        let d1 = delta(&(p[0] * h), &(c1 * -3.0), &(p[1] * h), &(c2 * 0.01));
        assert!((d0 - d1).abs() < 1e-9, "{d0} vs {d1}");
    }

    #[test]
    fn plane_and_algorithm_3_centre_are_exact() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for _ in 0..100 {
            let s = setup(&mut rng);
            let p: Vec<_> = s.poses.iter().map(|q| camera_matrix(&s.k, q)).collect();
            let o: Vec<_> = s.poses.iter().map(camera_centre).collect();
            let (c0, c1, c2) = (
                conic(&s, 0, &s.centre),
                conic(&s, 1, &s.centre),
                conic(&s, 2, &s.centre),
            );
            let sol = conic_plane(&p[0], &c0, &o[0], &p[1], &c1, &o[1]).unwrap();
            let n = Vector3::new(sol.plane.x, sol.plane.y, sol.plane.z);
            // The true plane, oriented toward the cameras.
            let sign = if s.normal.dot(&(o[0].coords - s.centre)) > 0.0 {
                1.0
            } else {
                -1.0
            };
            assert!(
                (n - s.normal * sign).norm() < 1e-9,
                "normal {n} vs {}",
                s.normal * sign
            );
            assert!((n.dot(&s.centre) + sol.plane.w).abs() < 1e-9);
            assert!(sol.rank2_residual < 1e-9, "{}", sol.rank2_residual);
            // Algorithm 3 in the third view: the projected true centre to 1e-6 px.
            let anchor = Point3::from(s.centre + Vector3::new(0.01, -0.02, 0.0));
            let (x3d, x) = conic_centre_on_plane(&p[2], &c2, &sol.plane, &anchor).unwrap();
            assert!((x3d.coords - s.centre).norm() < 1e-9);
            let truth = p[2] * Vector4::new(s.centre.x, s.centre.y, s.centre.z, 1.0);
            let truth = Vector2::new(truth.x / truth.z, truth.y / truth.z);
            assert!((x - truth).norm() < 1e-6, "{} px", (x - truth).norm());
            // The same by the pole of the vanishing line, and the ellipse centre differs.
            let pole = centre_by_vanishing_line(&p[2], &c2, &n).unwrap();
            assert!((pole - truth).norm() < 1e-6);
            let ell = Ellipse::from_conic(&c2).unwrap();
            assert!((ell.centre() - truth).norm() > 1e-4);
        }
    }

    /// The image conic of the ellipse `(s/a)² + (t/b)² = 1` in the plane through `centre` with
    /// `normal`, axes along an orthonormal basis of the plane.
    fn conic_of_planar_ellipse(s: &Setup, view: usize, semi_axes: (f64, f64)) -> Matrix3<f64> {
        let (u, v) = crate::geometry::plane_basis(&s.normal);
        let m = nalgebra::Matrix4x3::from_columns(&[u.push(0.0), v.push(0.0), s.centre.push(1.0)]);
        let h = camera_matrix(&s.k, &s.poses[view]) * m;
        let on_plane = Matrix3::from_diagonal(&Vector3::new(
            1.0 / (semi_axes.0 * semi_axes.0),
            1.0 / (semi_axes.1 * semi_axes.1),
            -1.0,
        ));
        let h_inv = h.try_inverse().unwrap();
        h_inv.transpose() * on_plane * h_inv
    }

    #[test]
    fn roundness_on_the_plane_is_the_shape_itself() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..50 {
            let s = setup(&mut rng);
            let p: Vec<_> = s.poses.iter().map(|q| camera_matrix(&s.k, q)).collect();
            let o: Vec<_> = s.poses.iter().map(camera_centre).collect();
            let anchor = Point3::from(s.centre);
            // A circle: round in its plane from every view, whatever the image ellipse.
            let c: Vec<_> = (0..3).map(|v| conic(&s, v, &s.centre)).collect();
            let sol = conic_plane(&p[0], &c[0], &o[0], &p[1], &c[1], &o[1]).unwrap();
            for v in 0..3 {
                let q = roundness_on_plane(&p[v], &c[v], &sol.plane, &anchor).unwrap();
                assert!((q - 1.0).abs() < 1e-9, "circle, view {v}: {q}");
            }
            // A planar ellipse of axis ratio 0.8 (Quan's plane needs no circle): 0.8 in every
            // view, though its images' axis ratios differ.
            let e: Vec<_> = (0..3)
                .map(|v| conic_of_planar_ellipse(&s, v, (0.05, 0.04)))
                .collect();
            let sol = conic_plane(&p[0], &e[0], &o[0], &p[1], &e[1], &o[1]).unwrap();
            for v in 0..3 {
                let q = roundness_on_plane(&p[v], &e[v], &sol.plane, &anchor).unwrap();
                assert!((q - 0.8).abs() < 1e-9, "ellipse, view {v}: {q}");
            }
        }
    }
}
