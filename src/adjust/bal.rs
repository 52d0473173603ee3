//! The BAL benchmark problem as a [`Problem`] over [`BalModel`].

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};

use super::AdjustError;
use super::model::BalModel;
use super::problem::{Observation, Problem};
use crate::io::bal::BalProblem;

/// Builds the adjustment problem of a BAL file: poses from the Rodrigues vectors and
/// translations, per-camera `(f, k1, k2)`, unit weights.
///
/// # Errors
/// [`AdjustError`] if the file's indices are inconsistent.
pub fn problem_from_bal(bal: &BalProblem) -> Result<Problem<BalModel>, AdjustError> {
    let poses = bal
        .cameras
        .iter()
        .map(|c| {
            Isometry3::from_parts(
                Translation3::new(c[3], c[4], c[5]),
                UnitQuaternion::from_scaled_axis(Vector3::new(c[0], c[1], c[2])),
            )
        })
        .collect();
    let local = bal
        .cameras
        .iter()
        .flat_map(|c| [c[6], c[7], c[8]])
        .collect();
    let points = bal
        .points
        .iter()
        .map(|p| Vector3::new(p[0], p[1], p[2]))
        .collect();
    let observations = bal
        .observations
        .iter()
        .map(|o| Observation {
            camera: o.camera,
            point: o.point,
            uv: Vector2::new(o.xy[0], o.xy[1]),
            weight: 1.0,
            time_offset_s: 0.0,
        })
        .collect();
    Problem::new(BalModel, poses, local, Vec::new(), points, observations)
}
