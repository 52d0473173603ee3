//! A point cloud prepared for fitting: coordinates around a local origin (TLS coordinates are
//! large; f64 keeps them exact, the local origin keeps the sums well conditioned), and per point
//! a normal and a local noise from a robust PCA of its k nearest neighbours.
//!
//! The local geometry is computed on demand ([`Cloud::prepare`], [`Cloud::local`]) and kept:
//! a fit reads it for its subsample and for the points near its candidate cylinders, not for a
//! wall or a floor far from any pipe. The k nearest neighbours come from a k-d tree (kiddo),
//! queried in batches along a Z-order (Morton) curve so that consecutive queries share the
//! cache (twice as fast as in input order).

use std::num::NonZero;
use std::sync::OnceLock;

use kiddo::leaf_strategy::FlatVec;
use kiddo::{Eytzinger, KdTree, SquaredEuclidean};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

/// A cloud around a local origin; normals and local noise on demand.
pub struct Cloud {
    /// The local origin in the input frame (the points' mean).
    pub origin: Vector3<f64>,
    /// Points relative to `origin`.
    pub points: Vec<Vector3<f64>>,
    /// Robust scale (m) of the points about their local planes: 1.4826 × the median of the
    /// neighbourhoods' RMS plane distances (over an evenly strided subsample of at most
    /// [`NOISE_SAMPLE`] points). Noise plus curvature at the scale of k neighbours.
    pub surface_noise: f64,
    /// The largest local noise a consensus threshold uses (m): the 99th percentile of the
    /// subsample's. A point in a sparser neighbourhood gets no wider threshold.
    pub noise_cap: f64,
    morton: Morton,
    tree: Tree,
    /// Per point: unit normal (sign arbitrary) and the RMS distance of its neighbours from
    /// their robust plane (m), once computed.
    local: Vec<OnceLock<(Vector3<f64>, f64)>>,
}

impl std::fmt::Debug for Cloud {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Cloud")
            .field("origin", &self.origin)
            .field("points", &self.points.len())
            .field("surface_noise", &self.surface_noise)
            .field("noise_cap", &self.noise_cap)
            .finish_non_exhaustive()
    }
}

/// The k-d tree: flat leaves of 16 points (a fifth faster for 16-neighbour queries than
/// kiddo's default immutable tree with 32-point arenas, and quicker to build).
type Tree = KdTree<f64, u32, Eytzinger, FlatVec<f64, u32, 3, 16>, 3, 16>;

/// Per-thread query scratch of [`Tree`].
type Scratch = kiddo::QueryScratch<Eytzinger, f64, 3>;

/// Points whose local noise sets [`Cloud::surface_noise`] and [`Cloud::noise_cap`].
pub const NOISE_SAMPLE: usize = 32_768;

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

/// Bits per axis of the Morton codes.
const MORTON_BITS: u32 = 21;

/// Spreads the low 21 bits of `v` two zero bits apart.
fn spread21(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    (x | (x << 2)) & 0x1249_2492_4924_9249
}

/// The points' order along a Z-order curve over their bounding box.
struct Morton {
    lo: Vector3<f64>,
    /// Cells per metre per axis.
    scale: Vector3<f64>,
    /// Point indices in curve order (ties by index).
    order: Vec<u32>,
    /// Position of each point in `order`.
    rank: Vec<u32>,
}

impl Morton {
    fn new(points: &[Vector3<f64>]) -> Self {
        let lo = points
            .iter()
            .fold(Vector3::repeat(f64::INFINITY), |m, p| m.inf(p));
        let hi = points
            .iter()
            .fold(Vector3::repeat(f64::NEG_INFINITY), |m, p| m.sup(p));
        let cells = f64::from((1u32 << MORTON_BITS) - 1);
        let scale = (hi - lo).map(|v| if v > 0.0 { cells / v } else { 0.0 });
        let mut m = Morton {
            lo,
            scale,
            order: Vec::new(),
            rank: Vec::new(),
        };
        let mut keyed: Vec<(u64, u32)> = points
            .par_iter()
            .enumerate()
            .map(|(i, p)| (m.code(p), i as u32))
            .collect();
        keyed.par_sort_unstable();
        m.rank = vec![0; points.len()];
        for (pos, &(_, i)) in keyed.iter().enumerate() {
            m.rank[i as usize] = pos as u32;
        }
        m.order = keyed.into_iter().map(|(_, i)| i).collect();
        m
    }

    /// The Z-order code of `p`'s cell (per axis clamped to the box).
    fn code(&self, p: &Vector3<f64>) -> u64 {
        let max = f64::from((1u32 << MORTON_BITS) - 1);
        let c = (p - self.lo).component_mul(&self.scale);
        let [x, y, z] = [c.x, c.y, c.z].map(|v| v.clamp(0.0, max) as u64);
        spread21(x) | (spread21(y) << 1) | (spread21(z) << 2)
    }
}

impl Cloud {
    /// Prepares a cloud: drops non-finite points, moves to the local origin, orders the points
    /// along a Z-order curve, builds the k-d tree and estimates the noise scale from an evenly
    /// strided subsample (in parallel; deterministic).
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
        let points: Vec<Vector3<f64>> = finite.par_iter().map(|p| p - origin).collect();
        let morton = Morton::new(&points);
        // The tree's items are positions along the curve: built from sorted entries, its
        // leaves hold spatially coherent runs.
        let entries: Vec<[f64; 3]> = morton
            .order
            .iter()
            .map(|&i| {
                let p = points[i as usize];
                [p.x, p.y, p.z]
            })
            .collect();
        let tree =
            Tree::new_from_slice(&entries).map_err(|e| CloudError::Index(format!("{e:?}")))?;
        let n = points.len();
        let mut cloud = Cloud {
            origin,
            local: (0..n).map(|_| OnceLock::new()).collect(),
            points,
            surface_noise: 0.0,
            noise_cap: 0.0,
            morton,
            tree,
        };
        // The noise scale from every `stride`-th point along the curve (spread evenly).
        let stride = n.div_ceil(NOISE_SAMPLE);
        let subsample: Vec<usize> = (0..n)
            .step_by(stride)
            .map(|pos| cloud.morton.order[pos] as usize)
            .collect();
        cloud.prepare(&subsample);
        let mut scales: Vec<f64> = subsample
            .iter()
            .map(|&k| cloud.local(k).1)
            .filter(|s| s.is_finite())
            .collect();
        scales.sort_by(f64::total_cmp);
        let quantile = |q: f64| {
            scales
                .get(((scales.len() as f64 * q) as usize).min(scales.len().saturating_sub(1)))
                .copied()
                .unwrap_or(0.0)
        };
        cloud.surface_noise = 1.4826 * quantile(0.5);
        cloud.noise_cap = quantile(0.99).max(cloud.surface_noise);
        Ok(cloud)
    }

    /// Points whose local geometry has been computed.
    #[must_use]
    pub fn computed(&self) -> usize {
        self.local.iter().filter(|l| l.get().is_some()).count()
    }

    /// Number of points.
    #[must_use]
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the cloud has no points (never, once built).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Computes the local geometry of the points `idx` that lack it, in parallel in Z-order
    /// (neighbouring queries share the cache).
    pub fn prepare(&self, idx: &[usize]) {
        let mut missing: Vec<u32> = idx
            .iter()
            .filter(|&&k| self.local[k].get().is_none())
            .map(|&k| self.morton.rank[k])
            .collect();
        missing.par_sort_unstable();
        missing.dedup();
        missing.par_iter().for_each_init(
            || self.tree.create_scratch::<SquaredEuclidean<f64>>(),
            |scratch, &pos| {
                let k = self.morton.order[pos as usize] as usize;
                let _ = self.local[k].set(self.compute_local(k, Some(scratch)));
            },
        );
    }

    /// Unit normal (sign arbitrary) and local noise of point `k`, computed on first use.
    #[must_use]
    pub fn local(&self, k: usize) -> (Vector3<f64>, f64) {
        *self.local[k].get_or_init(|| self.compute_local(k, None))
    }

    /// Robust PCA of the point's [`NORMAL_NEIGHBOURS`] nearest neighbours (itself included);
    /// a neighbourhood without a plane gets the z axis and an infinite noise.
    fn compute_local(&self, k: usize, scratch: Option<&mut Scratch>) -> (Vector3<f64>, f64) {
        let mut nb = [Vector3::zeros(); NORMAL_NEIGHBOURS];
        let found = self.nearest(k, &mut nb, scratch);
        robust_normal(&nb[..found])
            .filter(|(_, s)| s.is_finite())
            .unwrap_or((Vector3::z(), f64::INFINITY))
    }

    /// The [`NORMAL_NEIGHBOURS`] nearest points of point `k` (itself included) into `out`;
    /// returns how many.
    fn nearest(
        &self,
        k: usize,
        out: &mut [Vector3<f64>; NORMAL_NEIGHBOURS],
        scratch: Option<&mut Scratch>,
    ) -> usize {
        let q = self.points[k];
        let q = [q.x, q.y, q.z];
        let nn = NonZero::new(NORMAL_NEIGHBOURS).unwrap_or(NonZero::<usize>::MIN);
        let query = self.tree.query(&q).nearest_n::<SquaredEuclidean<f64>>(nn);
        // A caller's scratch saves kiddo's thread-local lookup per query.
        let found = match scratch {
            Some(s) => query.with_scratch(s).execute(),
            None => query.execute(),
        };
        for (slot, r) in out.iter_mut().zip(&found) {
            *slot = self.points[self.morton.order[r.item as usize] as usize];
        }
        found.len().min(NORMAL_NEIGHBOURS)
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
        for k in 0..c.len() {
            let m = c.local(k).0;
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
