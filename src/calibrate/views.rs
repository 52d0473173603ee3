//! The frames as the calibration sees them: each frame's camera (intrinsics and pose) and its
//! detected targets expressed in *undistorted pixel coordinates* — the pinhole image
//! `u = (c + b1)·x + b2·y + u0`, `v = c·y + v0` of the current intrinsics — where a circle's
//! image is an exact conic and the cameras are the 3×4 matrices `K [R | t]` that Quan's
//! construction and the triangulation need (docs/math.md §0: "All geometry in §1–§3 must be
//! done in undistorted coordinates").

use nalgebra::{Matrix3, Matrix3x4, Point3, Vector2};

use crate::camera::Intrinsics;
use crate::geometry::Rigid3;
use crate::geometry::conic::{Ellipse, fit_ellipse_direct};
use crate::geometry::pose::camera_centre;
use crate::geometry::triangulation::camera_matrix;

/// Points sampled on a detected ellipse to map it through the undistortion.
const ELLIPSE_SAMPLES: usize = 96;

/// A frame's camera in the current estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameCamera {
    /// Intrinsics.
    pub intrinsics: Intrinsics,
    /// Pose.
    pub cam_from_world: Rigid3,
}

impl FrameCamera {
    /// The undistorted pinhole calibration matrix.
    #[must_use]
    pub fn k(&self) -> Matrix3<f64> {
        self.intrinsics.pinhole_matrix()
    }

    /// `K [R | t]` in undistorted pixels.
    #[must_use]
    pub fn p(&self) -> Matrix3x4<f64> {
        camera_matrix(&self.k(), &self.cam_from_world)
    }

    /// The projection centre (world).
    #[must_use]
    pub fn centre(&self) -> Point3<f64> {
        camera_centre(&self.cam_from_world)
    }

    /// Undistorted pixel of an observed (distorted) pixel.
    #[must_use]
    pub fn undistort(&self, uv: &Vector2<f64>) -> Option<Vector2<f64>> {
        let xy = self.intrinsics.ideal_from_pixel(uv).ok()?;
        let h = self.k() * nalgebra::Vector3::new(xy.x, xy.y, 1.0);
        Some(Vector2::new(h.x / h.z, h.y / h.z))
    }

    /// Observed (distorted) pixel of an undistorted one.
    #[must_use]
    pub fn distort(&self, uv: &Vector2<f64>) -> Option<Vector2<f64>> {
        let k_inv = self.k().try_inverse()?;
        let h = k_inv * nalgebra::Vector3::new(uv.x, uv.y, 1.0);
        Some(
            self.intrinsics
                .pixel_from_ideal(&Vector2::new(h.x / h.z, h.y / h.z)),
        )
    }

    /// The undistorted ellipse of a detected one: points on the detected ellipse mapped through
    /// the undistortion and refitted (refitting undistorted edge points is exact, math §3.4;
    /// a detected ellipse stands for its edge to a hundredth of a pixel).
    #[must_use]
    pub fn undistort_ellipse(&self, detected: &Ellipse) -> Option<Ellipse> {
        let pts: Vec<Vector2<f64>> = (0..ELLIPSE_SAMPLES)
            .map(|k| {
                self.undistort(
                    &detected.point(std::f64::consts::TAU * k as f64 / ELLIPSE_SAMPLES as f64),
                )
            })
            .collect::<Option<_>>()?;
        fit_ellipse_direct(&pts)
    }
}

/// A detected target in one frame, in undistorted pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TargetObservation {
    /// Frame index.
    pub frame: usize,
    /// Index of the detection in its frame.
    pub index: usize,
    /// The detected ellipse (observed pixels).
    pub detected: Ellipse,
    /// The ellipse in undistorted pixels.
    pub ellipse: Ellipse,
    /// Its normalised point conic.
    pub conic: Matrix3<f64>,
}

impl TargetObservation {
    /// The undistorted ellipse centre.
    #[must_use]
    pub fn centre(&self) -> Vector2<f64> {
        self.ellipse.centre()
    }
}

/// The targets of one frame in undistorted pixels (detections that cannot be undistorted are
/// left out).
#[must_use]
pub fn observations(
    frame: usize,
    camera: &FrameCamera,
    detected: &[Ellipse],
) -> Vec<TargetObservation> {
    detected
        .iter()
        .enumerate()
        .filter_map(|(index, d)| {
            let ellipse = camera.undistort_ellipse(d)?;
            Some(TargetObservation {
                frame,
                index,
                detected: *d,
                ellipse,
                conic: ellipse.to_conic(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::conic::conic_of_circle;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    #[test]
    fn undistorting_a_distorted_circle_image_gives_the_pinhole_conic() {
        let cam = FrameCamera {
            intrinsics: Intrinsics {
                k1: 0.0125,
                k2: -0.0094,
                p1: 1.6e-4,
                p2: -2.1e-4,
                ..Intrinsics::pinhole(3050.0, 1931.4, 1074.6)
            },
            cam_from_world: Isometry3::from_parts(
                Translation3::new(0.3, -0.2, 3.0),
                UnitQuaternion::from_euler_angles(0.2, -0.3, 0.1),
            ),
        };
        let (centre, normal, r) = (
            Vector3::new(0.5, 0.3, 0.2),
            Vector3::new(0.2, -0.1, -1.0).normalize(),
            0.04,
        );
        // The distorted edge: circle points through the full model, then the detected ellipse.
        let u = normal.cross(&Vector3::x()).normalize();
        let v = normal.cross(&u);
        let edge: Vec<Vector2<f64>> = (0..720)
            .map(|k| {
                let phi = std::f64::consts::TAU * f64::from(k) / 720.0;
                let p = centre + (u * phi.cos() + v * phi.sin()) * r;
                cam.intrinsics
                    .project(
                        &(cam.cam_from_world.rotation * p + cam.cam_from_world.translation.vector),
                    )
                    .unwrap()
            })
            .collect();
        let detected = fit_ellipse_direct(&edge).unwrap();
        let und = cam.undistort_ellipse(&detected).unwrap();
        let exact = Ellipse::from_conic(
            &conic_of_circle(&cam.k(), &cam.cam_from_world, &centre, &normal, r).unwrap(),
        )
        .unwrap();
        assert!(
            (und.centre() - exact.centre()).norm() < 2e-3,
            "{und:?} vs {exact:?}"
        );
        assert!((und.a - exact.a).abs() < 2e-3 && (und.b - exact.b).abs() < 2e-3);
        // Round trip of single pixels.
        let uv = Vector2::new(100.0, 2000.0);
        assert!((cam.distort(&cam.undistort(&uv).unwrap()).unwrap() - uv).norm() < 1e-9);
    }
}
