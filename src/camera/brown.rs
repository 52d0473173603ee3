//! The `brown` camera model of DESIGN.md "Conventions": projection, distortion, its iterative
//! inversion and analytic Jacobians.
//!
//! ```text
//! x = X/Z, y = Y/Z, r² = x² + y², radial = 1 + k1·r² + k2·r⁴ + k3·r⁶
//! xd = x·radial + 2·p1·x·y + p2·(r² + 2x²)
//! yd = y·radial + p1·(r² + 2y²) + 2·p2·x·y
//! u  = (c + b1)·xd + b2·yd + u0
//! v  = c·yd + v0
//! ```
//!
//! This is OpenCV's `k1, k2, p1, p2, k3` model with `fx = c + b1`, skew `b2`, `fy = c`,
//! `cx = u0 − 0.5`, `cy = v0 − 0.5` (pixel centres at half-integers, see the crate conventions).
//! Pose Jacobians use the perturbation of [`crate::geometry::pose`].

use nalgebra::{Matrix2, Matrix2x3, SMatrix, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::geometry::Rigid3;
use crate::geometry::pose::skew;

/// One intrinsic parameter of the `brown` model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Term {
    /// Principal distance (px).
    C,
    /// Principal point, u (px).
    U0,
    /// Principal point, v (px).
    V0,
    /// Radial distortion, r² coefficient.
    K1,
    /// Radial distortion, r⁴ coefficient.
    K2,
    /// Radial distortion, r⁶ coefficient.
    K3,
    /// Decentring distortion (OpenCV p1).
    P1,
    /// Decentring distortion (OpenCV p2).
    P2,
    /// Affinity: `fx − fy` (px).
    B1,
    /// Shear (px).
    B2,
}

impl Term {
    /// All terms, in the order of [`Intrinsics::to_array`] and of the Jacobian columns.
    pub const ALL: [Term; 10] = [
        Term::C,
        Term::U0,
        Term::V0,
        Term::K1,
        Term::K2,
        Term::K3,
        Term::P1,
        Term::P2,
        Term::B1,
        Term::B2,
    ];

    /// Index of this term in [`Term::ALL`].
    #[must_use]
    pub fn index(self) -> usize {
        self as usize
    }

    /// The term's name as written in profiles (`"c"`, `"k1"`, ...).
    #[must_use]
    pub fn name(self) -> &'static str {
        ["c", "u0", "v0", "k1", "k2", "k3", "p1", "p2", "b1", "b2"][self.index()]
    }

    /// The term called `name`, if any.
    #[must_use]
    pub fn from_name(name: &str) -> Option<Term> {
        Term::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The unit in which the term is reported.
    #[must_use]
    pub fn unit(self) -> &'static str {
        match self {
            Term::C | Term::U0 | Term::V0 | Term::B1 | Term::B2 => "px",
            _ => "",
        }
    }
}

impl std::fmt::Display for Term {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The ten intrinsics of the `brown` model (pixels for c, u0, v0, b1, b2; unitless otherwise).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Intrinsics {
    /// Principal distance (px).
    pub c: f64,
    /// Principal point u (px, COLMAP pixel convention).
    pub u0: f64,
    /// Principal point v (px, COLMAP pixel convention).
    pub v0: f64,
    /// Radial r² coefficient.
    #[serde(default)]
    pub k1: f64,
    /// Radial r⁴ coefficient.
    #[serde(default)]
    pub k2: f64,
    /// Radial r⁶ coefficient.
    #[serde(default)]
    pub k3: f64,
    /// Decentring p1.
    #[serde(default)]
    pub p1: f64,
    /// Decentring p2.
    #[serde(default)]
    pub p2: f64,
    /// Affinity (px): `fx = c + b1`.
    #[serde(default)]
    pub b1: f64,
    /// Shear (px).
    #[serde(default)]
    pub b2: f64,
}

/// Why a pixel could not be undistorted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum UndistortError {
    /// The pixel lies beyond the radius at which the radial distortion folds back on itself.
    #[error(
        "pixel ({u:.3}, {v:.3}) lies outside the region where the distortion model is invertible \
         (normalised radius {radius:.4}, the model folds at {max_radius:.4})"
    )]
    OutsideValidRegion {
        /// Pixel u.
        u: f64,
        /// Pixel v.
        v: f64,
        /// Normalised radius reached (ideal for a converged solution, distorted otherwise).
        radius: f64,
        /// Largest normalised radius where the model is invertible.
        max_radius: f64,
    },
    /// Newton's iteration did not converge.
    #[error(
        "undistorting pixel ({u:.3}, {v:.3}) did not converge in {iterations} iterations \
         (residual {residual:.3e})"
    )]
    NoConvergence {
        /// Pixel u.
        u: f64,
        /// Pixel v.
        v: f64,
        /// Iterations made.
        iterations: usize,
        /// Final residual in normalised units.
        residual: f64,
    },
    /// The pixel or the model is not a finite number.
    #[error("pixel ({u}, {v}) or the intrinsics are not finite")]
    NotFinite {
        /// Pixel u.
        u: f64,
        /// Pixel v.
        v: f64,
    },
}

/// A projected point with its derivatives.
#[derive(Clone, Copy, Debug)]
pub struct Projection {
    /// The pixel.
    pub uv: Vector2<f64>,
    /// `∂uv/∂p_cam` (2×3).
    pub d_uv_d_p_cam: Matrix2x3<f64>,
    /// `∂uv/∂intrinsics`, columns in the order of [`Term::ALL`] (2×10).
    pub d_uv_d_intrinsics: SMatrix<f64, 2, 10>,
}

/// A world point projected through a pose, with derivatives for the bundle adjustment.
#[derive(Clone, Copy, Debug)]
pub struct WorldProjection {
    /// The pixel.
    pub uv: Vector2<f64>,
    /// `∂uv/∂p_world` (2×3).
    pub d_uv_d_p_world: Matrix2x3<f64>,
    /// `∂uv/∂(δω, δt)` for the pose perturbation of [`crate::geometry::pose`] (2×6).
    pub d_uv_d_pose: SMatrix<f64, 2, 6>,
    /// `∂uv/∂intrinsics` (2×10), columns in the order of [`Term::ALL`].
    pub d_uv_d_intrinsics: SMatrix<f64, 2, 10>,
}

/// Newton iterations allowed when inverting the distortion.
const MAX_UNDISTORT_ITERATIONS: usize = 50;
/// Convergence tolerance of the inversion in normalised units (1e-14 ≈ 3e-11 px at c = 3000).
const UNDISTORT_TOLERANCE: f64 = 1e-14;

impl Intrinsics {
    /// A distortion-free camera.
    #[must_use]
    pub fn pinhole(c: f64, u0: f64, v0: f64) -> Self {
        Intrinsics {
            c,
            u0,
            v0,
            k1: 0.0,
            k2: 0.0,
            k3: 0.0,
            p1: 0.0,
            p2: 0.0,
            b1: 0.0,
            b2: 0.0,
        }
    }

    /// The parameters in the order of [`Term::ALL`].
    #[must_use]
    pub fn to_array(&self) -> [f64; 10] {
        [
            self.c, self.u0, self.v0, self.k1, self.k2, self.k3, self.p1, self.p2, self.b1, self.b2,
        ]
    }

    /// Builds intrinsics from the order of [`Term::ALL`].
    #[must_use]
    pub fn from_array(a: [f64; 10]) -> Self {
        Intrinsics {
            c: a[0],
            u0: a[1],
            v0: a[2],
            k1: a[3],
            k2: a[4],
            k3: a[5],
            p1: a[6],
            p2: a[7],
            b1: a[8],
            b2: a[9],
        }
    }

    /// The value of one term.
    #[must_use]
    pub fn get(&self, term: Term) -> f64 {
        self.to_array()[term.index()]
    }

    /// Sets one term.
    pub fn set(&mut self, term: Term, value: f64) {
        let mut a = self.to_array();
        a[term.index()] = value;
        *self = Intrinsics::from_array(a);
    }

    /// The calibration matrix of the undistorted pinhole image of this camera: pixels
    /// `u = (c + b1)·x + b2·y + u0`, `v = c·y + v0` of ideal normalised coordinates.
    #[must_use]
    pub fn pinhole_matrix(&self) -> nalgebra::Matrix3<f64> {
        nalgebra::Matrix3::new(
            self.c + self.b1,
            self.b2,
            self.u0,
            0.0,
            self.c,
            self.v0,
            0.0,
            0.0,
            1.0,
        )
    }

    /// Whether any distortion term (k, p) is non-zero.
    #[must_use]
    pub fn has_distortion(&self) -> bool {
        [self.k1, self.k2, self.k3, self.p1, self.p2]
            .iter()
            .any(|&k| k != 0.0)
    }

    /// Whether every parameter is finite and `c > 0`, `c + b1 > 0`.
    #[must_use]
    pub fn is_valid(&self) -> bool {
        self.to_array().iter().all(|v| v.is_finite()) && self.c > 0.0 && self.c + self.b1 > 0.0
    }

    /// Distorts ideal normalised coordinates: `xy → xy_d`.
    #[must_use]
    pub fn distort(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (xy.x, xy.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        Vector2::new(
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// [`Intrinsics::distort`] with its Jacobian `∂xy_d/∂xy`.
    #[must_use]
    pub fn distort_with_jacobian(&self, xy: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let (x, y) = (xy.x, xy.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d(radial)/d(r²)
        let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2);
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        let dxd_dx = radial + 2.0 * x * x * dradial + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
        let dxd_dy = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dyd_dx = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dyd_dy = radial + 2.0 * y * y * dradial + 6.0 * self.p1 * y + 2.0 * self.p2 * x;
        (
            Vector2::new(xd, yd),
            Matrix2::new(dxd_dx, dxd_dy, dyd_dx, dyd_dy),
        )
    }

    /// Pixel of distorted normalised coordinates (the affine part of the model).
    #[must_use]
    pub fn pixel_from_distorted(&self, xy_d: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            (self.c + self.b1) * xy_d.x + self.b2 * xy_d.y + self.u0,
            self.c * xy_d.y + self.v0,
        )
    }

    /// Distorted normalised coordinates of a pixel (exact inverse of the affine part).
    #[must_use]
    pub fn distorted_from_pixel(&self, uv: &Vector2<f64>) -> Vector2<f64> {
        let yd = (uv.y - self.v0) / self.c;
        let xd = (uv.x - self.u0 - self.b2 * yd) / (self.c + self.b1);
        Vector2::new(xd, yd)
    }

    /// Pixel of ideal normalised coordinates: distortion then the affine part.
    #[must_use]
    pub fn pixel_from_ideal(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        self.pixel_from_distorted(&self.distort(xy))
    }

    /// Projects a point of the camera frame; `None` behind or on the camera plane (`Z ≤ 0`) or
    /// beyond the radius where the radial distortion folds back (such rays lie outside the
    /// lens's field; the polynomial would map them to arbitrary pixels, even inside the image).
    #[must_use]
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        if p_cam.z <= 0.0 {
            return None;
        }
        let xy = Vector2::new(p_cam.x, p_cam.y) / p_cam.z;
        self.in_valid_region(xy.norm_squared())
            .then(|| self.pixel_from_ideal(&xy))
    }

    /// Whether the radial map `r·radial(r)` is increasing on `[0, r]` (`r2 = r²`): the region
    /// where the model is invertible. Exact: `g(s) = 1 + 3·k1·s + 5·k2·s² + 7·k3·s³` must stay
    /// positive on `[0, r²]`, checked at `r²` and at the stationary points of `g` inside.
    #[must_use]
    pub fn in_valid_region(&self, r2: f64) -> bool {
        let g = |s: f64| 1.0 + s * (3.0 * self.k1 + s * (5.0 * self.k2 + s * 7.0 * self.k3));
        let at_r = g(r2);
        if at_r <= 0.0 || at_r.is_nan() {
            return false;
        }
        // g'(s) = 3·k1 + 10·k2·s + 21·k3·s².
        let (a, b, c) = (21.0 * self.k3, 10.0 * self.k2, 3.0 * self.k1);
        let roots: [Option<f64>; 2] = if a == 0.0 {
            [(b != 0.0).then(|| -c / b), None]
        } else {
            let d = b * b - 4.0 * a * c;
            if d < 0.0 {
                [None, None]
            } else {
                let sq = d.sqrt();
                [Some((-b - sq) / (2.0 * a)), Some((-b + sq) / (2.0 * a))]
            }
        };
        roots
            .into_iter()
            .flatten()
            .all(|s| !(s > 0.0 && s < r2) || g(s) > 0.0)
    }

    /// The largest normalised radius up to which the radial map `r·radial(r)` is increasing,
    /// i.e. the region where undistortion has a unique solution; `f64::INFINITY` if it never
    /// folds.
    ///
    /// It is the smallest positive root of `1 + 3·k1·s + 5·k2·s² + 7·k3·s³` in `s = r²`.
    #[must_use]
    pub fn max_valid_radius(&self) -> f64 {
        let g = |s: f64| 1.0 + s * (3.0 * self.k1 + s * (5.0 * self.k2 + s * 7.0 * self.k3));
        // Scan s geometrically from 1e-6 to 1e6 (radius 1e-3 to 1e3), then bisect the bracket.
        let mut s_prev = 0.0;
        let mut s = 1e-6;
        while s < 1e6 {
            if g(s) <= 0.0 {
                let (mut lo, mut hi) = (s_prev, s);
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    if g(mid) > 0.0 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                return lo.sqrt();
            }
            s_prev = s;
            s *= 1.02;
        }
        f64::INFINITY
    }

    /// Ideal normalised coordinates of a pixel: the affine part inverted exactly, then the
    /// distortion inverted by damped Newton iteration with a convergence check.
    ///
    /// # Errors
    ///
    /// [`UndistortError::OutsideValidRegion`] when the solution would lie beyond
    /// [`Intrinsics::max_valid_radius`] (or there is none), [`UndistortError::NoConvergence`] if
    /// the iteration stalls, [`UndistortError::NotFinite`] for non-finite input.
    pub fn ideal_from_pixel(&self, uv: &Vector2<f64>) -> Result<Vector2<f64>, UndistortError> {
        if !uv.iter().all(|v| v.is_finite()) || !self.is_valid() {
            return Err(UndistortError::NotFinite { u: uv.x, v: uv.y });
        }
        let target = self.distorted_from_pixel(uv);
        if !self.has_distortion() {
            return Ok(target);
        }
        let max_radius = self.max_valid_radius();
        let outside = |radius: f64| UndistortError::OutsideValidRegion {
            u: uv.x,
            v: uv.y,
            radius,
            max_radius,
        };
        let mut xy = target;
        let mut residual = f64::INFINITY;
        for iteration in 0..MAX_UNDISTORT_ITERATIONS {
            let (f, jac) = self.distort_with_jacobian(&xy);
            let r = f - target;
            residual = r.norm();
            if residual <= UNDISTORT_TOLERANCE * (1.0 + target.norm()) {
                if xy.norm() >= max_radius {
                    return Err(outside(xy.norm()));
                }
                return Ok(xy);
            }
            let Some(jinv) = jac.try_inverse() else {
                return Err(outside(xy.norm()));
            };
            let mut step = jinv * r;
            // Keep the iterate inside the valid disc: halve steps that would leave it.
            let mut tries = 0;
            while (xy - step).norm() >= max_radius && tries < 60 {
                step *= 0.5;
                tries += 1;
            }
            if tries == 60 {
                return Err(outside(target.norm()));
            }
            xy -= step;
            if iteration + 1 == MAX_UNDISTORT_ITERATIONS {
                break;
            }
        }
        // Did not converge: if the distorted radius exceeds what the valid disc can produce,
        // the pixel is outside the invertible region; otherwise report the stall.
        if max_radius.is_finite() {
            let edge = Vector2::new(max_radius, 0.0);
            let max_distorted = self.distort(&edge).norm();
            if target.norm() >= max_distorted * (1.0 - 1e-9) {
                return Err(outside(target.norm()));
            }
        }
        Err(UndistortError::NoConvergence {
            u: uv.x,
            v: uv.y,
            iterations: MAX_UNDISTORT_ITERATIONS,
            residual,
        })
    }

    /// Projects a camera-frame point with the Jacobians with respect to the point and to every
    /// intrinsic; `None` for `Z ≤ 0`.
    #[must_use]
    pub fn project_with_jacobians(&self, p_cam: &Vector3<f64>) -> Option<Projection> {
        if p_cam.z <= 0.0 {
            return None;
        }
        let iz = 1.0 / p_cam.z;
        let xy = Vector2::new(p_cam.x * iz, p_cam.y * iz);
        if !self.in_valid_region(xy.norm_squared()) {
            return None;
        }
        let (x, y) = (xy.x, xy.y);
        let (xy_d, d_xyd_d_xy) = self.distort_with_jacobian(&xy);
        let (xd, yd) = (xy_d.x, xy_d.y);
        let fx = self.c + self.b1;
        let uv = Vector2::new(fx * xd + self.b2 * yd + self.u0, self.c * yd + self.v0);

        // ∂uv/∂xy_d
        let d_uv_d_xyd = Matrix2::new(fx, self.b2, 0.0, self.c);
        // ∂xy/∂p_cam
        let d_xy_d_p = Matrix2x3::new(iz, 0.0, -x * iz, 0.0, iz, -y * iz);
        let d_uv_d_p_cam = d_uv_d_xyd * d_xyd_d_xy * d_xy_d_p;

        let r2 = x * x + y * y;
        let r4 = r2 * r2;
        let r6 = r4 * r2;
        // ∂xy_d/∂(k1, k2, k3, p1, p2), as columns.
        let dk = [
            Vector2::new(x * r2, y * r2),
            Vector2::new(x * r4, y * r4),
            Vector2::new(x * r6, y * r6),
            Vector2::new(2.0 * x * y, r2 + 2.0 * y * y),
            Vector2::new(r2 + 2.0 * x * x, 2.0 * x * y),
        ];
        let mut d_uv_d_intrinsics = SMatrix::<f64, 2, 10>::zeros();
        // c: u = (c + b1)·xd + ..., v = c·yd + v0
        d_uv_d_intrinsics[(0, 0)] = xd;
        d_uv_d_intrinsics[(1, 0)] = yd;
        d_uv_d_intrinsics[(0, 1)] = 1.0;
        d_uv_d_intrinsics[(1, 2)] = 1.0;
        for (i, col) in dk.iter().enumerate() {
            let d = d_uv_d_xyd * col;
            d_uv_d_intrinsics[(0, 3 + i)] = d.x;
            d_uv_d_intrinsics[(1, 3 + i)] = d.y;
        }
        d_uv_d_intrinsics[(0, 8)] = xd;
        d_uv_d_intrinsics[(0, 9)] = yd;
        Some(Projection {
            uv,
            d_uv_d_p_cam,
            d_uv_d_intrinsics,
        })
    }

    /// Projects a world point through `cam_from_world`, with the Jacobians with respect to the
    /// world point, the pose (perturbation of [`crate::geometry::pose`]) and the intrinsics.
    #[must_use]
    pub fn project_world_with_jacobians(
        &self,
        cam_from_world: &Rigid3,
        p_world: &Vector3<f64>,
    ) -> Option<WorldProjection> {
        let r_p = cam_from_world.rotation * p_world;
        let p_cam = r_p + cam_from_world.translation.vector;
        let proj = self.project_with_jacobians(&p_cam)?;
        let rot = cam_from_world.rotation.to_rotation_matrix();
        let d_uv_d_p_world = proj.d_uv_d_p_cam * rot.matrix();
        let d_omega = -proj.d_uv_d_p_cam * skew(&r_p);
        let mut d_uv_d_pose = SMatrix::<f64, 2, 6>::zeros();
        d_uv_d_pose.fixed_view_mut::<2, 3>(0, 0).copy_from(&d_omega);
        d_uv_d_pose
            .fixed_view_mut::<2, 3>(0, 3)
            .copy_from(&proj.d_uv_d_p_cam);
        Some(WorldProjection {
            uv: proj.uv,
            d_uv_d_p_world,
            d_uv_d_pose,
            d_uv_d_intrinsics: proj.d_uv_d_intrinsics,
        })
    }
}

/// A `brown` camera: image size and intrinsics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrownCamera {
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// The intrinsics.
    pub intrinsics: Intrinsics,
}

impl BrownCamera {
    /// Projects a world point through `cam_from_world`; `None` behind the camera.
    #[must_use]
    pub fn project_world(
        &self,
        cam_from_world: &Rigid3,
        p_world: &Vector3<f64>,
    ) -> Option<Vector2<f64>> {
        let p_cam = cam_from_world.rotation * p_world + cam_from_world.translation.vector;
        self.intrinsics.project(&p_cam)
    }

    /// Whether a pixel lies inside the image, `margin` pixels away from every border.
    #[must_use]
    pub fn contains(&self, uv: &Vector2<f64>, margin: f64) -> bool {
        uv.x >= margin
            && uv.y >= margin
            && uv.x <= f64::from(self.width) - margin
            && uv.y <= f64::from(self.height) - margin
    }

    /// The same camera for an image scaled by `factor` (c, u0, v0, b1, b2 scale; the
    /// normalised distortion does not). The pixel-corner convention makes `u0` scale exactly.
    #[must_use]
    pub fn scaled(&self, width: u32, height: u32) -> BrownCamera {
        let s = f64::from(width) / f64::from(self.width);
        let i = self.intrinsics;
        BrownCamera {
            width,
            height,
            intrinsics: Intrinsics {
                c: i.c * s,
                u0: i.u0 * s,
                v0: i.v0 * f64::from(height) / f64::from(self.height),
                b1: i.b1 * s,
                b2: i.b2 * s,
                ..i
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose::retract;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector6};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn phone() -> Intrinsics {
        Intrinsics {
            c: 3050.0,
            u0: 1931.4,
            v0: 1074.6,
            k1: 0.0125,
            k2: -0.0094,
            k3: 0.004,
            p1: 1.6e-4,
            p2: -2.1e-4,
            b1: 0.8,
            b2: -0.3,
        }
    }

    #[test]
    fn project_pinhole_matches_hand_computation() {
        let cam = Intrinsics::pinhole(1000.0, 320.0, 240.0);
        let uv = cam.project(&Vector3::new(0.5, -0.25, 2.0)).unwrap();
        assert_eq!(uv, Vector2::new(320.0 + 250.0, 240.0 - 125.0));
        assert!(cam.project(&Vector3::new(0.0, 0.0, 0.0)).is_none());
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn distort_matches_hand_computation() {
        let cam = Intrinsics {
            k1: 0.1,
            k2: 0.01,
            k3: 0.001,
            p1: 0.002,
            p2: -0.003,
            ..phone()
        };
        let (x, y) = (0.3, -0.2);
        let r2: f64 = 0.13;
        let radial = 1.0 + 0.1 * r2 + 0.01 * r2 * r2 + 0.001 * r2 * r2 * r2;
        let xd = x * radial + 2.0 * 0.002 * x * y - 0.003 * (r2 + 2.0 * x * x);
        let yd = y * radial + 0.002 * (r2 + 2.0 * y * y) + 2.0 * -0.003 * x * y;
        let got = cam.distort(&Vector2::new(x, y));
        assert!((got.x - xd).abs() < 1e-16 && (got.y - yd).abs() < 1e-16);
        let uv = cam.pixel_from_distorted(&got);
        assert!((uv.x - ((3050.0 + 0.8) * xd - 0.3 * yd + 1931.4)).abs() < 1e-12);
        assert!((uv.y - (3050.0 * yd + 1074.6)).abs() < 1e-12);
    }

    #[test]
    fn undistort_inverts_projection_over_the_frame() {
        let cam = phone();
        for row in 0..=20 {
            for col in 0..=20 {
                let uv = Vector2::new(
                    3840.0 * f64::from(col) / 20.0,
                    2160.0 * f64::from(row) / 20.0,
                );
                let xy = cam.ideal_from_pixel(&uv).unwrap();
                let back = cam.pixel_from_ideal(&xy);
                assert!(
                    (back - uv).norm() < 1e-9,
                    "round trip error {} px at {uv:?}",
                    (back - uv).norm()
                );
            }
        }
    }

    #[test]
    fn undistort_outside_valid_region_errors() {
        // k1 < 0 folds at r² = −1/(3·k1): k1 = −0.2 gives r = 1.2910.
        let cam = Intrinsics {
            k1: -0.2,
            ..Intrinsics::pinhole(1000.0, 500.0, 500.0)
        };
        let max_r = cam.max_valid_radius();
        assert!(
            (max_r - (1.0f64 / 0.6).sqrt()).abs() < 1e-9,
            "fold radius {max_r}"
        );
        // The largest distorted radius is r·(1 + k1 r²) at the fold: 0.8607; pixel 900 px out.
        let err = cam
            .ideal_from_pixel(&Vector2::new(500.0 + 900.0, 500.0))
            .unwrap_err();
        assert!(
            matches!(err, UndistortError::OutsideValidRegion { .. }),
            "{err}"
        );
        // Inside, it works.
        assert!(
            cam.ideal_from_pixel(&Vector2::new(500.0 + 800.0, 500.0))
                .is_ok()
        );
    }

    #[test]
    fn projection_beyond_the_fold_is_none() {
        // p30-like k1 > 0, k2 < 0 folds at r² = 5.03 (r = 2.24); a point at r = 3.4 would be
        // mapped back inside the image by the polynomial.
        let cam = Intrinsics {
            k1: 0.0125,
            k2: -0.0094,
            ..Intrinsics::pinhole(762.5, 480.0, 270.0)
        };
        let r = cam.max_valid_radius();
        assert!((r - 2.2428).abs() < 1e-3, "fold radius {r}");
        assert!(cam.project(&Vector3::new(3.17, 1.27, 1.0)).is_none());
        assert!(cam.project(&Vector3::new(r * 0.999, 0.0, 1.0)).is_some());
        assert!(cam.project(&Vector3::new(r * 1.001, 0.0, 1.0)).is_none());
        // k1 = −0.5, k2 = 0.2: g = 1 − 1.5s + s² has its minimum 0.4375 at s = 0.75, never
        // reaching zero: valid everywhere.
        let dip = Intrinsics {
            k1: -0.5,
            k2: 0.2,
            ..Intrinsics::pinhole(100.0, 0.0, 0.0)
        };
        assert!(dip.in_valid_region(100.0));
        // k1 = −0.5, k2 = 0.1: g = 1 − 1.5s + 0.5s² is negative between its roots 1 and 2 and
        // positive again beyond: s = 4 is invalid although g(4) > 0.
        let fold = Intrinsics {
            k1: -0.5,
            k2: 0.1,
            ..Intrinsics::pinhole(100.0, 0.0, 0.0)
        };
        assert!(
            fold.in_valid_region(0.9) && !fold.in_valid_region(1.2) && !fold.in_valid_region(4.0)
        );
    }

    #[test]
    fn undistort_non_finite_pixel_errors() {
        let err = phone()
            .ideal_from_pixel(&Vector2::new(f64::NAN, 1.0))
            .unwrap_err();
        assert!(matches!(err, UndistortError::NotFinite { .. }));
    }

    #[test]
    fn max_valid_radius_is_infinite_without_fold() {
        let cam = Intrinsics {
            k1: 0.1,
            ..Intrinsics::pinhole(1000.0, 0.0, 0.0)
        };
        assert_eq!(cam.max_valid_radius(), f64::INFINITY);
    }

    /// Central differences with step h on a function of one scalar.
    fn central(f: impl Fn(f64) -> Vector2<f64>, x: f64, h: f64) -> Vector2<f64> {
        (f(x + h) - f(x - h)) / (2.0 * h)
    }

    #[track_caller]
    fn assert_close(analytic: Vector2<f64>, numeric: Vector2<f64>, what: &str) {
        let scale = 1.0 + numeric.norm();
        assert!(
            (analytic - numeric).norm() <= 1e-6 * scale,
            "{what}: analytic {analytic:?} vs numeric {numeric:?}"
        );
    }

    #[test]
    fn jacobians_match_central_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let cam = phone();
        for _ in 0..50 {
            let pose = Isometry3::from_parts(
                Translation3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    3.0,
                ),
                UnitQuaternion::from_euler_angles(
                    rng.random_range(-0.3..0.3),
                    rng.random_range(-0.3..0.3),
                    rng.random_range(-3.0..3.0),
                ),
            );
            let p = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.6..0.6),
                rng.random_range(-0.5..1.0),
            );
            let j = cam.project_world_with_jacobians(&pose, &p).unwrap();
            let proj = |cam: &Intrinsics, pose: &Rigid3, p: &Vector3<f64>| {
                cam.project(&(pose.rotation * p + pose.translation.vector))
                    .unwrap()
            };
            assert!((j.uv - proj(&cam, &pose, &p)).norm() < 1e-9);
            for k in 0..3 {
                let numeric = central(
                    |h| {
                        let mut q = p;
                        q[k] += h;
                        proj(&cam, &pose, &q)
                    },
                    0.0,
                    1e-6,
                );
                assert_close(
                    j.d_uv_d_p_world.column(k).into(),
                    numeric,
                    &format!("point {k}"),
                );
            }
            for k in 0..6 {
                let numeric = central(
                    |h| {
                        let mut d = Vector6::zeros();
                        d[k] = h;
                        proj(&cam, &retract(&pose, &d), &p)
                    },
                    0.0,
                    1e-7,
                );
                assert_close(
                    j.d_uv_d_pose.column(k).into(),
                    numeric,
                    &format!("pose {k}"),
                );
            }
            for term in Term::ALL {
                // uv is linear in every intrinsic, so a large step has no truncation error and
                // keeps the rounding error (≈ 1e-16·uv/h) far below the tolerance.
                let h = if term.unit() == "px" { 1e-2 } else { 1e-3 };
                let numeric = central(
                    |d| {
                        let mut c = cam;
                        c.set(term, c.get(term) + d);
                        proj(&c, &pose, &p)
                    },
                    0.0,
                    h,
                );
                assert_close(
                    j.d_uv_d_intrinsics.column(term.index()).into(),
                    numeric,
                    term.name(),
                );
            }
        }
    }

    #[test]
    fn term_names_round_trip() {
        for t in Term::ALL {
            assert_eq!(Term::from_name(t.name()), Some(t));
            assert_eq!(
                serde_json::to_string(&t).unwrap(),
                format!("\"{}\"", t.name())
            );
        }
        assert_eq!(Term::from_name("k4"), None);
    }

    #[test]
    fn scaled_camera_projects_scaled_rays() {
        let cam = BrownCamera {
            width: 3840,
            height: 2160,
            intrinsics: phone(),
        };
        let small = cam.scaled(960, 540);
        let p = Vector3::new(0.4, -0.3, 2.0);
        let big = cam.intrinsics.project(&p).unwrap();
        let little = small.intrinsics.project(&p).unwrap();
        assert!((little * 4.0 - big).norm() < 1e-9);
    }
}
