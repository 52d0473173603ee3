//! A point cloud prepared for fitting: coordinates around a local origin (TLS coordinates are
//! large; f64 keeps them exact, the local origin keeps the sums well conditioned), and per point
//! a normal and a local noise from a robust PCA of its k nearest neighbours.
//!
//! The local geometry is computed on demand ([`Cloud::prepare`], [`Cloud::local`]) and kept:
//! a fit reads it for its subsample and for the points near its candidate cylinders, not for a
//! wall or a floor far from any pipe. The points are kept along a Z-order (Morton) curve
//! (`measure::zorder`); the methods named `_at` take positions along it, and passes in that
//! order read memory in order. The k nearest neighbours of a large batch (the band around a
//! candidate cylinder) come from the uniform grid sized to the batch's spacing, those of
//! scattered points and of the grid's few refusals from the cells a bound on their reach
//! picks (`zorder::Morton::nearest`); both are exact, and neither needs a tree.

use std::sync::atomic::{AtomicU64, Ordering};

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::zorder::{self, BlockScratch, Grid, Morton, OctreeScratch};
use crate::geometry::bounds;

/// A cloud around a local origin; normals and local noise on demand.
pub struct Cloud {
    /// The local origin in the input frame (the points' mean).
    pub origin: Vector3<f64>,
    /// Robust scale (m) of the points about their local planes: 1.4826 × the median of the
    /// neighbourhoods' RMS plane distances (over an evenly strided subsample of at most
    /// [`NOISE_SAMPLE`] points). Noise plus curvature at the scale of k neighbours.
    pub surface_noise: f64,
    /// The largest local noise a consensus threshold uses (m): the 99th percentile of the
    /// subsample's. A point in a sparser neighbourhood gets no wider threshold.
    pub noise_cap: f64,
    morton: Morton,
    /// The points (relative to `origin`) in curve order (the grids' runs index it); point
    /// `k` of the input's finite points is at [`Cloud::position`]`(k)`.
    sorted: Vec<[f64; 3]>,
    /// Per run of [`BOX_RUN`] curve positions: the centre and half diagonal of its bounding
    /// box (along the curve, a run is a compact patch: a pass can skip a run whose box is
    /// far from what it looks for).
    boxes: Vec<(Vector3<f64>, f64)>,
    /// Per curve position, the local geometry once computed ([`LocalSlots`]).
    local: LocalSlots,
}

/// Per curve position: the unit normal (sign arbitrary) and the RMS distance of the point's
/// neighbours from their robust plane (m), once computed. Four words per point (a
/// `OnceLock` would add a fifth): the normal's coordinates, then the noise's bits
/// complemented, which marks the slot as filled (a noise is never NaN, so its complement is
/// never 0). Zeroed in parallel when the cloud is made: a zeroed allocation would defer the
/// pages' first touch to the fit, where a page read before it is written faults twice.
struct LocalSlots(Vec<[AtomicU64; 4]>);

impl LocalSlots {
    fn new(n: usize) -> Self {
        LocalSlots((0..n).into_par_iter().map(|_| Default::default()).collect())
    }

    fn get(&self, pos: usize) -> Option<(Vector3<f64>, f64)> {
        let slot = &self.0[pos];
        // Acquire: the normal stored before the mark is visible.
        let mark = slot[3].load(Ordering::Acquire);
        (mark != 0).then(|| {
            let c = |a: usize| f64::from_bits(slot[a].load(Ordering::Relaxed));
            (Vector3::new(c(0), c(1), c(2)), f64::from_bits(!mark))
        })
    }

    /// Stores the geometry of `pos` unless it is there already (the first stays, as a
    /// point's geometry from the grid and from the octree may differ in the last bits: the
    /// neighbours are the same, their order may not be).
    fn set(&self, pos: usize, (normal, noise): (Vector3<f64>, f64)) {
        let slot = &self.0[pos];
        if slot[3].load(Ordering::Relaxed) != 0 {
            return;
        }
        for (word, v) in slot.iter().zip(normal.iter()) {
            word.store(v.to_bits(), Ordering::Relaxed);
        }
        slot[3].store(!noise.to_bits(), Ordering::Release);
    }

    fn is_set(&self, pos: usize) -> bool {
        self.0[pos][3].load(Ordering::Acquire) != 0
    }
}

impl std::fmt::Debug for Cloud {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Cloud")
            .field("origin", &self.origin)
            .field("points", &self.len())
            .field("surface_noise", &self.surface_noise)
            .field("noise_cap", &self.noise_cap)
            .finish_non_exhaustive()
    }
}

/// Points whose local noise sets [`Cloud::surface_noise`] and [`Cloud::noise_cap`].
pub const NOISE_SAMPLE: usize = 32_768;

/// Neighbours used for each normal.
pub const NORMAL_NEIGHBOURS: usize = zorder::K;

/// Curve positions per box of [`Cloud::run_box`].
pub const BOX_RUN: usize = 256;

/// Batches of at least this many points are answered by a grid ([`Cloud::prepare`]).
const GRID_BATCH: usize = 8192;

/// Points of a batch whose neighbourhoods size its grid.
const PILOT: usize = 512;

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
    /// The points spread wider than the fit's arithmetic is made for.
    #[error(
        "the cloud's points span {extent_m:e} m along an axis, more than the {limit_m:e} m a cloud may span (coordinates in other units than metres, or stray points)"
    )]
    TooLarge {
        /// The largest span along an axis (may be infinite).
        extent_m: f64,
        /// [`MAX_EXTENT_M`].
        limit_m: f64,
    },
}

/// The widest a cloud may span along an axis (m): 10⁹ m, far beyond any site, yet small enough
/// that every squared distance, sum and product of the fit stays finite (coordinates near 10³⁰⁸
/// overflowed and made the fit panic).
pub const MAX_EXTENT_M: f64 = 1e9;

/// The mean of the finite points, accumulated relative to the first one (exact for clouds far
/// from the origin).
fn local_origin<'a>(points: impl Iterator<Item = &'a Vector3<f64>>) -> Vector3<f64> {
    let (mut first, mut sum, mut n) = (None, Vector3::zeros(), 0usize);
    for p in points {
        sum += p - *first.get_or_insert(*p);
        n += 1;
    }
    first.map_or(Vector3::zeros(), |f| f + sum / n as f64)
}

/// Whether every coordinate of `p` is finite.
fn is_finite(p: &&Vector3<f64>) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// The indices of the finite points of `input` (`found` of them), in input order, or `None`
/// when every point is finite (the usual case).
fn finite_indices(input: &[Vector3<f64>], found: usize) -> Option<Vec<u32>> {
    (found < input.len()).then(|| {
        input
            .iter()
            .enumerate()
            .filter(|(_, p)| is_finite(p))
            .map(|(i, _)| i as u32)
            .collect()
    })
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
    // The six distinct sums of the symmetric covariance (products commute exactly: the same
    // matrix as the full outer products, at two thirds of the work).
    let mut c = [0.0; 6];
    for p in points {
        let d = p - mean;
        c[0] += d.x * d.x;
        c[1] += d.x * d.y;
        c[2] += d.x * d.z;
        c[3] += d.y * d.y;
        c[4] += d.y * d.z;
        c[5] += d.z * d.z;
    }
    let c = c.map(|v| v / n as f64);
    let cov = Matrix3::new(c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5]);
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
pub(crate) fn smallest_eigen(a: &Matrix3<f64>) -> Option<(Vector3<f64>, f64)> {
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

/// The 9th smallest of 16 values (the median [`robust_normal`] takes, `m / 2` from 0): the
/// 53 comparators of Batcher's odd–even merge sort of 16 that it depends on, unrolled and
/// branch-free (a selection on a neighbourhood's distances mispredicts about half its
/// comparisons).
#[rustfmt::skip]
fn median16(v: [u64; 16]) -> u64 {
    let [mut v0, mut v1, mut v2, mut v3, mut v4, mut v5, mut v6, mut v7, mut v8, mut v9, mut v10,
        mut v11, mut v12, mut v13, mut v14, mut v15] = v;
    (v0, v1) = (v0.min(v1), v0.max(v1));
    (v2, v3) = (v2.min(v3), v2.max(v3));
    (v0, v2) = (v0.min(v2), v0.max(v2));
    (v1, v3) = (v1.min(v3), v1.max(v3));
    (v1, v2) = (v1.min(v2), v1.max(v2));
    (v4, v5) = (v4.min(v5), v4.max(v5));
    (v6, v7) = (v6.min(v7), v6.max(v7));
    (v4, v6) = (v4.min(v6), v4.max(v6));
    (v5, v7) = (v5.min(v7), v5.max(v7));
    (v5, v6) = (v5.min(v6), v5.max(v6));
    (v0, v4) = (v0.min(v4), v0.max(v4));
    (v2, v6) = (v2.min(v6), v2.max(v6));
    (v2, v4) = (v2.min(v4), v2.max(v4));
    (v1, v5) = (v1.min(v5), v1.max(v5));
    (v3, v7) = (v3.min(v7), v3.max(v7));
    (v3, v5) = (v3.min(v5), v3.max(v5));
    (v1, v2) = (v1.min(v2), v1.max(v2));
    (v3, v4) = (v3.min(v4), v3.max(v4));
    (v5, v6) = (v5.min(v6), v5.max(v6));
    (v8, v9) = (v8.min(v9), v8.max(v9));
    (v10, v11) = (v10.min(v11), v10.max(v11));
    (v8, v10) = (v8.min(v10), v8.max(v10));
    (v9, v11) = (v9.min(v11), v9.max(v11));
    (v9, v10) = (v9.min(v10), v9.max(v10));
    (v12, v13) = (v12.min(v13), v12.max(v13));
    (v14, v15) = (v14.min(v15), v14.max(v15));
    (v12, v14) = (v12.min(v14), v12.max(v14));
    (v13, v15) = (v13.min(v15), v13.max(v15));
    (v13, v14) = (v13.min(v14), v13.max(v14));
    (v8, v12) = (v8.min(v12), v8.max(v12));
    (v10, v14) = (v10.min(v14), v10.max(v14));
    (v10, v12) = (v10.min(v12), v10.max(v12));
    (v9, v13) = (v9.min(v13), v9.max(v13));
    (v11, v15) = (v11.min(v15), v11.max(v15));
    (v11, v13) = (v11.min(v13), v11.max(v13));
    (v9, v10) = (v9.min(v10), v9.max(v10));
    (v11, v12) = (v11.min(v12), v11.max(v12));
    (v13, v14) = (v13.min(v14), v13.max(v14));
    (v0, v8) = (v0.min(v8), v0.max(v8));
    (v4, v12) = (v4.min(v12), v4.max(v12));
    (v4, v8) = (v4.min(v8), v4.max(v8));
    (v2, v10) = (v2.min(v10), v2.max(v10));
    (v6, v14) = (v6.min(v14), v6.max(v14));
    (v6, v10) = (v6.min(v10), v6.max(v10));
    (v6, v8) = (v6.min(v8), v6.max(v8));
    (v1, v9) = (v1.min(v9), v1.max(v9));
    (v5, v13) = (v5.min(v13), v5.max(v13));
    (v5, v9) = (v5.min(v9), v5.max(v9));
    (v3, v11) = (v3.min(v11), v3.max(v11));
    (v7, v15) = (v7.min(v15), v7.max(v15));
    (v7, v11) = (v7.min(v11), v7.max(v11));
    (v7, v9) = (v7.min(v9), v7.max(v9));
    (v7, v8) = (v7.min(v8), v7.max(v8));
    // The other wires' last values are not needed (they are not the 9th smallest).
    let _ = (v0, v1, v2, v3, v4, v5, v6, v7, v9, v10, v11, v12, v13, v14, v15);
    v8
}

/// The plane normal and RMS plane distance of a neighbourhood (at most [`NORMAL_NEIGHBOURS`]
/// points), with one reweighting pass that drops neighbours farther than 2.5 robust σ from the
/// first plane (robust PCA: an edge or a second surface in the neighbourhood does not tilt the
/// normal).
fn robust_normal(nb: &[Vector3<f64>]) -> Option<(Vector3<f64>, f64)> {
    let m = nb.len().min(NORMAL_NEIGHBOURS);
    let nb = &nb[..m];
    let (n0, m0, l0) = plane_of(nb.iter().copied())?;
    let mut d = [0.0; NORMAL_NEIGHBOURS];
    for (v, p) in d.iter_mut().zip(nb) {
        *v = (p - m0).dot(&n0).abs();
    }
    // The median distance: non-negative floats order like their bits.
    let mut bits = d.map(f64::to_bits);
    let median = if m == NORMAL_NEIGHBOURS {
        median16(bits)
    } else {
        *bits[..m].select_nth_unstable(m / 2).1
    };
    let limit = (2.5 * crate::robust::MAD_TO_SIGMA * f64::from_bits(median)).max(1e-12);
    let mut keep = [true; NORMAL_NEIGHBOURS];
    for (k, v) in keep.iter_mut().zip(&d[..m]) {
        *k = *v <= limit;
    }
    // Nothing dropped: the refit would repeat the first fit.
    if keep[..m].iter().all(|&k| k) {
        return Some((n0, l0.sqrt()));
    }
    let (n1, _, l1) = plane_fit(nb, &keep[..m]).unwrap_or((n0, m0, 0.0));
    Some((n1, l1.sqrt()))
}

impl Cloud {
    /// Prepares a cloud: drops non-finite points, moves to the local origin, orders the points
    /// along a Z-order curve and estimates the noise scale from an evenly strided subsample
    /// (in parallel; deterministic).
    ///
    /// # Errors
    /// [`CloudError::TooFewPoints`] for fewer than [`NORMAL_NEIGHBOURS`] finite points.
    pub fn new(input: &[Vector3<f64>]) -> Result<Self, CloudError> {
        let found = input.par_iter().filter(is_finite).count();
        if found < NORMAL_NEIGHBOURS {
            return Err(CloudError::TooFewPoints {
                found,
                required: NORMAL_NEIGHBOURS,
            });
        }
        let (lo, hi) = bounds(input.iter().filter(is_finite).copied());
        let extent_m = (hi - lo).max();
        if extent_m.is_nan() || extent_m > MAX_EXTENT_M {
            return Err(CloudError::TooLarge {
                extent_m,
                limit_m: MAX_EXTENT_M,
            });
        }
        let origin = local_origin(input.iter().filter(is_finite));
        // Finite point `k` relative to the origin: the curve's order and the sorted copy are
        // made from the input directly (no copy in input order).
        let finite = finite_indices(input, found);
        let point = |k: usize| {
            let i = finite.as_ref().map_or(k, |f| f[k] as usize);
            input[i] - origin
        };
        let morton = Morton::new(found, &point);
        let sorted = morton.gather(&point);
        let boxes = sorted
            .par_chunks(BOX_RUN)
            .map(|run| {
                let (lo, hi) = bounds(run.iter().map(|p| Vector3::from(*p)));
                ((lo + hi) / 2.0, (hi - lo).norm() / 2.0)
            })
            .collect();
        let n = found;
        let mut cloud = Cloud {
            origin,
            local: LocalSlots::new(n),
            surface_noise: 0.0,
            noise_cap: 0.0,
            morton,
            sorted,
            boxes,
        };
        // The noise scale from every `stride`-th point along the curve (spread evenly).
        let stride = n.div_ceil(NOISE_SAMPLE);
        let subsample: Vec<u32> = (0..n as u32).step_by(stride).collect();
        cloud.prepare_scattered(&subsample);
        let mut scales: Vec<f64> = subsample
            .iter()
            .map(|&pos| cloud.local_at(pos as usize).1)
            .filter(|s| s.is_finite())
            .collect();
        scales.sort_by(f64::total_cmp);
        let quantile = |q: f64| {
            scales
                .get(((scales.len() as f64 * q) as usize).min(scales.len().saturating_sub(1)))
                .copied()
                .unwrap_or(0.0)
        };
        cloud.surface_noise = crate::robust::MAD_TO_SIGMA * quantile(0.5);
        cloud.noise_cap = quantile(0.99).max(cloud.surface_noise);
        Ok(cloud)
    }

    /// Points whose local geometry has been computed.
    #[must_use]
    pub fn computed(&self) -> usize {
        (0..self.len())
            .filter(|&pos| self.local.is_set(pos))
            .count()
    }

    /// Number of points.
    #[must_use]
    pub fn len(&self) -> usize {
        self.sorted.len()
    }

    /// Whether the cloud has no points (never, once built).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.sorted.is_empty()
    }

    /// Finite point `k` (in the input's order, non-finite points skipped), relative to the
    /// local origin.
    #[must_use]
    pub fn point(&self, k: usize) -> Vector3<f64> {
        self.point_at(self.position(k))
    }

    /// The curve position of point `k` (the index of the cloud's methods named `_at`: in
    /// curve order, neighbouring positions are neighbouring points, so a pass over positions
    /// in order reads memory in order).
    #[must_use]
    pub fn position(&self, k: usize) -> usize {
        self.morton.rank[k] as usize
    }

    /// The point index at curve position `pos`.
    #[must_use]
    pub fn index_at(&self, pos: usize) -> usize {
        self.morton.order[pos] as usize
    }

    /// The point at curve position `pos` (relative to the local origin).
    #[must_use]
    pub fn point_at(&self, pos: usize) -> Vector3<f64> {
        Vector3::from(self.sorted[pos])
    }

    /// The centre and half diagonal of the bounding box of the curve positions
    /// `run · BOX_RUN ..` `(run + 1) · BOX_RUN`: every one of those points is within the half
    /// diagonal of the centre.
    #[must_use]
    pub fn run_box(&self, run: usize) -> (Vector3<f64>, f64) {
        self.boxes[run]
    }

    /// Computes the local geometry of the points `idx` that lack it ([`Cloud::prepare_at`]).
    pub fn prepare(&self, idx: &[usize]) {
        let positions: Vec<usize> = idx.iter().map(|&k| self.position(k)).collect();
        self.prepare_at(&positions);
    }

    /// Computes the local geometry of the points at curve positions `positions` that lack
    /// it, in parallel in curve order (neighbouring queries share the cache). A large batch
    /// (a band around a cylinder) is answered by the uniform grid whose cells match the
    /// batch's point spacing (measured on a pilot of 512 of its points): each cell's
    /// queries scan its 3×3×3 block, and the few whose neighbourhood may reach beyond the
    /// block are answered alone (by the implicit octree of `measure::zorder`). Both give the
    /// exact k nearest neighbours.
    pub fn prepare_at(&self, positions: &[usize]) {
        // Gathered per chunk (a filtered parallel collect grows its pieces element by element).
        let parts: Vec<Vec<u32>> = positions
            .par_chunks(4096)
            .map(|chunk| {
                let missing = chunk.iter().filter(|&&pos| !self.local.is_set(pos));
                missing.map(|&pos| pos as u32).collect()
            })
            .collect();
        let mut missing = parts.concat();
        if !missing.is_sorted() {
            missing.par_sort_unstable();
        }
        missing.dedup();
        if missing.len() < GRID_BATCH {
            self.prepare_scattered(&missing);
            return;
        }
        // The pilot: evenly strided along the curve; its 16th-neighbour distances size the
        // grid's cells so that nine in ten neighbourhoods fit in a cell's block.
        let stride = missing.len().div_ceil(PILOT);
        let pilot: Vec<u32> = missing.iter().step_by(stride).copied().collect();
        let mut reach: Vec<f64> = pilot
            .par_iter()
            .map_init(OctreeScratch::default, |scratch, &pos| {
                let (local, d2) = self.compute_local(pos, scratch);
                self.local.set(pos as usize, local);
                d2.sqrt()
            })
            .collect();
        reach.sort_by(f64::total_cmp);
        let Some(&cell) = reach.get(reach.len() * 9 / 10) else {
            return;
        };
        if !(cell.is_finite() && cell > 0.0) {
            self.prepare_scattered(&missing);
            return;
        }
        let level = self.morton.level_for(cell);
        // Runs of queries in one cell.
        let mut groups: Vec<&[u32]> = Vec::new();
        let mut keys: Vec<u64> = Vec::new();
        let mut rest = &missing[..];
        while let Some(&first) = rest.first() {
            let key = self.morton.key(level, first);
            // Groups are short (eight queries on average): scanned, not searched.
            let len = rest
                .iter()
                .position(|&p| self.morton.key(level, p) != key)
                .unwrap_or(rest.len());
            let (group, tail) = rest.split_at(len);
            groups.push(group);
            keys.push(key);
            rest = tail;
        }
        // Scattered queries (about one per cell) gain nothing from the block scan.
        if groups.len() * 2 > missing.len() {
            self.prepare_scattered(&missing);
            return;
        }
        let grid = Grid::covering(&self.morton, level, &keys);
        groups.par_iter().with_min_len(16).for_each_init(
            || (BlockScratch::default(), OctreeScratch::default()),
            |(block, scratch), group| {
                grid.nearest_in_cell(&self.morton, &self.sorted, group, block, |pos, nb| {
                    if self.local.is_set(pos as usize) {
                        return;
                    }
                    let local = match nb {
                        Some(nb) => {
                            let mut pts = [Vector3::zeros(); NORMAL_NEIGHBOURS];
                            for (p, &q) in pts.iter_mut().zip(&nb.pos) {
                                *p = Vector3::from(self.sorted[q as usize]);
                            }
                            local_geometry(&pts[..nb.len])
                        }
                        None => self.compute_local(pos, scratch).0,
                    };
                    self.local.set(pos as usize, local);
                });
            },
        );
    }

    /// [`Cloud::prepare`] one query at a time, for the curve positions `missing` (sorted).
    fn prepare_scattered(&self, missing: &[u32]) {
        missing
            .par_iter()
            .for_each_init(OctreeScratch::default, |scratch, &pos| {
                self.local
                    .set(pos as usize, self.compute_local(pos, scratch).0);
            });
    }

    /// Unit normal (sign arbitrary) and local noise of point `k`, computed on first use.
    #[must_use]
    pub fn local(&self, k: usize) -> (Vector3<f64>, f64) {
        self.local_at(self.position(k))
    }

    /// [`Cloud::local`] of the point at curve position `pos`.
    #[must_use]
    pub fn local_at(&self, pos: usize) -> (Vector3<f64>, f64) {
        if let Some(local) = self.local.get(pos) {
            return local;
        }
        let local = self
            .compute_local(pos as u32, &mut OctreeScratch::default())
            .0;
        self.local.set(pos, local);
        // Another thread's may have been stored first.
        self.local.get(pos).unwrap_or(local)
    }

    /// The local geometry of the point at curve position `pos` from its [`NORMAL_NEIGHBOURS`]
    /// nearest neighbours ([`Morton::nearest`]), and the squared distance of the farthest of
    /// them.
    fn compute_local(&self, pos: u32, scratch: &mut OctreeScratch) -> ((Vector3<f64>, f64), f64) {
        let found = self.morton.nearest(&self.sorted, pos, scratch);
        let mut nb = [Vector3::zeros(); NORMAL_NEIGHBOURS];
        for (slot, &q) in nb.iter_mut().zip(&found.pos[..found.len]) {
            *slot = Vector3::from(self.sorted[q as usize]);
        }
        let d2 = found.d2[..found.len].iter().copied().fold(0.0, f64::max);
        (local_geometry(&nb[..found.len]), d2)
    }
}

/// Robust PCA of a point's nearest neighbours (itself included): its normal and local noise;
/// a neighbourhood without a plane gets the z axis and an infinite noise.
fn local_geometry(nb: &[Vector3<f64>]) -> (Vector3<f64>, f64) {
    robust_normal(nb)
        .filter(|(_, s)| s.is_finite())
        .unwrap_or((Vector3::z(), f64::INFINITY))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 100 finite points with x in [0, 1e308), y in (−1e308, 0], z = 1e308 made the
    /// cylinder fit panic ("cannot sample empty range"): the local origin overflowed.
    #[test]
    fn coordinates_near_1e308_are_refused() {
        let points: Vec<Vector3<f64>> = (0..100)
            .map(|k| {
                let t = f64::from(k) / 100.0;
                Vector3::new(t * 1e308, -t * 1e308, 1e308)
            })
            .collect();
        match Cloud::new(&points) {
            Err(CloudError::TooLarge { extent_m, limit_m }) => {
                assert!(extent_m > 9.8e307, "{extent_m}");
                assert_eq!(limit_m, 1e9);
            }
            other => panic!("{:?}", other.map(|c| c.len())),
        }
        // At the limit itself the cloud is prepared.
        let near: Vec<Vector3<f64>> = points.iter().map(|p| p / 1e308 * 1e9).collect();
        assert_eq!(Cloud::new(&near).map(|c| c.len()), Ok(100));
    }

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
    fn a_batch_through_the_grid_gets_the_local_geometry_of_the_exact_neighbours() {
        // A noisy pipe in sparse clutter, 44,000 points far from the origin: the half of the
        // points not in the noise subsample (every other curve position) is one batch, large
        // enough for the grid; a point's normal and noise must be those of its brute-force 16
        // nearest neighbours.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let offset = Vector3::new(4.0e5, 6.0e6, 80.0);
        let mut pts: Vec<Vector3<f64>> = (0..40_000)
            .map(|_| {
                let (t, a): (f64, f64) = (rng.random_range(0.0..1.0), rng.random_range(0.0..6.3));
                let e = 0.001 * rng.random_range(-1.0..1.0);
                offset + Vector3::new(t, (0.05 + e) * a.cos(), (0.05 + e) * a.sin())
            })
            .collect();
        pts.extend((0..4000).map(|_| {
            offset
                + Vector3::new(
                    rng.random_range(0.0..1.0),
                    rng.random_range(-0.3..0.3),
                    rng.random_range(-0.3..0.3),
                )
        }));
        let cloud = Cloud::new(&pts).unwrap();
        let all: Vec<usize> = (0..cloud.len()).collect();
        assert_eq!(cloud.computed(), cloud.len() / 2);
        cloud.prepare(&all);
        for k in (0..cloud.len())
            .filter(|&k| cloud.position(k) % 2 == 1)
            .step_by(37)
        {
            let p = cloud.point(k);
            let mut by_distance: Vec<(f64, usize)> = (0..cloud.len())
                .map(|j| ((cloud.point(j) - p).norm_squared(), j))
                .collect();
            by_distance.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let nb: Vec<Vector3<f64>> = by_distance[..NORMAL_NEIGHBOURS]
                .iter()
                .map(|&(_, j)| cloud.point(j))
                .collect();
            let (n_ref, s_ref) = local_geometry(&nb);
            let (n, s) = cloud.local(k);
            assert!(
                n.dot(&n_ref).abs() > 1.0 - 1e-12,
                "point {k}: {n} vs {n_ref}"
            );
            assert!(
                (s - s_ref).abs() <= 1e-12 * s_ref.max(1e-9),
                "point {k}: {s} vs {s_ref}"
            );
        }
    }

    #[test]
    fn median16_is_the_ninth_smallest() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for range in [3, 16, 1 << 40] {
            // Few distinct values (ties at every rank) and distinct ones.
            for _ in 0..2000 {
                let v: [u64; 16] = std::array::from_fn(|_| rng.random_range(0..range));
                let mut sorted = v;
                sorted.sort_unstable();
                assert_eq!(median16(v), sorted[8], "{v:?}");
            }
        }
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
    fn non_finite_points_are_skipped_and_the_rest_keep_their_order() {
        // A curved patch with NaN and infinite points among its points: the cloud must be
        // that of the finite points alone, point k the k-th finite point.
        let finite: Vec<Vector3<f64>> = (0..900)
            .map(|i| {
                let (x, y) = (f64::from(i % 30) * 0.01, f64::from(i / 30) * 0.01);
                Vector3::new(x, y, 0.3 * x * x - 0.2 * y * y + 7.0)
            })
            .collect();
        let mut with_gaps = Vec::new();
        for (i, p) in finite.iter().enumerate() {
            if i % 7 == 3 {
                with_gaps.push(Vector3::new(f64::NAN, 1.0, 2.0));
            }
            if i % 11 == 5 {
                with_gaps.push(Vector3::new(0.0, f64::INFINITY, 2.0));
            }
            with_gaps.push(*p);
        }
        let (a, b) = (
            Cloud::new(&finite).unwrap(),
            Cloud::new(&with_gaps).unwrap(),
        );
        assert_eq!(b.len(), finite.len());
        assert_eq!(a.origin, b.origin);
        for (k, p) in finite.iter().enumerate() {
            assert_eq!(b.point(k) + b.origin, a.point(k) + a.origin);
            assert!((b.point(k) + b.origin - p).norm() < 1e-12);
            assert_eq!(a.local(k), b.local(k));
        }
        assert_eq!(a.surface_noise, b.surface_noise);
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
