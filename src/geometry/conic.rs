//! Ellipses and point conics (docs/math.md §1): geometric ↔ algebraic conversion, the centre by
//! cofactors, normalisation (unit Frobenius norm, interior negative), the conic of a projected
//! circle, and the direct least-squares ellipse fit (Fitzgibbon et al. 1999 in the numerically
//! stable form of Halíř & Flusser 1998) on normalised coordinates.

use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// An ellipse in pixel coordinates: centre, semi-axes `a ≥ b`, and `theta`, the angle of the
/// major axis from +u toward +v, wrapped to (−π/2, π/2].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ellipse {
    /// Centre u (px).
    pub cx: f64,
    /// Centre v (px).
    pub cy: f64,
    /// Semi-major axis (px).
    pub a: f64,
    /// Semi-minor axis (px).
    pub b: f64,
    /// Angle of the major axis (rad).
    pub theta: f64,
}

/// Wraps an angle to (−π/2, π/2].
#[must_use]
pub fn wrap_half_pi(theta: f64) -> f64 {
    let mut t = theta % std::f64::consts::PI;
    if t <= -std::f64::consts::FRAC_PI_2 {
        t += std::f64::consts::PI;
    } else if t > std::f64::consts::FRAC_PI_2 {
        t -= std::f64::consts::PI;
    }
    t
}

impl Ellipse {
    /// An ellipse with the axes put in order (`a ≥ b`) and `theta` wrapped.
    #[must_use]
    pub fn new(cx: f64, cy: f64, a: f64, b: f64, theta: f64) -> Self {
        if a >= b {
            Ellipse {
                cx,
                cy,
                a,
                b,
                theta: wrap_half_pi(theta),
            }
        } else {
            Ellipse {
                cx,
                cy,
                a: b,
                b: a,
                theta: wrap_half_pi(theta + std::f64::consts::FRAC_PI_2),
            }
        }
    }

    /// The centre.
    #[must_use]
    pub fn centre(&self) -> Vector2<f64> {
        Vector2::new(self.cx, self.cy)
    }

    /// The point at parameter `phi`.
    #[must_use]
    pub fn point(&self, phi: f64) -> Vector2<f64> {
        let (s, c) = self.theta.sin_cos();
        let (x, y) = (self.a * phi.cos(), self.b * phi.sin());
        Vector2::new(self.cx + x * c - y * s, self.cy + x * s + y * c)
    }

    /// The normalised point conic (math §1.1, then [`normalize_conic`]).
    #[must_use]
    pub fn to_conic(&self) -> Matrix3<f64> {
        let (s, c) = self.theta.sin_cos();
        let (a2, b2) = (self.a * self.a, self.b * self.b);
        let ca = a2 * s * s + b2 * c * c;
        let cb = 2.0 * (b2 - a2) * s * c;
        let cc = a2 * c * c + b2 * s * s;
        let cd = -2.0 * ca * self.cx - cb * self.cy;
        let ce = -cb * self.cx - 2.0 * cc * self.cy;
        let cf = ca * self.cx * self.cx + cb * self.cx * self.cy + cc * self.cy * self.cy - a2 * b2;
        normalize_conic(&Matrix3::new(
            ca,
            cb / 2.0,
            cd / 2.0,
            cb / 2.0,
            cc,
            ce / 2.0,
            cd / 2.0,
            ce / 2.0,
            cf,
        ))
    }

    /// The ellipse of a point conic (math §1.2), or `None` if it is not a real ellipse.
    #[must_use]
    pub fn from_conic(conic: &Matrix3<f64>) -> Option<Ellipse> {
        let m = normalize_conic(conic);
        if !m.iter().all(|v| v.is_finite()) {
            return None;
        }
        let (a, b, c) = (m[(0, 0)], 2.0 * m[(0, 1)], m[(1, 1)]);
        let disc = b * b - 4.0 * a * c;
        if disc >= 0.0 {
            return None;
        }
        let centre = conic_centre(&m)?;
        let f0 = (Vector3::new(centre.x, centre.y, 1.0))
            .dot(&(m * Vector3::new(centre.x, centre.y, 1.0)));
        if f0 >= 0.0 {
            return None; // imaginary ellipse
        }
        let s = nalgebra::Matrix2::new(a, b / 2.0, b / 2.0, c);
        let eig = s.symmetric_eigen();
        let (l1, l2) = (eig.eigenvalues[0], eig.eigenvalues[1]);
        if l1 <= 0.0 || l2 <= 0.0 {
            return None;
        }
        // The major axis belongs to the smaller eigenvalue.
        let (lmin, lmax, vmin) = if l1 <= l2 {
            (l1, l2, eig.eigenvectors.column(0).into_owned())
        } else {
            (l2, l1, eig.eigenvectors.column(1).into_owned())
        };
        let semi_major = (-f0 / lmin).sqrt();
        let semi_minor = (-f0 / lmax).sqrt();
        let theta = wrap_half_pi(vmin.y.atan2(vmin.x));
        Some(Ellipse {
            cx: centre.x,
            cy: centre.y,
            a: semi_major,
            b: semi_minor,
            theta,
        })
    }
}

/// Scales a conic to unit Frobenius norm with the interior negative (`A + C > 0`).
#[must_use]
pub fn normalize_conic(c: &Matrix3<f64>) -> Matrix3<f64> {
    let n = c.norm();
    let sign = if c[(0, 0)] + c[(1, 1)] < 0.0 {
        -1.0
    } else {
        1.0
    };
    c * (sign / n)
}

/// The centre of a conic from its cofactors (math §1.3): the pole of the line at infinity;
/// `None` for a parabola.
#[must_use]
pub fn conic_centre(c: &Matrix3<f64>) -> Option<Vector2<f64>> {
    let (a, h, g) = (c[(0, 0)], c[(0, 1)], c[(0, 2)]);
    let (b, f) = (c[(1, 1)], c[(1, 2)]);
    let a13 = h * f - b * g;
    let a23 = g * h - a * f;
    let a33 = a * b - h * h;
    (a33 != 0.0).then(|| Vector2::new(a13 / a33, a23 / a33))
}

/// The image conic of a circle (math §3.2) for a camera with calibration `k` (pixels from ideal
/// normalised coordinates) and pose `(R, t)` (`cam_from_world`): circle centre `centre`, unit
/// normal `normal`, radius `radius`, all in world coordinates. Exact for a distortion-free camera.
#[must_use]
pub fn conic_of_circle(
    k: &Matrix3<f64>,
    cam_from_world: &crate::geometry::Rigid3,
    centre: &Vector3<f64>,
    normal: &Vector3<f64>,
    radius: f64,
) -> Option<Matrix3<f64>> {
    let xc = cam_from_world.rotation * centre + cam_from_world.translation.vector;
    let nc = cam_from_world.rotation * normal;
    let s = nc.dot(&xc);
    let q = Matrix3::identity() * (s * s) - (nc * xc.transpose() + xc * nc.transpose()) * s
        + nc * nc.transpose() * (xc.norm_squared() - radius * radius);
    let kinv = k.try_inverse()?;
    Some(normalize_conic(&(kinv.transpose() * q * kinv)))
}

/// Direct least-squares ellipse fit (Fitzgibbon, Pilu & Fisher 1999; Halíř & Flusser 1998) on
/// coordinates translated to the centroid and scaled to unit RMS distance, so it is invariant to
/// the image size. Always returns an ellipse when one exists for the points; `None` for fewer
/// than 5 points or degenerate configurations.
#[must_use]
pub fn fit_ellipse_direct(points: &[Vector2<f64>]) -> Option<Ellipse> {
    let n = points.len();
    if n < 5 {
        return None;
    }
    let mean = points.iter().fold(Vector2::zeros(), |a, p| a + p) / n as f64;
    let rms = (points
        .iter()
        .map(|p| (p - mean).norm_squared())
        .sum::<f64>()
        / n as f64)
        .sqrt();
    if !(rms > 0.0 && rms.is_finite()) {
        return None;
    }
    let s = 1.0 / rms;
    // Scatter matrices of the quadratic (x², xy, y²) and linear (x, y, 1) parts.
    let mut s1 = Matrix3::zeros();
    let mut s2 = Matrix3::zeros();
    let mut s3 = Matrix3::zeros();
    for p in points {
        let (x, y) = ((p.x - mean.x) * s, (p.y - mean.y) * s);
        let d1 = Vector3::new(x * x, x * y, y * y);
        let d2 = Vector3::new(x, y, 1.0);
        s1 += d1 * d1.transpose();
        s2 += d1 * d2.transpose();
        s3 += d2 * d2.transpose();
    }
    let s3_inv = s3.try_inverse()?;
    let t = -s3_inv * s2.transpose();
    let m = s1 + s2 * t;
    // Premultiply by the inverse of the constraint matrix C1 = [[0,0,2],[0,-1,0],[2,0,0]].
    let m = Matrix3::new(
        m[(2, 0)] / 2.0,
        m[(2, 1)] / 2.0,
        m[(2, 2)] / 2.0,
        -m[(1, 0)],
        -m[(1, 1)],
        -m[(1, 2)],
        m[(0, 0)] / 2.0,
        m[(0, 1)] / 2.0,
        m[(0, 2)] / 2.0,
    );
    let eig = m.complex_eigenvalues();
    // The ellipse is the eigenvector with 4ac − b² > 0; find it by inverse iteration on each
    // real eigenvalue.
    let mut best: Option<Vector3<f64>> = None;
    for k in 0..3 {
        let lambda = eig[k];
        if lambda.im.abs() > 1e-9 * (1.0 + lambda.re.abs()) {
            continue;
        }
        let shifted = m - Matrix3::identity() * lambda.re;
        let svd = shifted.svd(false, true);
        let v_t = svd.v_t?;
        let (idx, _) = svd.singular_values.argmin();
        let v: Vector3<f64> = v_t.row(idx).transpose();
        if 4.0 * v.x * v.z - v.y * v.y > 0.0 {
            best = Some(v);
        }
    }
    let a1 = best?;
    let a2 = t * a1;
    // Conic in normalised coordinates, then back to pixels: x_n = S (x − mean).
    let cn = Matrix3::new(
        a1.x,
        a1.y / 2.0,
        a2.x / 2.0,
        a1.y / 2.0,
        a1.z,
        a2.y / 2.0,
        a2.x / 2.0,
        a2.y / 2.0,
        a2.z,
    );
    let tn = Matrix3::new(s, 0.0, -s * mean.x, 0.0, s, -s * mean.y, 0.0, 0.0, 1.0);
    Ellipse::from_conic(&(tn.transpose() * cn * tn))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_ellipse(rng: &mut ChaCha8Rng) -> Ellipse {
        let a = rng.random_range(5.0..200.0);
        Ellipse::new(
            rng.random_range(0.0..3840.0),
            rng.random_range(0.0..2160.0),
            a,
            a * rng.random_range(0.2..0.999),
            rng.random_range(-3.0..3.0),
        )
    }

    #[track_caller]
    fn assert_same(e: &Ellipse, f: &Ellipse, tol: f64) {
        assert!(
            (e.cx - f.cx).abs() < tol && (e.cy - f.cy).abs() < tol,
            "{e:?} vs {f:?}"
        );
        assert!(
            (e.a - f.a).abs() < tol && (e.b - f.b).abs() < tol,
            "{e:?} vs {f:?}"
        );
        let dt = wrap_half_pi(e.theta - f.theta).abs();
        assert!(dt < 1e-6 || e.a - e.b < 1e-3, "{e:?} vs {f:?}");
    }

    #[test]
    fn ellipse_conic_round_trip() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..1000 {
            let e = random_ellipse(&mut rng);
            let c = e.to_conic();
            assert!((c.norm() - 1.0).abs() < 1e-12);
            assert!(c[(0, 0)] + c[(1, 1)] > 0.0 && c.determinant() < 0.0);
            let back = Ellipse::from_conic(&c).unwrap();
            assert_same(&e, &back, 1e-9 * 4000.0);
            // Points on the ellipse satisfy the conic; the centre is the cofactor centre.
            for k in 0..8 {
                let p = e.point(f64::from(k));
                let h = Vector3::new(p.x, p.y, 1.0);
                let value = h.dot(&(c * h)) / (h.norm_squared());
                assert!(value.abs() < 1e-12, "{value}");
            }
            let centre = conic_centre(&(c * -7.5)).unwrap();
            assert!((centre - e.centre()).norm() < 1e-8);
        }
    }

    #[test]
    fn non_ellipses_are_rejected() {
        // Hyperbola x² − y² = 1 and an imaginary ellipse x² + y² = −1.
        assert!(
            Ellipse::from_conic(&Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0))
                .is_none()
        );
        assert!(
            Ellipse::from_conic(&Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
                .is_none()
        );
    }

    #[test]
    fn direct_fit_is_exact_on_exact_points_including_short_arcs() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..200 {
            let e = random_ellipse(&mut rng);
            let start = rng.random_range(0.0..6.0);
            let span = rng.random_range(1.6..6.3);
            let pts: Vec<_> = (0..60)
                .map(|k| e.point(start + span * f64::from(k) / 59.0))
                .collect();
            let f = fit_ellipse_direct(&pts).unwrap();
            assert_same(&e, &f, 1e-6 * e.a.max(1.0));
        }
        assert!(fit_ellipse_direct(&[Vector2::new(0.0, 0.0); 4]).is_none());
    }

    #[test]
    fn conic_of_circle_contains_the_projected_circle() {
        use nalgebra::{Isometry3, Translation3, UnitQuaternion};
        let k = Matrix3::new(3000.0, 0.0, 1920.0, 0.0, 3000.0, 1080.0, 0.0, 0.0, 1.0);
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 3.0),
            UnitQuaternion::from_euler_angles(0.3, -0.4, 0.1),
        );
        let centre = Vector3::new(0.2, 0.1, 0.3);
        let normal = Vector3::new(0.3, -0.2, -1.0).normalize();
        let u = normal.cross(&Vector3::x()).normalize();
        let v = normal.cross(&u);
        let c = conic_of_circle(&k, &pose, &centre, &normal, 0.04).unwrap();
        for i in 0..36 {
            let phi = f64::from(i) * 10f64.to_radians();
            let p = centre + (u * phi.cos() + v * phi.sin()) * 0.04;
            let pc = pose.rotation * p + pose.translation.vector;
            let uv = k * (pc / pc.z);
            assert!((uv.dot(&(c * uv)) / uv.norm_squared()).abs() < 1e-13);
        }
    }
}
