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

/// Least-squares plane of `points`: (unit normal, mean, smallest eigenvalue of the covariance,
/// i.e. the mean squared distance from the plane); `None` for fewer than three points. No
/// allocation.
pub(crate) fn plane_of(
    points: impl Iterator<Item = Vector3<f64>> + Clone,
) -> Option<(Vector3<f64>, Vector3<f64>, f64)> {
    let mut n = 0usize;
    let mut mean = Vector3::zeros();
    for p in points.clone() {
        mean += p;
        n += 1;
    }
    if n < 3 {
        return None;
    }
    mean /= n as f64;
    let mut cov = Matrix3::zeros();
    for p in points {
        let d = p - mean;
        cov += d * d.transpose();
    }
    cov /= n as f64;
    let (normal, lmin) = smallest_eigen(&cov)?;
    Some((normal, mean, lmin.max(0.0)))
}

/// [`plane_of`] the points of `pts` whose `keep` flag is set.
fn plane_fit(pts: &[Vector3<f64>], keep: &[bool]) -> Option<(Vector3<f64>, Vector3<f64>, f64)> {
    plane_of(pts.iter().zip(keep).filter(|(_, k)| **k).map(|(p, _)| *p))
}

/// The smallest eigenvalue of a symmetric 3×3 matrix and its unit eigenvector, in closed form
/// (trigonometric eigenvalues, the eigenvector as the largest cross product of two rows of
/// `A − λI`): far cheaper than an iterative decomposition for millions of neighbourhoods. Falls
/// back to the iterative one when the smallest eigenvalue is (nearly) repeated.
fn smallest_eigen(a: &Matrix3<f64>) -> Option<(Vector3<f64>, f64)> {
    let p1 = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    let q = a.trace() / 3.0;
    let p2 = (a[(0, 0)] - q).powi(2) + (a[(1, 1)] - q).powi(2) + (a[(2, 2)] - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    if !(p > 0.0 && p.is_finite()) {
        return None;
    }
    let b = (a - Matrix3::identity() * q) / p;
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let lmin = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    let m = a - Matrix3::identity() * lmin;
    let (r0, r1, r2) = (
        m.row(0).transpose(),
        m.row(1).transpose(),
        m.row(2).transpose(),
    );
    let candidates = [r0.cross(&r1), r0.cross(&r2), r1.cross(&r2)];
    let best = candidates
        .iter()
        .max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared()))?;
    let scale = m.norm_squared();
    if best.norm_squared() > 1e-20 * scale * scale {
        return Some((best.normalize(), lmin));
    }
    let eig = SymmetricEigen::new(*a);
    let (k, l) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|x, y| x.1.total_cmp(y.1))?;
    Some((eig.eigenvectors.column(k).normalize(), *l))
}

/// The plane normal and RMS plane distance of a neighbourhood (at most [`NORMAL_NEIGHBOURS`]
/// points), with one reweighting pass that drops neighbours farther than 2.5 robust σ from the
/// first plane (robust PCA: an edge or a second surface in the neighbourhood does not tilt the
/// normal).
fn robust_normal(nb: &[Vector3<f64>]) -> Option<(Vector3<f64>, f64)> {
    let m = nb.len().min(NORMAL_NEIGHBOURS);
    let nb = &nb[..m];
    let mut keep = [true; NORMAL_NEIGHBOURS];
    let (n0, m0, _) = plane_fit(nb, &keep[..m])?;
    let mut d = [0.0; NORMAL_NEIGHBOURS];
    for (v, p) in d.iter_mut().zip(nb) {
        *v = (p - m0).dot(&n0).abs();
    }
    let mut sorted = d;
    sorted[..m].sort_unstable_by(f64::total_cmp);
    let limit = (2.5 * 1.4826 * sorted[m / 2]).max(1e-12);
    for (k, v) in keep.iter_mut().zip(&d[..m]) {
        *k = *v <= limit;
    }
    let (n1, _, l1) = plane_fit(nb, &keep[..m]).unwrap_or((n0, m0, 0.0));
    Some((n1, l1.sqrt()))
}

/// Indices of `points` sorted along a Z-order curve over their bounding box (10 bits per
/// axis), ties by index.
fn morton_order(points: &[Vector3<f64>]) -> Vec<usize> {
    let lo = points
        .iter()
        .fold(Vector3::repeat(f64::INFINITY), |m, p| m.inf(p));
    let hi = points
        .iter()
        .fold(Vector3::repeat(f64::NEG_INFINITY), |m, p| m.sup(p));
    let span = (hi - lo).map(|v| v.max(1e-300));
    let spread = |v: u64| -> u64 {
        // Interleave the low 10 bits of v with two zero bits between each.
        let mut x = v & 0x3ff;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    };
    let mut keyed: Vec<(u64, usize)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let c = (p - lo).component_div(&span) * 1023.0;
            let key = spread(c.x as u64) | (spread(c.y as u64) << 1) | (spread(c.z as u64) << 2);
            (key, i)
        })
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
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
        // Queries in Morton (Z-curve) order, so that consecutive queries visit the same
        // leaves of the tree: the k-NN search dominates and random order defeats the cache.
        let order = morton_order(&points);
        let sorted_results: Vec<(Vector3<f64>, f64)> = order
            .par_iter()
            .map(|&i| {
                let q = &entries[i];
                let mut nb = [Vector3::zeros(); NORMAL_NEIGHBOURS];
                let found = tree
                    .query(q)
                    .nearest_n::<SquaredEuclidean<f64>>(k)
                    .execute();
                for (slot, r) in nb.iter_mut().zip(&found) {
                    *slot = points[r.item as usize];
                }
                robust_normal(&nb[..found.len().min(NORMAL_NEIGHBOURS)])
                    .unwrap_or((Vector3::z(), f64::NAN))
            })
            .collect();
        let mut with_scale = vec![(Vector3::z(), f64::NAN); points.len()];
        for (&i, r) in order.iter().zip(sorted_results) {
            with_scale[i] = r;
        }
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
    fn closed_form_smallest_eigenvector_matches_the_iterative_one() {
        let m = Matrix3::new(4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 0.01);
        let (v, l) = smallest_eigen(&m).unwrap();
        let eig = SymmetricEigen::new(m);
        let (k, l_ref) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|x, y| x.1.total_cmp(y.1))
            .unwrap();
        assert!((l - l_ref).abs() < 1e-12, "{l} vs {l_ref}");
        assert!(v.dot(&eig.eigenvectors.column(k)).abs() > 1.0 - 1e-12);
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
