//! Scans of any size: the pipe network of a PLY or E57 file read in chunks, in
//! memory bounded by a point budget rather than by the scan's size.
//!
//! Two passes over the file:
//! 1. The points are streamed and decimated: a scan within [`ScanConfig::search_points`] is
//!    kept whole (and searched exactly as [`extract_network`] searches a cloud in memory); a
//!    larger one keeps one point in `stride`, the stride the declared count over the budget,
//!    chosen by a hash of the point's position in the file (should the file hold more than it
//!    declared, the stride doubles and every second kept point goes). The network is
//!    extracted from what was kept: the same scan, sparser.
//! 2. Only when the scan was decimated: the file is streamed again and each segment takes the
//!    points within a band about its surface and between its ends, at most
//!    [`ScanConfig::band_points`] of them (every second, fourth, … point once more arrive);
//!    each segment is then re-fitted ([`refit_among`]) on its band, so its radius, σ, RMSE,
//!    inliers and arc come from the scan's full density.
//!
//! Why decimation and not a voxel grid (one point per voxel, PCL's `VoxelGrid`): a voxel grid
//! thins the surfaces near the scanner tenfold but keeps every isolated mixed pixel behind a
//! pipe's silhouette, each alone in its voxel, so the outliers' share grows tenfold. Measured
//! on plant room seed 2 at 0.83 mrad (49 M points): with 5.7 mm voxels (7.3 M points searched)
//! the 4.7 m riser was refused as faceted (1.24 mm departure from the circle), with 11.3 mm
//! voxels both header segments were lost; decimated, the scan keeps its own proportions.
//! Why hashed and not every n-th point: a scanner writes its points column by column, and
//! every 9th point of a 0.83 mrad column is a sheared lattice, 7.5 mrad apart along the column
//! and 0.83 mrad across; its neighbourhoods are anisotropic, and on room seed 3 two segment
//! ends moved 5 cm (one remains, see the README).
//! Why not tiles: a tile border cuts pipes into pieces that would have to be found twice and
//! joined, and a tile of a dense scan near the scanner holds as many points as a whole sparse
//! one. Memory is the budget's points, whatever the scan's size.

use std::path::Path;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::cloud::Cloud;
use super::cylinder::{Cylinder, refit_among};
use super::network::{Network, NetworkConfig, NetworkError, PipeSegment, extract_network};
use super::nominal::nominal_size;
use crate::io::ReadError;
use crate::io::e57::{declared_points, stream_cloud};
use crate::io::ply::StreamSummary;

/// How a scan file is read and searched.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanConfig {
    /// The network's extraction.
    pub network: NetworkConfig,
    /// Most points searched (pass 1's budget).
    pub search_points: usize,
    /// Points per chunk read.
    pub chunk_points: usize,
    /// Most points of a segment's band in pass 2.
    pub band_points: usize,
}

impl Default for ScanConfig {
    fn default() -> Self {
        ScanConfig {
            network: NetworkConfig::default(),
            search_points: 6_000_000,
            chunk_points: 1 << 20,
            band_points: 2_000_000,
        }
    }
}

/// The network of a scan file.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanNetwork {
    /// The network (segments re-fitted on the full scan when it was decimated; their
    /// `inlier_indices` index [`ScanNetwork::searched`]).
    pub network: Network,
    /// What the reader saw.
    pub read: StreamSummary,
    /// The points searched: all finite points, or every `stride`-th.
    pub searched: Vec<Vector3<f64>>,
    /// Every how many finite points one was searched (1: all).
    pub stride: usize,
}

/// Which pass a progress report is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pass {
    /// Pass 1: reading and decimating.
    Search,
    /// Pass 2: collecting the segments' bands.
    Bands,
}

/// Why a scan's network could not be extracted.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScanError {
    /// The file cannot be read.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The extraction failed.
    #[error("{path}: {source}")]
    Network {
        /// The file.
        path: String,
        /// The failure.
        source: NetworkError,
    },
}

/// Extracts the pipe network of the PLY or E57 file `path` (see the module's doc);
/// `progress(pass, points)` is told after each chunk how many points that pass has read.
///
/// Deterministic: the same file gives the same network whatever the chunk size or the
/// thread count.
///
/// # Errors
///
/// [`ScanError::Read`] naming the file (unreadable, malformed, no finite point);
/// [`ScanError::Network`] when a setting is out of range.
pub fn extract_network_from(
    path: &Path,
    config: &ScanConfig,
    progress: &mut dyn FnMut(Pass, usize),
) -> Result<ScanNetwork, ScanError> {
    config
        .network
        .cylinder
        .validate()
        .map_err(|e| network_error(path, e.into()))?;
    let declared = declared_points(path)?;
    let mut kept = Decimator::new(declared, config.search_points);
    let read = stream_cloud(path, config.chunk_points, &mut |chunk| {
        chunk.iter().for_each(|p| kept.push(p.coords));
        progress(Pass::Search, kept.seen);
    })?;
    read.require_finite(path)?;
    let mut network =
        extract_network(&kept.points, &config.network).map_err(|e| network_error(path, e))?;
    if kept.stride > 1 && !network.segments.is_empty() {
        refit_on_full_scan(path, &mut network.segments, config, progress)?;
        refuse_out_of_range(&mut network, &config.network);
    }
    Ok(ScanNetwork {
        network,
        read,
        searched: kept.points,
        stride: kept.stride,
    })
}

/// SplitMix64's output function (Steele, Lea and Flood 2014): a well-mixed hash of a point's
/// position in the stream.
fn splitmix64(k: u64) -> u64 {
    let mut z = k.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// One point in `stride` of a stream (by [`splitmix64`] of its position), at most `budget` of
/// them.
#[derive(Debug)]
struct Decimator {
    stride: usize,
    budget: usize,
    seen: usize,
    points: Vec<Vector3<f64>>,
}

impl Decimator {
    /// For a stream that declares `declared` points: the smallest stride whose expected
    /// count is 6σ (binomial, ≈ 6√budget) below `budget`, so that the hash's spread does not
    /// overflow it.
    fn new(declared: u64, budget: usize) -> Self {
        let budget = budget.max(1);
        let target = (budget as f64 - 6.0 * (budget as f64).sqrt()).max(1.0);
        let stride = if declared as f64 <= budget as f64 {
            1
        } else {
            ((declared as f64 / target).ceil() as usize).max(1)
        };
        Decimator {
            stride,
            budget,
            seen: 0,
            points: Vec::with_capacity(budget.min(declared.try_into().unwrap_or(usize::MAX))),
        }
    }

    fn push(&mut self, p: Vector3<f64>) {
        if splitmix64(self.seen as u64).is_multiple_of(self.stride as u64) {
            self.points.push(p);
            if self.points.len() > self.budget {
                // More than declared: every second point kept so far goes, and the stride
                // doubles for those to come.
                let mut k = 0;
                self.points.retain(|_| {
                    k += 1;
                    k % 2 == 1
                });
                self.stride = self.stride.saturating_mul(2);
            }
        }
        self.seen += 1;
    }
}

fn network_error(path: &Path, source: NetworkError) -> ScanError {
    ScanError::Network {
        path: path.display().to_string(),
        source,
    }
}

/// The points of one segment's band, decimated to a cap as they arrive.
#[derive(Debug)]
struct Band {
    start: Vector3<f64>,
    direction: Vector3<f64>,
    length: f64,
    radius: f64,
    half_width: f64,
    cap: usize,
    stride: usize,
    count: usize,
    points: Vec<Vector3<f64>>,
}

impl Band {
    /// The band of `s`: within max(4 × RMSE, 3 mm) of its surface, between its ends.
    fn of(s: &PipeSegment, cap: usize) -> Self {
        let (start, direction, length) = s.axis();
        Band {
            start,
            direction,
            length,
            radius: s.radius_m,
            half_width: (4.0 * s.rmse_m).max(3e-3),
            cap: cap.max(16),
            stride: 1,
            count: 0,
            points: Vec::new(),
        }
    }

    /// Takes the points of `chunk` in the band: every `stride`-th of them; when the cap is
    /// reached the stride doubles and every second point kept so far goes.
    fn take(&mut self, chunk: &[Point3<f64>]) {
        for p in chunk {
            let w = p.coords - self.start;
            let t = w.dot(&self.direction);
            if !(0.0..=self.length).contains(&t) {
                continue;
            }
            let d = (w - self.direction * t).norm();
            if (d - self.radius).abs() > self.half_width {
                continue;
            }
            self.count += 1;
            if !self.count.is_multiple_of(self.stride) {
                continue;
            }
            self.points.push(p.coords);
            if self.points.len() > self.cap {
                // Kept: counts stride·1, stride·2, …; the multiples of 2·stride are the odd
                // positions.
                let mut k = 0;
                self.points.retain(|_| {
                    k += 1;
                    k % 2 == 0
                });
                self.stride *= 2;
            }
        }
    }
}

/// Pass 2 (see the module's doc): each segment re-fitted on its band of the full scan.
fn refit_on_full_scan(
    path: &Path,
    segments: &mut [PipeSegment],
    config: &ScanConfig,
    progress: &mut dyn FnMut(Pass, usize),
) -> Result<(), ReadError> {
    let mut bands: Vec<Band> = segments
        .iter()
        .map(|s| Band::of(s, config.band_points))
        .collect();
    let mut read = 0usize;
    stream_cloud(path, config.chunk_points, &mut |chunk| {
        bands.par_iter_mut().for_each(|b| b.take(chunk));
        read += chunk.len();
        progress(Pass::Bands, read);
    })?;
    segments
        .par_iter_mut()
        .zip(bands.into_par_iter())
        .for_each(|(s, band)| refit_segment(s, &band.points, &config.network));
    Ok(())
}

/// Moves the segments whose radius, re-fitted on every point, left the radius of interest
/// to the refused (a thin conduit that the decimated search fitted at 15 mm and every point
/// puts at 12.3 mm), and numbers the rest again in order.
fn refuse_out_of_range(network: &mut super::network::Network, config: &NetworkConfig) {
    use super::network::{Refusal, RefusedCandidate};
    let (min, max) = (config.cylinder.radius_min, config.cylinder.radius_max);
    let (kept, out): (Vec<PipeSegment>, Vec<PipeSegment>) = network
        .segments
        .drain(..)
        .partition(|s| (min..=max).contains(&s.radius_m));
    network
        .refused
        .extend(out.into_iter().map(|s| RefusedCandidate {
            start: s.start,
            end: s.end,
            radius_m: s.radius_m,
            inliers: s.inliers,
            normal_deviation_deg: s.normal_deviation_deg,
            normal_turn: s.normal_turn,
            shape_departure_m: s.shape_departure_m,
            refusal: Refusal::RadiusOutOfRange {
                min_m: min,
                max_m: max,
            },
        }));
    network.segments = kept
        .into_iter()
        .enumerate()
        .map(|(id, s)| PipeSegment { id, ..s })
        .collect();
}

/// Re-fits segment `s` on the points of its band; keeps the search's figures when the band
/// gives no fit.
fn refit_segment(s: &mut PipeSegment, points: &[Vector3<f64>], config: &NetworkConfig) {
    let Ok(cloud) = Cloud::new(points) else {
        return;
    };
    let (a, d, _) = s.axis();
    let start = Cylinder {
        point: a,
        direction: d,
        radius: s.radius_m,
    };
    let all: Vec<usize> = (0..cloud.len()).collect();
    let Some((fit, coverage)) = refit_among(&cloud, &all, &start, &config.cylinder) else {
        return;
    };
    let c = fit.cylinder;
    let on_axis = |p: [f64; 3]| {
        let w = Vector3::from(p) - c.point;
        c.point + c.direction * w.dot(&c.direction)
    };
    let (start, end) = (on_axis(s.start), on_axis(s.end));
    s.start = start.into();
    s.end = end.into();
    s.length_m = (end - start).norm();
    s.radius_m = c.radius;
    s.radius_std_m = fit.radius_std;
    s.rmse_m = fit.rmse;
    s.searched_inliers = s.inliers;
    s.inliers = fit.inliers;
    s.coverage_deg = coverage.to_degrees();
    s.nominal = nominal_size(2e3 * c.radius, config.material);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::nominal::PipeMaterial;

    #[test]
    fn a_stream_within_the_budget_is_kept_whole_in_order() {
        let mut d = Decimator::new(1000, 1000);
        let pts: Vec<Vector3<f64>> = (0..1000)
            .map(|k| Vector3::new(k as f64, 0.0, 0.0))
            .collect();
        pts.iter().for_each(|p| d.push(*p));
        assert_eq!(d.stride, 1);
        assert_eq!(d.points, pts);
    }

    #[test]
    fn a_larger_stream_keeps_one_point_in_stride_within_the_budget() {
        // 10⁶ declared, budget 10⁵ (less 6√10⁵: 98 103): stride 11; the hash keeps
        // 10⁶/11 = 90 909 ± 3σ (σ ≈ 290).
        let mut d = Decimator::new(1_000_000, 100_000);
        (0..1_000_000).for_each(|k| d.push(Vector3::new(k as f64, 0.0, 0.0)));
        assert_eq!(d.stride, 11);
        assert!(
            (d.points.len() as i64 - 90_909).abs() < 870,
            "{}",
            d.points.len()
        );
        // Spread over the whole stream, not its start: a tenth in each tenth, ± 4σ.
        for tenth in 0..10 {
            let n = d
                .points
                .iter()
                .filter(|p| (p.x / 100_000.0) as usize == tenth)
                .count();
            assert!((n as i64 - 9_091).abs() < 380, "tenth {tenth}: {n}");
        }
    }

    #[test]
    fn a_stream_longer_than_declared_still_keeps_the_budget() {
        // Declares 1000 but holds 10⁶: the stride doubles until the budget holds.
        let mut d = Decimator::new(1000, 1000);
        (0..1_000_000).for_each(|k| d.push(Vector3::new(k as f64, 0.0, 0.0)));
        assert!(d.points.len() <= 1000);
        assert!(d.points.len() >= 250, "{}", d.points.len());
        assert!(d.stride >= 512);
    }

    fn segment(radius: f64, rmse: f64) -> PipeSegment {
        PipeSegment {
            id: 0,
            start: [0.0, 0.0, 0.0],
            end: [0.0, 0.0, 2.0],
            length_m: 2.0,
            radius_m: radius,
            radius_std_m: 1e-5,
            rmse_m: rmse,
            inliers: 100,
            searched_inliers: 100,
            coverage_deg: 360.0,
            normal_deviation_deg: 1.0,
            normal_turn: 1.0,
            shape_departure_m: 1e-4,
            nominal: nominal_size(2e3 * radius, PipeMaterial::Steel),
            inlier_indices: Vec::new(),
        }
    }

    #[test]
    fn a_band_takes_the_points_near_the_surface_between_the_ends() {
        // RMSE 1 mm: the band is ±4 mm about r = 50 mm, for 0 ≤ z ≤ 2.
        let mut band = Band::of(&segment(0.05, 1e-3), 1000);
        let at = |rho: f64, z: f64| Point3::new(rho * 0.6, rho * 0.8, z);
        let chunk = [
            at(0.05, 1.0),    // on the surface
            at(0.0539, 0.01), // 3.9 mm out
            at(0.0461, 1.99), // 3.9 mm in
            at(0.0541, 1.0),  // 4.1 mm out
            at(0.05, -0.001), // before the start
            at(0.05, 2.001),  // past the end
            at(0.0, 1.0),     // on the axis
        ];
        band.take(&chunk);
        assert_eq!(band.points.len(), 3);
        assert_eq!(band.points[1], chunk[1].coords);
    }

    #[test]
    fn a_band_beyond_its_cap_keeps_every_other_point() {
        let mut band = Band::of(&segment(0.05, 1e-3), 16);
        let chunk: Vec<Point3<f64>> = (0..100)
            .map(|k| Point3::new(0.05, 0.0, 0.01 * k as f64 + 0.005))
            .collect();
        band.take(&chunk);
        // Cap 16: strides 1 → 2 → 4 → 8; the kept are the 8th, 16th, … of the 100.
        assert_eq!(band.stride, 8);
        let expected: Vec<Vector3<f64>> = (1..=12).map(|k| chunk[8 * k - 1].coords).collect();
        assert_eq!(band.points, expected);
    }
}
