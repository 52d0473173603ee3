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
