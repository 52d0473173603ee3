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
//!   later, at `p(s) = exp([s·ω + ½s²·α + ⅙s³·ζ + s⁴/24·σ]×)·p₀ + s·ν + ½s²·a + ⅙s³·j +
//!   s⁴/24·s₄`, with `ω` (rad/s) and `ν` (world units/s) in the camera frame (`[ω]× = Ṙ·Rᵀ`,
//!   `ν = Ṫ − ω × T` of `cam_from_world = (R, T)`), their rates of change `α`, `a`, those
//!   rates' `ζ`, `j` and theirs `σ`, `s₄`: up to fourth order about the frame time. Over one
//!   readout the second-order terms move a point by thousandths of a pixel; over `±1/fps` to a
//!   neighbouring video frame the hand's acceleration (15–20 °/s² on the simulated video
//!   paths) turns the camera by `½·α·Δ²`, about a pixel at 1920 px, its jerk makes the poses'
//!   central difference 1–2 % faster than the velocity, and its 4–12 Hz tremor bends the path
//!   within the `±(1/fps + τ/2)` the three frames' rows span more than a cubic follows
//!   (Hedborg et al. 2012 use first order within a frame; the neighbours need up to the
//!   fourth, [`MotionOrder`]).
//! * Projection: the row that sees the point depends on where it is seen, so the pixel
//!   solves `v = π_v(p(s(v)))` (a contraction: the motion over one row is a tiny fraction of
//!   a row); [`project`] iterates it, [`project_with_jacobians`] differentiates the solution
//!   implicitly.

use nalgebra::{Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};

use super::brown::Intrinsics;
use crate::geometry::pose::skew;

/// A frame's motion about its pose at the frame time (camera frame), up to fourth order.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Motion {
    /// Angular velocity ω (rad/s).
    pub angular: Vector3<f64>,
    /// Linear velocity ν (world units/s).
    pub linear: Vector3<f64>,
    /// Angular acceleration α (rad/s²); zero for a first-order motion.
    pub angular_acceleration: Vector3<f64>,
    /// Linear acceleration a (world units/s²); zero for a first-order motion.
    pub linear_acceleration: Vector3<f64>,
    /// Angular jerk ζ (rad/s³); zero below third order.
    pub angular_jerk: Vector3<f64>,
    /// Linear jerk j (world units/s³); zero below third order.
    pub linear_jerk: Vector3<f64>,
    /// Angular snap σ (rad/s⁴, the jerk's rate); zero below fourth order.
    pub angular_snap: Vector3<f64>,
    /// Linear snap s₄ (world units/s⁴); zero below fourth order.
    pub linear_snap: Vector3<f64>,
}

/// The order of a frame's motion about its time: how many of its values are adjusted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MotionOrder {
    /// Velocities `[ωx, ωy, ωz, νx, νy, νz]` (within one frame's readout).
    #[default]
    First,
    /// Velocities, then accelerations `[αx, αy, αz, ax, ay, az]`.
    Second,
    /// Velocities, accelerations, then jerks `[ζx, ζy, ζz, jx, jy, jz]` (neighbouring video
    /// frames `±1/fps` away: the central difference of their poses is the velocity only to
    /// second order, `Δ²·jerk/6` off, 1–2 % of the speed on the simulated video paths).
    Third,
    /// Up to the snaps `[σx, σy, σz, sx, sy, sz]`, the jerks' rates: what a frame and its two
    /// neighbours can carry with the readout time still determined (per axis they show three
    /// poses and three velocities, the rows' shear over τ; a degree-4 path has five values
    /// besides the pose, a quintic would match any τ). Hand tremor at 8–12 Hz bends the path
    /// over the ±48 ms the three frames' rows span: a cubic leaves 5–21 % of its amplitude, a
    /// quartic 2–9 %.
    Fourth,
}

impl MotionOrder {
    /// The order as a number: 1 (velocities) to 4 (snaps).
    #[must_use]
    pub fn number(self) -> u8 {
        match self {
            MotionOrder::First => 1,
            MotionOrder::Second => 2,
            MotionOrder::Third => 3,
            MotionOrder::Fourth => 4,
        }
    }

    /// Adjusted values: 6 per order.
    #[must_use]
    pub fn values(self) -> usize {
        match self {
            MotionOrder::First => 6,
            MotionOrder::Second => 12,
            MotionOrder::Third => 18,
            MotionOrder::Fourth => 24,
        }
    }
}

/// The time unit of the adjusted higher-order values (s, one frame interval at 30 fps): an
/// acceleration is adjusted as `α·T`, a jerk as `ζ·T²` and a snap as `σ·T³`, in the units of a velocity, so that
/// over `±1/fps` every order moves the image by comparable amounts per unit and the normal
/// equations stay well conditioned (a jerk in rad/s³ moves a pixel 10⁵ times less than a
/// rotation of the pose).
pub const HIGHER_ORDER_TIME_UNIT_S: f64 = 1.0 / 30.0;

/// The blocks of the adjusted values ([`Motion::values`]) in world units: ν, `a·T`, `j·T²`
/// and `s₄·T³`, which scale with the world; the angular ones do not.
pub const WORLD_UNIT_BLOCKS: [std::ops::Range<usize>; ORDERS] = [3..6, 9..12, 15..18, 21..24];

/// The most orders a motion has ([`MotionOrder::Fourth`]).
pub const ORDERS: usize = 4;

/// The most adjusted values of a motion: 6 per order.
pub const MAX_VALUES: usize = 6 * ORDERS;

/// The unit of each order's adjusted value, `Tᵏ` ([`HIGHER_ORDER_TIME_UNIT_S`]): the
/// velocities as they are, `α·T`, `a·T`, then `ζ·T²`, `j·T²`, then `σ·T³`, `s₄·T³`.
const ORDER_UNITS: [f64; ORDERS] = [
    1.0,
    HIGHER_ORDER_TIME_UNIT_S,
    HIGHER_ORDER_TIME_UNIT_S * HIGHER_ORDER_TIME_UNIT_S,
    HIGHER_ORDER_TIME_UNIT_S * HIGHER_ORDER_TIME_UNIT_S * HIGHER_ORDER_TIME_UNIT_S,
];

/// The Taylor weights `sᵏ⁺¹/(k+1)!` of the orders' values in the motion `s` seconds on:
/// `[s, ½s², ⅙s³, s⁴/24]`.
fn order_weights(s: f64) -> [f64; ORDERS] {
    let s2 = s * s;
    [s, 0.5 * s2, s2 * s / 6.0, s2 * s2 / 24.0]
}

/// Their derivatives in `s`: `[1, s, ½s², ⅙s³]`.
fn order_rates(s: f64) -> [f64; ORDERS] {
    [1.0, s, 0.5 * s * s, s * s * s / 6.0]
}

/// `Σₖ wₖ·xₖ`.
fn weighted(x: &[Vector3<f64>; ORDERS], w: [f64; ORDERS]) -> Vector3<f64> {
    x.iter().zip(w).map(|(x, w)| x * w).sum()
}

impl Motion {
    /// From the adjusted values of a motion of any order ([`MotionOrder::values`]; the higher
    /// orders missing are zero): velocities, then accelerations × [`HIGHER_ORDER_TIME_UNIT_S`],
    /// jerks × its square, snaps × its cube.
    #[must_use]
    pub fn from_slice(v: &[f64]) -> Self {
        let at = |k: usize| {
            v.get(3 * k..3 * k + 3).map_or_else(Vector3::zeros, |x| {
                Vector3::new(x[0], x[1], x[2]) / ORDER_UNITS[k / 2]
            })
        };
        Motion {
            angular: at(0),
            linear: at(1),
            angular_acceleration: at(2),
            linear_acceleration: at(3),
            angular_jerk: at(4),
            linear_jerk: at(5),
            angular_snap: at(6),
            linear_snap: at(7),
        }
    }

    /// The order of the motion: the highest derivative that is not zero (a motion of a lower
    /// order adjusted as a higher one keeps its higher terms exactly zero).
    #[must_use]
    pub fn order(&self) -> MotionOrder {
        let moves =
            |a: &Vector3<f64>, b: &Vector3<f64>| a.iter().chain(b.iter()).any(|v| *v != 0.0);
        if moves(&self.angular_snap, &self.linear_snap) {
            MotionOrder::Fourth
        } else if moves(&self.angular_jerk, &self.linear_jerk) {
            MotionOrder::Third
        } else if moves(&self.angular_acceleration, &self.linear_acceleration) {
            MotionOrder::Second
        } else {
            MotionOrder::First
        }
    }

    /// The adjusted values of the fourth-order motion: the inverse of [`Motion::from_slice`].
    #[must_use]
    pub fn values(&self) -> [f64; MAX_VALUES] {
        let mut out = [0.0; MAX_VALUES];
        let blocks = [
            self.angular,
            self.linear,
            self.angular_acceleration,
            self.linear_acceleration,
            self.angular_jerk,
            self.linear_jerk,
            self.angular_snap,
            self.linear_snap,
        ];
        for (k, (o, x)) in out.chunks_exact_mut(3).zip(blocks).enumerate() {
            for (o, v) in o.iter_mut().zip(x.iter()) {
                *o = v * ORDER_UNITS[k / 2];
            }
        }
        out
    }

    /// The angular values by order: `[ω, α, ζ, σ]`.
    fn angular_orders(&self) -> [Vector3<f64>; ORDERS] {
        [
            self.angular,
            self.angular_acceleration,
            self.angular_jerk,
            self.angular_snap,
        ]
    }

    /// The linear values by order: `[ν, a, j, s]`.
    fn linear_orders(&self) -> [Vector3<f64>; ORDERS] {
        [
            self.linear,
            self.linear_acceleration,
            self.linear_jerk,
            self.linear_snap,
        ]
    }

    /// The rotation vector turning the camera frame at the frame time into the one `s`
    /// seconds later (applied to points): `s·ω + ½s²·α + ⅙s³·ζ + s⁴/24·σ`.
    #[must_use]
    pub fn rotation_at(&self, s: f64) -> Vector3<f64> {
        weighted(&self.angular_orders(), order_weights(s))
    }

    /// Its rate `ω + s·α + ½s²·ζ + ⅙s³·σ`.
    #[must_use]
    pub fn rotation_rate_at(&self, s: f64) -> Vector3<f64> {
        weighted(&self.angular_orders(), order_rates(s))
    }

    /// The translation of the point: `s·ν + ½s²·a + ⅙s³·j + s⁴/24·s₄`.
    #[must_use]
    pub fn translation_at(&self, s: f64) -> Vector3<f64> {
        weighted(&self.linear_orders(), order_weights(s))
    }

    /// Its rate `ν + s·a + ½s²·j + ⅙s³·s₄`.
    #[must_use]
    pub fn translation_rate_at(&self, s: f64) -> Vector3<f64> {
        weighted(&self.linear_orders(), order_rates(s))
    }

    /// Where a point at `p0` in the camera frame at the frame time is `s` seconds later.
    #[must_use]
    pub fn point_at(&self, p0: &Vector3<f64>, s: f64) -> Vector3<f64> {
        exp_so3(&self.rotation_at(s)) * p0 + self.translation_at(s)
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
    /// `∂uv/∂(ω, ν, α, a, ζ, j, σ, s₄)` (2×24; the first [`MotionOrder::values`] columns are a
    /// motion of that order's).
    pub d_uv_d_motion: SMatrix<f64, 2, MAX_VALUES>,
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
    let phi = motion.rotation_at(s);
    let e = exp_so3(&phi);
    let e_p0 = e * p0;
    let q = e_p0 + motion.translation_at(s);
    let proj = intrinsics.project_with_jacobians(&q)?;
    let jb = proj.d_uv_d_p_cam;
    // ∂p/∂φ = −[E·p₀]×·J_l(φ); ∂p/∂s = ∂p/∂φ·φ'(s) + t'(s).
    let dq_dphi = -skew(&e_p0) * left_jacobian_so3(&phi);
    let dq_ds = dq_dphi * motion.rotation_rate_at(s) + motion.translation_rate_at(s);
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
    // Order k's values act through sᵏ/(k!·Tᵏ⁻¹) (T the time unit of the higher orders):
    // ∂p/∂ω = s·∂p/∂φ, ∂p/∂ν = s·I, ∂p/∂(α·T) = s²/(2T)·∂p/∂φ, ∂p/∂(a·T) = s²/(2T)·I,
    // ∂p/∂(ζ·T²) = s³/(6T²)·∂p/∂φ, ∂p/∂(j·T²) = s³/(6T²)·I, and s⁴/(24T³) for the snaps.
    let explicit_phi = jb * dq_dphi;
    let mut d_uv_d_motion = SMatrix::<f64, 2, MAX_VALUES>::zeros();
    for (order, (w, unit)) in order_weights(s).into_iter().zip(ORDER_UNITS).enumerate() {
        let f = w / unit;
        for c in 0..3 {
            let (ru, rv) = (explicit_phi[(0, c)], explicit_phi[(1, c)]);
            let (tu, tv) = (jb[(0, c)], jb[(1, c)]);
            d_uv_d_motion.set_column(6 * order + c, &solve(f * ru, f * rv, 0.0));
            d_uv_d_motion.set_column(6 * order + 3 + c, &solve(f * tu, f * tv, 0.0));
        }
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

    /// A motion's order is its highest derivative that is not zero, whatever order it was
    /// adjusted at.
    #[test]
    fn a_motion_s_order_is_its_highest_non_zero_derivative() {
        let mut values = [0.0; MAX_VALUES];
        assert_eq!(Motion::from_slice(&values).order(), MotionOrder::First);
        values[1] = 0.1;
        assert_eq!(Motion::from_slice(&values).order(), MotionOrder::First);
        values[9] = 0.2; // a linear acceleration
        assert_eq!(Motion::from_slice(&values).order(), MotionOrder::Second);
        values[14] = -0.3; // an angular jerk
        assert_eq!(Motion::from_slice(&values).order(), MotionOrder::Third);
        values[23] = 1e-9; // a linear snap
        assert_eq!(Motion::from_slice(&values).order(), MotionOrder::Fourth);
        assert_eq!(MotionOrder::Fourth.number(), 4);
    }
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

    /// Hand-held motion: 8 °/s about a tilted axis, 0.12 m/s, changing by 20 °/s² and 0.5
    /// m/s².
    fn motion() -> Motion {
        Motion {
            angular: Vector3::new(0.3, -0.9, 0.4).normalize() * 8f64.to_radians(),
            linear: Vector3::new(0.05, 0.1, -0.04).normalize() * 0.12,
            angular_acceleration: Vector3::new(-0.5, 0.2, 0.8).normalize() * 20f64.to_radians(),
            linear_acceleration: Vector3::new(0.3, -0.2, 0.1).normalize() * 0.5,
            angular_jerk: Vector3::new(0.1, 0.7, -0.3).normalize() * 400f64.to_radians(),
            linear_jerk: Vector3::new(-0.6, 0.2, 0.4).normalize() * 8.0,
            angular_snap: Vector3::new(0.5, -0.3, 0.6).normalize() * 9000f64.to_radians(),
            linear_snap: Vector3::new(0.2, 0.9, -0.1).normalize() * 150.0,
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
            let v = m.values();
            let back = Motion::from_slice(&v);
            for (x, y) in [
                (back.angular, m.angular),
                (back.linear_acceleration, m.linear_acceleration),
                (back.angular_jerk, m.angular_jerk),
                (back.linear_jerk, m.linear_jerk),
                (back.angular_snap, m.angular_snap),
                (back.linear_snap, m.linear_snap),
            ] {
                assert!((x - y).norm() <= 1e-12 * y.norm(), "{x} {y}");
            }
            for c in 0..MotionOrder::Fourth.values() {
                let h = 1e-6;
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
