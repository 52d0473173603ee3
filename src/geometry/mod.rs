//! Geometry value types and small exact computations shared by every stage (layer 1): poses,
//! conics and ellipses, triangulation.
//!
//! Poses follow COLMAP's `cam_from_world` naming: see the crate's `# Conventions`.

pub mod conic;
pub mod eccentricity;
pub mod epipolar;
pub mod pose;
pub mod quan;
pub mod solid;
pub mod triangulation;

pub use conic::Ellipse;
pub use pose::Rigid3;

use nalgebra::Vector3;

/// An orthonormal basis `(u, v)` of the plane through the origin with unit normal `n`, with
/// `(u, v, n)` right-handed: `u = h × n / |h × n|` for the helper `h` = z (x when `n` is
/// within 26° of z, where z × n would be short), `v = n × u`. The one construction the
/// simulator, the targets' planes and Quan's conic share, so their frames agree bit for bit.
#[must_use]
pub fn plane_basis(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if n.z.abs() < 0.9 {
        Vector3::z()
    } else {
        Vector3::x()
    };
    let u = helper.cross(n).normalize();
    (u, n.cross(&u))
}

/// The corners `(lo, hi)` of the axis-aligned bounding box of `points` (infinite, inverted,
/// for none).
pub fn bounds(points: impl IntoIterator<Item = Vector3<f64>>) -> (Vector3<f64>, Vector3<f64>) {
    points.into_iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(&p), hi.sup(&p)),
    )
}
