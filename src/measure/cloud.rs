//! A point cloud prepared for fitting: coordinates around a local origin (TLS coordinates are
//! large; f64 keeps them exact, the local origin keeps the sums well conditioned), a k-d tree
//! (kiddo) and normals from a robust PCA of each point's nearest neighbours.

use std::num::NonZero;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

/// A cloud around a local origin, with unit normals.
#[derive(Clone, Debug)]
pub struct Cloud {
    /// The local origin in the input frame (the points' mean).
    pub origin: Vector3<f64>,
    /// Points relative to `origin`.
    pub points: Vec<Vector3<f64>>,
    /// Unit normal per point (sign arbitrary).
    pub normals: Vec<Vector3<f64>>,
    /// Per point, the RMS distance of its neighbours from their robust plane (m): the local
    /// noise (curvature at the scale of k neighbours is far below it for pipes).
    pub point_noise: Vec<f64>,
    /// Robust scale (m) of the points about their local planes: 1.4826 × the median of the
    /// neighbourhoods' RMS plane distances. Noise plus curvature at the scale of k neighbours.
    pub surface_noise: f64,
}

/// Neighbours used for each normal.
pub const NORMAL_NEIGHBOURS: usize = 16;

/// Why a cloud cannot be prepared.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CloudError {
    /// Too few finite points.
    #[error("the cloud has {found} finite points; at least {required} are needed")]
    TooFewPoints {
        /// Finite points found.
        found: usize,
        /// Points needed.
        required: usize,
    },
    /// The k-d tree could not be built.
    #[error("cannot index the cloud: {0}")]
    Index(String),
}

/// The mean of the finite points, accumulated relative to the first one (exact for clouds far
/// from the origin).
fn local_origin(points: &[Vector3<f64>]) -> Vector3<f64> {
    let first = points[0];
    let sum: Vector3<f64> = points.iter().map(|p| p - first).sum();
    first + sum / points.len() as f64
}

/// The plane normal and RMS plane distance of a neighbourhood (smallest eigenvector of the
/// covariance), with one reweighting pass that drops neighbours farther than 2.5 robust σ from
/// the first plane (robust PCA: an edge or a second surface in the neighbourhood does not tilt
/// the normal).
fn robust_normal(nb: &[Vector3<f64>]) -> Option<(Vector3<f64>, f64)> {
    let fit = |pts: &mut dyn Iterator<Item = &Vector3<f64>>| -> Option<(Vector3<f64>, Vector3<f64>, f64)> {
        let pts: Vec<&Vector3<f64>> = pts.collect();
        if pts.len() < 3 {
            return None;
        }
        let n = pts.len() as f64;
        let mean: Vector3<f64> = pts.iter().copied().sum::<Vector3<f64>>() / n;
        let mut cov = Matrix3::zeros();
        for p in &pts {
            let d = *p - mean;
            cov += d * d.transpose();
        }
        cov /= n;
        let eig = SymmetricEigen::new(cov);
        let (k, lmin) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))?;
        Some((eig.eigenvectors.column(k).into_owned(), mean, lmin.max(0.0)))
    };
    let (n0, m0, _) = fit(&mut nb.iter())?;
    let mut d: Vec<f64> = nb.iter().map(|p| (p - m0).dot(&n0).abs()).collect();
    let mut sorted = d.clone();
    sorted.sort_by(f64::total_cmp);
    let scale = 1.4826 * sorted[sorted.len() / 2];
    let limit = (2.5 * scale).max(1e-12);
    let keep: Vec<bool> = d.iter().map(|v| *v <= limit).collect();
    let (n1, _, l1) = fit(&mut nb.iter().zip(&keep).filter(|(_, k)| **k).map(|(p, _)| p))
        .unwrap_or((n0, m0, 0.0));
    d.clear();
    Some((n1.normalize(), l1.sqrt()))
}

impl Cloud {
    /// Prepares a cloud: drops non-finite points, moves to the local origin, builds the k-d
    /// tree and estimates the normals (in parallel; deterministic).
    ///
    /// # Errors
    /// [`CloudError::TooFewPoints`] for fewer than [`NORMAL_NEIGHBOURS`] finite points.
    pub fn new(input: &[Vector3<f64>]) -> Result<Self, CloudError> {
        let finite: Vec<Vector3<f64>> = input
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .copied()
            .collect();
        if finite.len() < NORMAL_NEIGHBOURS {
            return Err(CloudError::TooFewPoints {
                found: finite.len(),
                required: NORMAL_NEIGHBOURS,
            });
        }
        let origin = local_origin(&finite);
        let points: Vec<Vector3<f64>> = finite.iter().map(|p| p - origin).collect();
        let entries: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&entries)
            .map_err(|e| CloudError::Index(format!("{e:?}")))?;
        let k = NonZero::new(NORMAL_NEIGHBOURS).unwrap_or(NonZero::<usize>::MIN);
        let with_scale: Vec<(Vector3<f64>, f64)> = entries
            .par_iter()
            .map(|q| {
                let nb: Vec<Vector3<f64>> = tree
                    .query(q)
                    .nearest_n::<SquaredEuclidean<f64>>(k)
                    .execute()
                    .iter()
                    .map(|r| points[r.item as usize])
                    .collect();
                robust_normal(&nb).unwrap_or((Vector3::z(), f64::NAN))
            })
            .collect();
        let mut scales: Vec<f64> = with_scale
            .iter()
            .map(|(_, s)| *s)
            .filter(|s| s.is_finite())
            .collect();
        scales.sort_by(f64::total_cmp);
        let surface_noise = 1.4826 * scales.get(scales.len() / 2).copied().unwrap_or(0.0);
        Ok(Cloud {
            origin,
            points,
            point_noise: with_scale
                .iter()
                .map(|(_, s)| if s.is_finite() { *s } else { surface_noise })
                .collect(),
            normals: with_scale.into_iter().map(|(n, _)| n).collect(),
            surface_noise,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_normals_and_a_far_origin() {
        // A 40×40 grid on the plane z = 2 + 0.1·x, a million metres from the origin.
        let offset = Vector3::new(1.0e6, -2.0e6, 500.0);
        let pts: Vec<Vector3<f64>> = (0..1600)
            .map(|i| {
                let (x, y) = (f64::from(i % 40) * 0.01, f64::from(i / 40) * 0.01);
                offset + Vector3::new(x, y, 2.0 + 0.1 * x)
            })
            .collect();
        let c = Cloud::new(&pts).unwrap();
        let n = Vector3::new(-0.1, 0.0, 1.0).normalize();
        for m in &c.normals {
            assert!(m.dot(&n).abs() > 1.0 - 1e-9, "{m}");
        }
        assert!((c.origin - (offset + Vector3::new(0.195, 0.195, 2.0195))).norm() < 1e-6);
        assert!(c.surface_noise < 1e-6);
    }

    #[test]
    fn nan_points_are_dropped_and_too_few_is_an_error() {
        let mut pts = vec![Vector3::new(f64::NAN, 0.0, 0.0); 5];
        pts.push(Vector3::zeros());
        assert_eq!(
            Cloud::new(&pts).unwrap_err(),
            CloudError::TooFewPoints {
                found: 1,
                required: NORMAL_NEIGHBOURS
            }
        );
    }
}
