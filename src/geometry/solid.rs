//! parry3d solids from the project's geometry: the one conversion the plant-room simulator and
//! the pipe network's clearances share (parry's cylinder lies along its local y axis, centred).

use nalgebra::Vector3;
use parry3d_f64::math::{Pose, Rotation, Vector};
use parry3d_f64::shape::Cylinder;

/// A parry vector from a nalgebra one.
#[must_use]
pub fn vector(p: &Vector3<f64>) -> Vector {
    Vector::new(p.x, p.y, p.z)
}

/// The solid cylinder of radius `radius` whose axis runs from `a` to `b`, with its pose.
#[must_use]
pub fn cylinder_between(a: &Vector3<f64>, b: &Vector3<f64>, radius: f64) -> (Pose, Cylinder) {
    let (a, b) = (vector(a), vector(b));
    let axis = b - a;
    let rotation = Rotation::from_rotation_arc(Vector::Y, axis.normalize());
    (
        Pose::from_parts((a + b) * 0.5, rotation),
        Cylinder::new(axis.length() * 0.5, radius),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use parry3d_f64::query::PointQuery;

    #[test]
    fn the_cylinder_spans_its_two_points() {
        let (a, b) = (Vector3::new(1.0, 2.0, 3.0), Vector3::new(4.0, 6.0, 3.0));
        let (pose, c) = cylinder_between(&a, &b, 0.5);
        // Both end centres on the boundary, the middle inside, a point 0.5 off the axis at the
        // middle on the surface.
        for p in [a, b] {
            assert!(c.distance_to_point(&pose, vector(&p), false) < 1e-12);
        }
        let mid = (a + b) * 0.5;
        assert!(c.contains_point(&pose, vector(&mid)));
        let side = mid + Vector3::new(0.0, 0.0, 0.5);
        assert!(c.distance_to_point(&pose, vector(&side), false) < 1e-12);
        let out = mid + Vector3::new(0.0, 0.0, 0.75);
        assert!((c.distance_to_point(&pose, vector(&out), false) - 0.25).abs() < 1e-12);
    }
}
