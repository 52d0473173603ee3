//! Rigid poses `b_from_a`, their COLMAP form and the local update used by every Jacobian.
//!
//! A pose `cam_from_world` maps `p_cam = R·p_world + t` (COLMAP's world-to-camera convention).
//! The local perturbation used throughout the crate (Jacobians in [`crate::camera`], the bundle
//! adjustment) is
//!
//! ```text
//! p_cam(δ) = exp([δω]×)·R·p_world + t + δt,        δ = (δω, δt) ∈ R⁶
//! ```
//!
//! so `∂p_cam/∂δω = −[R·p_world]×` and `∂p_cam/∂δt = I`; [`retract`] applies such a step.

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3, Vector6};

/// A rigid transform `b_from_a` (rotation then translation): `p_b = R·p_a + t`.
pub type Rigid3 = Isometry3<f64>;

/// Builds `cam_from_world` from COLMAP's `qvec = (qw, qx, qy, qz)` and `tvec`.
///
/// The quaternion is normalised; COLMAP writes unit quaternions, so this changes nothing but
/// rounding.
#[must_use]
pub fn rigid_from_colmap(qvec: [f64; 4], tvec: [f64; 3]) -> Rigid3 {
    let q = UnitQuaternion::from_quaternion(Quaternion::new(qvec[0], qvec[1], qvec[2], qvec[3]));
    Isometry3::from_parts(Translation3::new(tvec[0], tvec[1], tvec[2]), q)
}

/// COLMAP's `(qvec, tvec)` of a pose, with `qw ≥ 0` as COLMAP normalises it.
#[must_use]
pub fn colmap_from_rigid(pose: &Rigid3) -> ([f64; 4], [f64; 3]) {
    let q = pose.rotation.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    let t = pose.translation.vector;
    ([s * q.w, s * q.i, s * q.j, s * q.k], [t.x, t.y, t.z])
}

/// The projection centre of a camera in world coordinates: `−Rᵀ·t`.
#[must_use]
pub fn camera_centre(cam_from_world: &Rigid3) -> Point3<f64> {
    cam_from_world.inverse() * Point3::origin()
}

/// Applies a local step `δ = (δω, δt)` to a pose as defined in the module documentation:
/// `R ← exp([δω]×)·R`, `t ← t + δt`.
#[must_use]
pub fn retract(pose: &Rigid3, delta: &Vector6<f64>) -> Rigid3 {
    let omega = Vector3::new(delta[0], delta[1], delta[2]);
    let dt = Vector3::new(delta[3], delta[4], delta[5]);
    let rotation = UnitQuaternion::from_scaled_axis(omega) * pose.rotation;
    Isometry3::from_parts(Translation3::from(pose.translation.vector + dt), rotation)
}

/// The skew-symmetric matrix `[v]×` with `[v]×·w = v × w`.
#[must_use]
pub fn skew(v: &Vector3<f64>) -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colmap_round_trip_is_exact_for_unit_quaternions() {
        let q = UnitQuaternion::from_euler_angles(0.3, -1.2, 2.5);
        let pose = Isometry3::from_parts(Translation3::new(1.5, -2.0, 0.25), q);
        let (qvec, tvec) = colmap_from_rigid(&pose);
        assert!(qvec[0] >= 0.0);
        let back = rigid_from_colmap(qvec, tvec);
        let p = Point3::new(0.7, 0.1, -3.0);
        assert!(((back * p) - (pose * p)).norm() < 1e-14);
    }

    #[test]
    fn camera_centre_maps_to_camera_origin() {
        let pose = Isometry3::from_parts(
            Translation3::new(0.2, 0.3, 4.0),
            UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
        );
        let centre = camera_centre(&pose);
        assert!((pose * centre).coords.norm() < 1e-14);
    }

    #[test]
    fn retract_matches_first_order_perturbation() {
        let pose = Isometry3::from_parts(
            Translation3::new(0.2, 0.3, 4.0),
            UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
        );
        let p = Point3::new(1.0, -0.5, 2.0);
        let delta = Vector6::new(1e-7, -2e-7, 3e-7, 1e-6, 2e-6, -1e-6);
        let moved = retract(&pose, &delta) * p;
        let rp = pose.rotation * p.coords;
        let omega = Vector3::new(delta[0], delta[1], delta[2]);
        let dt = Vector3::new(delta[3], delta[4], delta[5]);
        let predicted = (pose * p).coords - skew(&rp) * omega + dt;
        assert!((moved.coords - predicted).norm() < 1e-12);
    }
}
