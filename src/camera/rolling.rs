//! Rolling shutter: the rows of a frame are exposed one after another over the readout time,
//! each at the pose the moving camera has then (Meingast et al. 2005, "Geometric models of
//! rolling-shutter cameras"; Hedborg et al. 2012, "Rolling shutter bundle adjustment"), with
//! the first-order motion of the camera about its pose at the frame time.
//!
//! * Row timing: the sensor row at pixel height `v` (rows of the observed, distorted image,
//!   `0` at the top edge) is exposed at `t = t_frame + Δ + (v / H − ½)·τ`, with `τ` the
//!   readout time, `H` the frame height and `Δ` the offset of the frame from the one whose
//!   pose is adjusted (`0`, or `±1/fps` for a neighbouring video frame); the middle row is at
//!   the frame time.
//! * Motion: a static point at `p₀` in the camera frame at the frame time is, `s` seconds
//!   later, at `p(s) = exp(s·[ω]×)·p₀ + s·ν`, with `ω` (rad/s) and `ν` (world units/s) in the
//!   camera frame (`[ω]× = Ṙ·Rᵀ`, `ν = Ṫ − ω × T` of `cam_from_world = (R, T)`).
//! * Projection: the row that sees the point depends on where it is seen, so the pixel
//!   solves `v = π_v(p(s(v)))` (a contraction: the motion over one row is a tiny fraction of
//!   a row); [`project`] iterates it, [`project_with_jacobians`] differentiates the solution
//!   implicitly.

use nalgebra::{Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};

use super::brown::Intrinsics;
use crate::geometry::pose::skew;

/// A frame's motion about its pose at the frame time (camera frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Motion {
    /// Angular velocity ω (rad/s).
    pub angular: Vector3<f64>,
    /// Linear velocity ν (world units/s).
    pub linear: Vector3<f64>,
}

impl Motion {
    /// From the six adjusted values `[ωx, ωy, ωz, νx, νy, νz]`.
    #[must_use]
    pub fn from_slice(v: &[f64]) -> Self {
        Motion {
            angular: Vector3::new(v[0], v[1], v[2]),
            linear: Vector3::new(v[3], v[4], v[5]),
        }
    }

    /// Where a point at `p0` in the camera frame at the frame time is `s` seconds later.
    #[must_use]
    pub fn point_at(&self, p0: &Vector3<f64>, s: f64) -> Vector3<f64> {
        exp_so3(&(self.angular * s)) * p0 + self.linear * s
    }
}

/// The row timing of a rolling-shutter frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RowTiming {
    /// Readout time τ (s): from the exposure of the top row to that of the bottom row.
    pub readout_s: f64,
    /// Frame height H (px).
    pub height_px: f64,
}

impl RowTiming {
    /// Time (s) of the row at pixel height `v`, from the frame time, for a frame `offset_s`
    /// from the adjusted one.
    #[must_use]
    pub fn time_of_row(&self, v: f64, offset_s: f64) -> f64 {
        offset_s + (v / self.height_px - 0.5) * self.readout_s
    }
}

/// Rotation matrix of the rotation vector `phi` (Rodrigues).
#[must_use]
pub fn exp_so3(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let k = skew(phi);
    let (a, b) = if theta2 < 1e-12 {
        (1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0)
    } else {
        let theta = theta2.sqrt();
        (theta.sin() / theta, (1.0 - theta.cos()) / theta2)
    };
    Matrix3::identity() + k * a + k * k * b
}

/// Left Jacobian of SO(3) at `phi`: `exp([φ + δ]×) ≈ exp([J_l(φ)·δ]×)·exp([φ]×)`.
#[must_use]
pub fn left_jacobian_so3(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let k = skew(phi);
    let (a, b) = if theta2 < 1e-12 {
        (0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0)
    } else {
        let theta = theta2.sqrt();
        (
            (1.0 - theta.cos()) / theta2,
            (theta - theta.sin()) / (theta2 * theta),
        )
    };
    Matrix3::identity() + k * a + k * k * b
}

/// Iterations of the row's fixed point at most; it gains about `H / (motion of a point over
/// the readout, px)` digits per step, so three or four reach the rounding level.
const MAX_ROW_ITERATIONS: usize = 12;

/// The pixel at which a rolling-shutter frame sees the point `p0` (camera frame at the frame
/// time), and the time of its row: `None` where the model is undefined.
#[must_use]
pub fn project(
    intrinsics: &Intrinsics,
    timing: &RowTiming,
    motion: &Motion,
    p0: &Vector3<f64>,
    offset_s: f64,
) -> Option<(Vector2<f64>, f64)> {
    let mut uv = intrinsics.project(&motion.point_at(p0, offset_s))?;
    for _ in 0..MAX_ROW_ITERATIONS {
        let s = timing.time_of_row(uv.y, offset_s);
        let next = intrinsics.project(&motion.point_at(p0, s))?;
        let moved = (next.y - uv.y).abs();
        uv = next;
        if moved <= 1e-10 * (1.0 + uv.y.abs()) {
            break;
        }
    }
    // The time of the row the pixel lies on (it moved by less than the tolerance since the
    // last projection).
    Some((uv, timing.time_of_row(uv.y, offset_s)))
}

/// A rolling-shutter projection with its derivatives.
#[derive(Clone, Copy, Debug)]
pub struct RollingProjection {
    /// The pixel.
    pub uv: Vector2<f64>,
    /// Time of its row (s from the frame time).
    pub time_s: f64,
    /// `∂uv/∂p₀` (2×3).
    pub d_uv_d_p0: Matrix2x3<f64>,
    /// `∂uv/∂(ω, ν)` (2×6).
    pub d_uv_d_motion: SMatrix<f64, 2, 6>,
    /// `∂uv/∂intrinsics`, columns in the order of [`super::Term::ALL`] (2×10).
    pub d_uv_d_intrinsics: SMatrix<f64, 2, 10>,
    /// `∂uv/∂τ` (px/s).
    pub d_uv_d_readout: Vector2<f64>,
}

/// [`project`] with the derivatives of the solved pixel, by implicit differentiation of
/// `v = π_v(p(s(v)))`: with `(b, a) = ∂π/∂p·∂p/∂s` and `k = τ/H`, a parameter θ acting
/// on the pixel by `(e_u, e_v)` at a fixed time and on the time by `σ_θ` gives
/// `dv = (e_v + a·σ_θ)/(1 − a·k)`, `ds = σ_θ + k·dv`, `du = e_u + b·ds`.
#[must_use]
pub fn project_with_jacobians(
    intrinsics: &Intrinsics,
    timing: &RowTiming,
    motion: &Motion,
    p0: &Vector3<f64>,
    offset_s: f64,
) -> Option<RollingProjection> {
    let (_, s) = project(intrinsics, timing, motion, p0, offset_s)?;
    let phi = motion.angular * s;
    let e = exp_so3(&phi);
    let e_p0 = e * p0;
    let q = e_p0 + motion.linear * s;
    let proj = intrinsics.project_with_jacobians(&q)?;
    let jb = proj.d_uv_d_p_cam;
    // ∂p/∂s = ω × (E·p₀) + ν
    let dq_ds = motion.angular.cross(&e_p0) + motion.linear;
    let ba = jb * dq_ds;
    let (b, a) = (ba.x, ba.y);
    let k = timing.readout_s / timing.height_px;
    let denominator = 1.0 - a * k;
    if denominator.is_nan() || denominator.abs() <= 1e-6 {
        return None;
    }
    // One column: explicit (e_u, e_v) and direct time derivative σ.
    let solve = |eu: f64, ev: f64, sigma: f64| {
        let dv = (ev + a * sigma) / denominator;
        let ds = sigma + k * dv;
        Vector2::new(eu + b * ds, dv)
    };
    let explicit_p0 = jb * e;
    let mut d_uv_d_p0 = Matrix2x3::zeros();
    for c in 0..3 {
        d_uv_d_p0.set_column(c, &solve(explicit_p0[(0, c)], explicit_p0[(1, c)], 0.0));
    }
    // ∂p/∂ω = −s·[E·p₀]×·J_l(s·ω), ∂p/∂ν = s·I.
    let dq_domega = -skew(&e_p0) * left_jacobian_so3(&phi) * s;
    let explicit_omega = jb * dq_domega;
    let explicit_nu = jb * s;
    let mut d_uv_d_motion = SMatrix::<f64, 2, 6>::zeros();
    for c in 0..3 {
        d_uv_d_motion.set_column(
            c,
            &solve(explicit_omega[(0, c)], explicit_omega[(1, c)], 0.0),
        );
        d_uv_d_motion.set_column(3 + c, &solve(explicit_nu[(0, c)], explicit_nu[(1, c)], 0.0));
    }
    let mut d_uv_d_intrinsics = SMatrix::<f64, 2, 10>::zeros();
    for c in 0..10 {
        d_uv_d_intrinsics.set_column(
            c,
            &solve(
                proj.d_uv_d_intrinsics[(0, c)],
                proj.d_uv_d_intrinsics[(1, c)],
                0.0,
            ),
        );
    }
    let d_uv_d_readout = solve(0.0, 0.0, proj.uv.y / timing.height_px - 0.5);
    Some(RollingProjection {
        uv: proj.uv,
        time_s: s,
        d_uv_d_p0,
        d_uv_d_motion,
        d_uv_d_intrinsics,
        d_uv_d_readout,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Intrinsics {
        Intrinsics::from_array([
            1500.0, 962.0, 541.0, -0.08, 0.02, 0.0, 2e-4, -1e-4, 0.3, -0.1,
        ])
    }

    fn timing() -> RowTiming {
        RowTiming {
            readout_s: 0.025,
            height_px: 1080.0,
        }
    }

    /// Hand-held motion: 8 °/s about a tilted axis, 0.12 m/s.
    fn motion() -> Motion {
        Motion {
            angular: Vector3::new(0.3, -0.9, 0.4).normalize() * 8f64.to_radians(),
            linear: Vector3::new(0.05, 0.1, -0.04).normalize() * 0.12,
        }
    }

    /// The solved pixel's row is the row whose pose sees the point there: checked against a
    /// brute-force scan of the rows' times, independent of the fixed point.
    #[test]
    fn projection_lies_on_the_row_whose_time_it_carries() {
        let (i, t, m) = (camera(), timing(), motion());
        for p0 in [
            Vector3::new(0.4, -0.3, 2.0),
            Vector3::new(-0.7, 0.35, 1.5),
            Vector3::new(0.0, 0.0, 3.0),
        ] {
            for offset in [0.0, -0.04, 0.04] {
                let (uv, s) = project(&i, &t, &m, &p0, offset).unwrap();
                assert!((s - t.time_of_row(uv.y, offset)).abs() < 1e-12);
                // Brute force: the row v where π_v(p(s(v))) − v changes sign, by bisection
                // on a fine scan.
                let g = |v: f64| {
                    i.project(&m.point_at(&p0, t.time_of_row(v, offset)))
                        .unwrap()
                        .y
                        - v
                };
                let mut lo = 0.0;
                while g(lo) * g(lo + 1.0) > 0.0 {
                    lo += 1.0;
                    assert!(lo < 1080.0);
                }
                let (mut a, mut b) = (lo, lo + 1.0);
                for _ in 0..60 {
                    let mid = 0.5 * (a + b);
                    if g(a) * g(mid) <= 0.0 {
                        b = mid;
                    } else {
                        a = mid;
                    }
                }
                assert!((uv.y - 0.5 * (a + b)).abs() < 1e-8, "{} vs {}", uv.y, a);
                // The same pixel as a global-shutter camera at that row's pose.
                let direct = i.project(&m.point_at(&p0, s)).unwrap();
                assert!((direct - uv).norm() < 1e-8);
            }
        }
    }

    /// Without motion the rows' times change nothing: the global-shutter projection.
    #[test]
    fn without_motion_it_is_the_global_shutter_projection() {
        let (i, t) = (camera(), timing());
        let p0 = Vector3::new(0.4, -0.3, 2.0);
        let (uv, s) = project(&i, &t, &Motion::default(), &p0, 0.0).unwrap();
        assert_eq!(uv, i.project(&p0).unwrap());
        assert!((s - t.time_of_row(uv.y, 0.0)).abs() < 1e-15);
    }

    /// Analytic derivatives against central differences of the solved pixel.
    #[test]
    fn jacobians_match_central_differences() {
        let (i, t, m) = (camera(), timing(), motion());
        let p0 = Vector3::new(0.45, 0.3, 1.8);
        for offset in [0.0, 0.04] {
            let j = project_with_jacobians(&i, &t, &m, &p0, offset).unwrap();
            let at = |i: &Intrinsics, t: &RowTiming, m: &Motion, p: &Vector3<f64>| {
                project(i, t, m, p, offset).unwrap().0
            };
            let close = |num: Vector2<f64>, an: Vector2<f64>, what: &str| {
                assert!(
                    (num - an).norm() < 1e-5 * (1.0 + an.norm()),
                    "{what}: numeric {num:?} analytic {an:?}"
                );
            };
            for c in 0..3 {
                let h = 1e-6;
                let (mut a, mut b) = (p0, p0);
                a[c] += h;
                b[c] -= h;
                let num = (at(&i, &t, &m, &a) - at(&i, &t, &m, &b)) / (2.0 * h);
                close(num, j.d_uv_d_p0.column(c).into(), "p0");
            }
            for c in 0..6 {
                let h = 1e-6;
                let mut v = [0.0; 6];
                v[..3].copy_from_slice(m.angular.as_slice());
                v[3..].copy_from_slice(m.linear.as_slice());
                let (mut a, mut b) = (v, v);
                a[c] += h;
                b[c] -= h;
                let num = (at(&i, &t, &Motion::from_slice(&a), &p0)
                    - at(&i, &t, &Motion::from_slice(&b), &p0))
                    / (2.0 * h);
                close(num, j.d_uv_d_motion.column(c).into(), "motion");
            }
            let arr = i.to_array();
            for c in 0..10 {
                let h = 1e-7 * (1.0 + arr[c].abs());
                let (mut a, mut b) = (arr, arr);
                a[c] += h;
                b[c] -= h;
                let num = (at(&Intrinsics::from_array(a), &t, &m, &p0)
                    - at(&Intrinsics::from_array(b), &t, &m, &p0))
                    / (2.0 * h);
                close(num, j.d_uv_d_intrinsics.column(c).into(), "intrinsics");
            }
            let h = 1e-7;
            let (mut a, mut b) = (t, t);
            a.readout_s += h;
            b.readout_s -= h;
            let num = (at(&i, &a, &m, &p0) - at(&i, &b, &m, &p0)) / (2.0 * h);
            close(num, j.d_uv_d_readout, "readout");
        }
    }

    #[test]
    fn exp_and_left_jacobian_agree_with_their_definitions() {
        let phi = Vector3::new(0.2, -0.1, 0.3);
        let r = exp_so3(&phi);
        assert!((r * r.transpose() - Matrix3::identity()).norm() < 1e-14);
        assert!((r.determinant() - 1.0).abs() < 1e-14);
        // exp([φ + δ]×) ≈ exp([J_l δ]×) exp([φ]×)
        let d = Vector3::new(1e-6, -2e-6, 0.5e-6);
        let lhs = exp_so3(&(phi + d));
        let rhs = exp_so3(&(left_jacobian_so3(&phi) * d)) * r;
        assert!((lhs - rhs).norm() < 1e-11);
    }
}
