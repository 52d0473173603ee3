//! The eccentricity of a circle's image (docs/math.md §3): the offset of the imaged ellipse's
//! centre from the image of the circle's centre, by the closed form of Luhmann (2014) in its
//! exact conic form (math §3.2). It needs the circle's 3D centre, unit normal and radius —
//! object-space knowledge that Algorithm 3 does without.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::Rigid3;
use super::conic::{Ellipse, conic_of_circle};

/// The eccentricity vector `e = x_ellipse − x_centre` (px) of a circle (centre, unit normal,
/// radius, world) seen by the camera `K [R | t]`. `None` if the circle is not seen as an
/// ellipse (behind the camera, edge-on).
#[must_use]
pub fn luhmann_eccentricity(
    k: &Matrix3<f64>,
    cam_from_world: &Rigid3,
    centre: &Vector3<f64>,
    normal: &Vector3<f64>,
    radius: f64,
) -> Option<Vector2<f64>> {
    let conic = conic_of_circle(k, cam_from_world, centre, normal, radius)?;
    let ellipse = Ellipse::from_conic(&conic)?;
    let p = k * (cam_from_world.rotation * centre + cam_from_world.translation.vector);
    if p.z <= 0.0 {
        return None;
    }
    Some(ellipse.centre() - Vector2::new(p.x / p.z, p.y / p.z))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, UnitQuaternion};

    /// The on-axis case (math §3.1): a circle of radius r at depth Z on the optical axis tilted
    /// by α about the image x axis moves by `c r² sin 2α / (2 (Z² − r² sin² α))` along v.
    #[test]
    fn on_axis_eccentricity_matches_the_closed_formula() {
        let c = 3000.0;
        let k = Matrix3::new(c, 0.0, 0.0, 0.0, c, 0.0, 0.0, 0.0, 1.0);
        let (r, z) = (0.05, 2.0);
        for deg in [10.0f64, 30.0, 45.0, 70.0] {
            let a = deg.to_radians();
            let normal =
                UnitQuaternion::from_euler_angles(a, 0.0, 0.0) * Vector3::new(0.0, 0.0, -1.0);
            let e = luhmann_eccentricity(
                &k,
                &Isometry3::identity(),
                &Vector3::new(0.0, 0.0, z),
                &normal,
                r,
            )
            .unwrap();
            let expected = c * r * r * (2.0 * a).sin() / (2.0 * (z * z - r * r * a.sin().powi(2)));
            assert!(e.x.abs() < 1e-9, "{e}");
            assert!(
                (e.y.abs() - expected).abs() < 1e-9,
                "α {deg}°: {} vs {expected}",
                e.y
            );
        }
    }
}
