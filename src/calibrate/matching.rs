//! Paper Algorithm 2: matching the detected targets of all views, with Algorithm 3 inside and
//! after it.
//!
//! Per overlapping pair (step 4, in parallel): candidates are the ellipses whose centres
//! satisfy eq. 2, `D(c_ik, c_jl) ≤ σ_ij·√χ²₀.₉₇₅,₂ (+ an eccentricity allowance)`, found
//! through a grid of image j's centres walked along the epipolar line (not all pairs of
//! ellipses); among the candidates, Quan's scale-normalised |δ| (eq. 1, math §2.2) ranks, and
//! two ellipses match only when each is the other's least |δ| (step 4c3). The connected group
//! of step 4c1 is implicit: an ellipse's candidates all lie in its group, so its minimum over
//! its candidates is its minimum in the group. Two-view matches chain into tracks (step 5) in
//! order of increasing |δ|, never joining two tracks that share an image (the conflict rule).
//! Each track's centres are triangulated by LMedS (step 6) and only the inlier views kept;
//! Algorithm 3 can correct the centres before that triangulation (paper, Fig. 4) and corrects
//! them again after it.
//!
//! Our addition to eq. 2, switchable: the band is widened by each ellipse's eccentricity bound
//! ([`eccentricity_bound`]), since ellipse centres are not images of one point, so large
//! oblique targets would otherwise fall out of a band set by point features (math §4.1
//! pitfall).

use nalgebra::{Matrix4, Point3, Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::eccentricity::{EccentricityConfig, eccentricity_bound};
use super::refine::PairGeometry;
pub use super::track::{PairIndex, Track, TrackView};
use super::track::{corrections, observations_of};
use super::views::{FrameCamera, TargetObservation};
use crate::geometry::epipolar::symmetric_distance;
use crate::geometry::quan::{cone, delta_of_cones};
use crate::geometry::triangulation::{Observation, reprojection_rms, triangulate};
use crate::robust::triangulation::triangulate_robust_bounded;
use crate::robust::{LmedsConfig, SQRT_CHI2_975_2DOF};

/// Options of Algorithm 2; each step can be switched off for the paper's comparison (Table II).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchConfig {
    /// Widen the eq. 2 band by the two ellipses' eccentricity bounds (√2·(e_i + e_j)), default
    /// true. Off: the paper's band `σ_ij·√χ²₀.₉₇₅,₂` alone.
    pub eccentricity_allowance: bool,
    /// Require both ellipses to be each other's least |δ| (step 4c3), default true. Off: each
    /// ellipse of the first image takes its least-|δ| candidate.
    pub mutual: bool,
    /// Drop a two-view match whose |δ| exceeds this multiple of the median |δ| of its image
    /// pair's matches (pairs with at least five matches), default 400. Our addition to the
    /// paper's threshold-free rule: in simulation the true matches' |δ| stays within ~220×
    /// the pair's median (δ grows with the square of the conic errors, so it is heavy
    /// tailed), while a wrong match that is each ellipse's least |δ| — its true partner out of
    /// view — sits at 10³–10⁵×. `None`: the paper's rule alone.
    pub max_delta_ratio: Option<f64>,
    /// Robust LMedS triangulation keeping inlier views (step 6), default true. Off: every
    /// chained view is kept.
    pub robust_triangulation: bool,
    /// Algorithm 3 on the chained views before the robust triangulation, default true.
    pub correct_before_triangulation: bool,
    /// Algorithm 3 after the robust triangulation: the output centres, default true.
    pub correct_centres: bool,
    /// Robust triangulation options.
    pub triangulation: LmedsConfig,
    /// Algorithm 3 options.
    pub eccentricity: EccentricityConfig,
    /// One target, one track ([`super::tracks::consolidate`]): tracks that are one target
    /// merged, and views of well-determined targets found where their point projects, default
    /// true. Where the two-view rule cannot tell neighbours apart — a regular dot grid along the
    /// epipolar lines — one target otherwise ends up as several short tracks. It needs tracks
    /// cleaned by the robust triangulation (a mixed track's point claims neighbours' views), so
    /// it runs only with [`MatchConfig::robust_triangulation`]. Off: the paper's tracks.
    pub merge_tracks: bool,
    /// Drop a track whose median roundness in its plane (Algorithm 3's cut of each view's cone,
    /// [`TrackView::roundness`]) is below this, default [`MIN_ROUNDNESS`]: a circular target is
    /// round there from every view, a blot of paint an ellipse fits in each image is not
    /// (its own shape, the same from every view). Tracks with no roundness (no view had a
    /// partner) are kept. `None`: every track is kept.
    pub min_roundness: Option<f64>,
}

/// Least median roundness in the plane of a target's track. A printed circle is round to well
/// under 1 %; on the simulated labs the median of a target's views stays above 0.95 for 95 %
/// of targets (noise in small, oblique ellipses and in the two-view plane), and 0.9 keeps about
/// twice that deficit as margin.
pub const MIN_ROUNDNESS: f64 = 0.9;

impl MatchConfig {
    /// Algorithm 3's configuration when the centres are corrected, `None` when they are not.
    #[must_use]
    pub fn correction(&self) -> Option<&EccentricityConfig> {
        self.correct_centres.then_some(&self.eccentricity)
    }
}

impl Default for MatchConfig {
    fn default() -> Self {
        MatchConfig {
            eccentricity_allowance: true,
            mutual: true,
            max_delta_ratio: Some(400.0),
            robust_triangulation: true,
            correct_before_triangulation: true,
            correct_centres: true,
            triangulation: LmedsConfig::default(),
            eccentricity: EccentricityConfig::default(),
            merge_tracks: true,
            min_roundness: Some(MIN_ROUNDNESS),
        }
    }
}

/// The outcome of Algorithm 2.
#[derive(Clone, Debug, Default)]
pub struct Matching {
    /// Matched targets (two or more inlier views).
    pub tracks: Vec<Track>,
    /// Candidate pairs that passed eq. 2, over all image pairs.
    pub candidates: usize,
    /// Two-view matches (step 4).
    pub pair_matches: usize,
    /// Two-view matches the conflict rule refused while chaining (step 5).
    pub conflicts: usize,
    /// What "one target, one track" changed ([`super::tracks::consolidate`]).
    pub consolidation: super::tracks::Consolidation,
    /// Tracks dropped as not round in their plane ([`MatchConfig::min_roundness`]).
    pub not_round: usize,
}

/// A uniform grid over one frame's ellipse centres (covering the image and every centre).
struct CentreGrid {
    cell: f64,
    origin: Vector2<f64>,
    nx: usize,
    ny: usize,
    /// CSR: cell `k` holds `items[start[k]..start[k + 1]]`.
    start: Vec<u32>,
    items: Vec<u32>,
}

impl CentreGrid {
    fn new(centres: &[Vector2<f64>], width: f64, height: f64, cell: f64) -> Self {
        let finite = centres
            .iter()
            .filter(|c| c.x.is_finite() && c.y.is_finite());
        let (mut lo, mut hi) = (Vector2::new(0.0f64, 0.0f64), Vector2::new(width, height));
        for c in finite {
            lo = lo.inf(c);
            hi = hi.sup(c);
        }
        let nx = (((hi.x - lo.x) / cell).floor() as usize + 1).min(4096);
        let ny = (((hi.y - lo.y) / cell).floor() as usize + 1).min(4096);
        let cell = cell.max((hi.x - lo.x) / 4095.0).max((hi.y - lo.y) / 4095.0);
        let key = |c: &Vector2<f64>| {
            let ix = (((c.x - lo.x) / cell).floor().max(0.0) as usize).min(nx - 1);
            let iy = (((c.y - lo.y) / cell).floor().max(0.0) as usize).min(ny - 1);
            iy * nx + ix
        };
        let mut count = vec![0u32; nx * ny + 1];
        for c in centres {
            count[key(c) + 1] += 1;
        }
        for k in 1..count.len() {
            count[k] += count[k - 1];
        }
        let mut fill = count.clone();
        let mut items = vec![0u32; centres.len()];
        for (i, c) in centres.iter().enumerate() {
            let k = key(c);
            items[fill[k] as usize] = i as u32;
            fill[k] += 1;
        }
        CentreGrid {
            cell,
            origin: lo,
            nx,
            ny,
            start: count,
            items,
        }
    }

    /// Pushes the items of every cell within distance `tol` of the line `l` (a superset of the
    /// centres within `tol`): per column (or row, for steep lines) the band's extent.
    fn near_line(&self, l: &Vector3<f64>, tol: f64, out: &mut Vec<u32>) {
        out.clear();
        let n = (l.x * l.x + l.y * l.y).sqrt();
        if n == 0.0 || !n.is_finite() {
            return;
        }
        // The line in grid coordinates (origin moved to `self.origin`).
        let (a, b) = (l.x / n, l.y / n);
        let c = l.z / n + a * self.origin.x + b * self.origin.y;
        let cell = self.cell;
        let mut push = |ix: usize, iy: usize| {
            let k = iy * self.nx + ix;
            out.extend_from_slice(&self.items[self.start[k] as usize..self.start[k + 1] as usize]);
        };
        // Cells [lo, hi] (in cell units) clipped to 0..n.
        let span = |lo: f64, hi: f64, n: usize| -> Option<(usize, usize)> {
            let (lo, hi) = ((lo / cell).floor(), (hi / cell).floor());
            (hi >= 0.0 && lo < n as f64).then(|| (lo.max(0.0) as usize, (hi as usize).min(n - 1)))
        };
        if b.abs() >= a.abs() {
            // v = −(a u + c)/b per column; the band is ±tol/|b| in v.
            let half = tol / b.abs();
            for ix in 0..self.nx {
                let (u0, u1) = (ix as f64 * cell, (ix + 1) as f64 * cell);
                let (v0, v1) = (-(a * u0 + c) / b, -(a * u1 + c) / b);
                if let Some((r0, r1)) = span(v0.min(v1) - half, v0.max(v1) + half, self.ny) {
                    for iy in r0..=r1 {
                        push(ix, iy);
                    }
                }
            }
        } else {
            let half = tol / a.abs();
            for iy in 0..self.ny {
                let (v0, v1) = (iy as f64 * cell, (iy + 1) as f64 * cell);
                let (u0, u1) = (-(b * v0 + c) / a, -(b * v1 + c) / a);
                if let Some((c0, c1)) = span(u0.min(u1) - half, u0.max(u1) + half, self.nx) {
                    for ix in c0..=c1 {
                        push(ix, iy);
                    }
                }
            }
        }
    }
}

/// Per frame, what step 4 needs of each observation.
struct FrameData {
    /// Image size scale for conditioning.
    scale: f64,
    centres: Vec<Vector2<f64>>,
    conics: Vec<nalgebra::Matrix3<f64>>,
    bounds: Vec<f64>,
    grid: CentreGrid,
}

fn frame_data(
    camera: &FrameCamera,
    obs: &[TargetObservation],
    width: f64,
    height: f64,
) -> FrameData {
    let centres: Vec<Vector2<f64>> = obs.iter().map(TargetObservation::centre).collect();
    let conics = obs.iter().map(|o| o.conic).collect();
    let bounds = obs
        .iter()
        .map(|o| eccentricity_bound(o.ellipse.a, o.ellipse.b, camera.intrinsics.c))
        .collect();
    let grid = CentreGrid::new(&centres, width, height, (width.max(height) / 32.0).max(8.0));
    FrameData {
        scale: width.max(height),
        centres,
        conics,
        bounds,
        grid,
    }
}

/// |δ| of two unit-norm cones (math §2.2).
fn abs_delta(a: &Matrix4<f64>, b: &Matrix4<f64>) -> f64 {
    delta_of_cones(a, b).abs()
}

/// Step 4 for one pair: the candidates of eq. 2 and the mutual least-|δ| matches
/// `(obs in a, obs in b, |δ|)`.
fn match_pair(
    pair: &PairGeometry,
    cams: (&FrameCamera, &FrameCamera),
    fa: &FrameData,
    fb: &FrameData,
    config: &MatchConfig,
) -> (usize, Vec<(u32, u32, f64)>) {
    let _ = cams;
    let Some((p_a, p_b)) = pair.projective_cameras(fa.scale) else {
        return (0, Vec::new());
    };
    let mut cones_a: Vec<Option<Matrix4<f64>>> = vec![None; fa.centres.len()];
    let mut cones_b: Vec<Option<Matrix4<f64>>> = vec![None; fb.centres.len()];
    let base = pair.sigma * SQRT_CHI2_975_2DOF;
    let max_bound_b = fb.bounds.iter().copied().fold(0.0, f64::max);
    let allowance = |ea: f64, eb: f64| {
        if config.eccentricity_allowance {
            std::f64::consts::SQRT_2 * (ea + eb)
        } else {
            0.0
        }
    };
    // Candidate edges (i in a, j in b, |δ|).
    let mut edges: Vec<(u32, u32, f64)> = Vec::new();
    let mut near = Vec::new();
    for (i, ca) in fa.centres.iter().enumerate() {
        let line = pair.f * Vector3::new(ca.x, ca.y, 1.0);
        let widest = base + allowance(fa.bounds[i], max_bound_b);
        fb.grid.near_line(&line, widest, &mut near);
        for &j in &near {
            let tol = base + allowance(fa.bounds[i], fb.bounds[j as usize]);
            if symmetric_distance(&pair.f, ca, &fb.centres[j as usize]) <= tol {
                let ca = *cones_a[i].get_or_insert_with(|| cone(&p_a, &fa.conics[i]));
                let cb =
                    *cones_b[j as usize].get_or_insert_with(|| cone(&p_b, &fb.conics[j as usize]));
                edges.push((i as u32, j, abs_delta(&ca, &cb)));
            }
        }
    }
    let candidates = edges.len();
    // Least |δ| per ellipse on either side (ties broken by index, deterministic).
    let mut best_a: Vec<Option<(f64, u32)>> = vec![None; fa.centres.len()];
    let mut best_b: Vec<Option<(f64, u32)>> = vec![None; fb.centres.len()];
    for &(i, j, d) in &edges {
        let better = |cur: &Option<(f64, u32)>, other: u32| {
            cur.is_none_or(|(bd, bo)| d < bd || (d == bd && other < bo))
        };
        if better(&best_a[i as usize], j) {
            best_a[i as usize] = Some((d, j));
        }
        if better(&best_b[j as usize], i) {
            best_b[j as usize] = Some((d, i));
        }
    }
    let mut matches: Vec<(u32, u32, f64)> = best_a
        .iter()
        .enumerate()
        .filter_map(|(i, b)| {
            let (d, j) = (*b)?;
            let mutual = best_b[j as usize].is_some_and(|(_, i2)| i2 as usize == i);
            (mutual || !config.mutual).then_some((i as u32, j, d))
        })
        .collect();
    if let Some(ratio) = config.max_delta_ratio
        && matches.len() >= 5
    {
        let mut d: Vec<f64> = matches.iter().map(|m| m.2).collect();
        let median = crate::robust::lower_median(&mut d);
        matches.retain(|m| m.2 <= ratio * median);
    }
    (candidates, matches)
}

/// A chained track's views and the two-view matches joining them (indices into the views).
type ChainedTrack = (Vec<TrackView>, Vec<(usize, usize)>);

/// Union-find over all observations with per-set frame lists (step 5's conflict rule).
struct Chains {
    parent: Vec<usize>,
    frames: Vec<Vec<usize>>,
}

impl Chains {
    fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] != x {
            self.parent[x] = self.parent[self.parent[x]];
            x = self.parent[x];
        }
        x
    }

    /// Joins the sets of `x` and `y` unless they hold a common frame; false on conflict.
    fn join(&mut self, x: usize, y: usize) -> bool {
        let (rx, ry) = (self.find(x), self.find(y));
        if rx == ry {
            return true;
        }
        let (fx, fy) = (&self.frames[rx], &self.frames[ry]);
        let (mut i, mut j) = (0, 0);
        while i < fx.len() && j < fy.len() {
            match fx[i].cmp(&fy[j]) {
                std::cmp::Ordering::Equal => return false,
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
            }
        }
        let (big, small) = if fx.len() >= fy.len() {
            (rx, ry)
        } else {
            (ry, rx)
        };
        let moved = std::mem::take(&mut self.frames[small]);
        let merged = {
            let keep = &self.frames[big];
            let mut m = Vec::with_capacity(keep.len() + moved.len());
            let (mut i, mut j) = (0, 0);
            while i < keep.len() || j < moved.len() {
                if j == moved.len() || (i < keep.len() && keep[i] < moved[j]) {
                    m.push(keep[i]);
                    i += 1;
                } else {
                    m.push(moved[j]);
                    j += 1;
                }
            }
            m
        };
        self.frames[big] = merged;
        self.parent[small] = big;
        true
    }
}

/// Step 6 and Algorithm 3 for one chained track.
fn finish_track(
    mut views: Vec<TrackView>,
    edges: &[(usize, usize)],
    cameras: &[FrameCamera],
    observations: &[Vec<TargetObservation>],
    pairs: &PairIndex,
    prior_sigma: f64,
    config: &MatchConfig,
) -> Option<Track> {
    let robust = |obs: &[Observation]| -> Option<(Point3<f64>, Vec<bool>)> {
        if config.robust_triangulation {
            let r = triangulate_robust_bounded(obs, prior_sigma, &config.triangulation)?;
            Some((r.point, r.inliers))
        } else {
            Some((triangulate(obs)?, vec![true; obs.len()]))
        }
    };
    if config.correct_before_triangulation {
        // Correct every view from partners among the views a first robust triangulation of
        // the fitted centres keeps, so that views with large eccentricity are not rejected.
        let (x0, inliers0) = robust(&observations_of(&views, cameras, false))?;
        let c = corrections(
            &views,
            cameras,
            observations,
            pairs,
            &inliers0,
            &x0,
            &config.eccentricity,
        );
        for (v, c) in views.iter_mut().zip(c) {
            v.set_correction(c);
        }
    }
    let (x, mut inliers) = robust(&observations_of(&views, cameras, true))?;
    if config.robust_triangulation {
        inliers = connected_inliers(&inliers, edges);
    }
    let mut rejected = Vec::new();
    let mut kept = Vec::with_capacity(views.len());
    for (v, inlier) in views.into_iter().zip(inliers) {
        if inlier {
            kept.push(v);
        } else {
            rejected.push((v.frame, v.obs));
        }
    }
    if kept.len() < 2 {
        return None;
    }
    let mut point = x;
    if config.correct_centres {
        let all = vec![true; kept.len()];
        let c = corrections(
            &kept,
            cameras,
            observations,
            pairs,
            &all,
            &point,
            &config.eccentricity,
        );
        for (v, c) in kept.iter_mut().zip(c) {
            v.set_correction(c);
        }
        point = triangulate(&observations_of(&kept, cameras, true))?;
    } else {
        for v in &mut kept {
            v.set_correction(None);
        }
        point = triangulate(&observations_of(&kept, cameras, false)).unwrap_or(point);
    }
    let rms_px = reprojection_rms(&observations_of(&kept, cameras, true), &point);
    Some(Track {
        views: kept,
        rejected,
        point,
        rms_px,
    })
}

/// The largest set of inlier views connected by two-view matches among themselves (ties: the
/// set holding the earliest view). A view agreeing with the triangulation only by chance —
/// reached through a view the triangulation rejected — is not kept: two views of different
/// targets near one epipolar line are geometrically consistent, but no match joins them.
fn connected_inliers(inliers: &[bool], edges: &[(usize, usize)]) -> Vec<bool> {
    let n = inliers.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    for &(a, b) in edges {
        if a < n && b < n && inliers[a] && inliers[b] {
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            if ra != rb {
                parent[ra.max(rb)] = ra.min(rb);
            }
        }
    }
    let mut size = vec![0usize; n];
    for k in (0..n).filter(|&k| inliers[k]) {
        let r = find(&mut parent, k);
        size[r] += 1;
    }
    let Some(best) = (0..n).max_by(|&a, &b| size[a].cmp(&size[b]).then(b.cmp(&a))) else {
        return Vec::new();
    };
    (0..n)
        .map(|k| inliers[k] && find(&mut parent, k) == best)
        .collect()
}

/// Step 6 with recovery: the views a robust triangulation rejects are tried again as a track
/// of their own (a wrong two-view match can chain two targets seen in disjoint sets of frames
/// into one track; LMedS keeps one of them and the other is not lost). Stops when fewer than
/// two views remain or nothing triangulates.
fn split_track(
    views: Vec<TrackView>,
    edges: &[(usize, usize)],
    cameras: &[FrameCamera],
    observations: &[Vec<TargetObservation>],
    pairs: &PairIndex,
    prior_sigma: f64,
    config: &MatchConfig,
) -> Vec<Track> {
    let mut out = Vec::new();
    let mut rest = views;
    let mut rest_edges = edges.to_vec();
    while rest.len() >= 2 {
        let Some(track) = finish_track(
            rest.clone(),
            &rest_edges,
            cameras,
            observations,
            pairs,
            prior_sigma,
            config,
        ) else {
            break;
        };
        // Re-index the edges among the rejected views.
        let new_index: Vec<Option<usize>> = rest
            .iter()
            .scan(0, |next, v| {
                Some(track.rejected.contains(&(v.frame, v.obs)).then(|| {
                    *next += 1;
                    *next - 1
                }))
            })
            .collect();
        rest_edges = rest_edges
            .iter()
            .filter_map(|&(a, b)| Some((new_index[a]?, new_index[b]?)))
            .collect();
        rest.retain(|v| track.rejected.contains(&(v.frame, v.obs)));
        out.push(track);
    }
    out
}

/// Step 4's outcome for one image pair.
#[derive(Clone, Debug, PartialEq)]
pub struct PairMatches {
    /// First frame.
    pub a: usize,
    /// Second frame.
    pub b: usize,
    /// Candidate pairs that passed eq. 2.
    pub candidates: usize,
    /// Two-view matches `(observation in a, observation in b, |δ|)`.
    pub matches: Vec<(u32, u32, f64)>,
}

/// Step 4 of Algorithm 2 over all overlapping pairs, in parallel.
#[must_use]
pub fn match_pairs(
    cameras: &[FrameCamera],
    observations: &[Vec<TargetObservation>],
    pairs: &[PairGeometry],
    image_size: (u32, u32),
    config: &MatchConfig,
) -> Vec<PairMatches> {
    let (w, h) = (f64::from(image_size.0), f64::from(image_size.1));
    let data: Vec<FrameData> = cameras
        .par_iter()
        .zip(observations.par_iter())
        .map(|(c, o)| frame_data(c, o, w, h))
        .collect();
    pairs
        .par_iter()
        .filter(|p| p.a < data.len() && p.b < data.len())
        .map(|p| {
            let (candidates, matches) = match_pair(
                p,
                (&cameras[p.a], &cameras[p.b]),
                &data[p.a],
                &data[p.b],
                config,
            );
            PairMatches {
                a: p.a,
                b: p.b,
                candidates,
                matches,
            }
        })
        .collect()
}

/// Runs Algorithm 2 (with Algorithm 3 as configured) on frames with cameras and undistorted
/// target observations, using the robust two-view geometry of the overlapping pairs (Algorithm
/// 1). `prior_sigma` is the a-priori σ of a target centre's reprojection (px) for tracks too
/// short for LMedS — Algorithm 1's reprojection σ is the honest value. `image_size` bounds the
/// candidate grids. Deterministic for any thread count.
#[must_use]
pub fn match_targets(
    cameras: &[FrameCamera],
    observations: &[Vec<TargetObservation>],
    pairs: &[PairGeometry],
    image_size: (u32, u32),
    prior_sigma: f64,
    config: &MatchConfig,
) -> Matching {
    let index = PairIndex::new(pairs);
    let per_pair = match_pairs(cameras, observations, pairs, image_size, config);
    let candidates = per_pair.iter().map(|p| p.candidates).sum();
    // Global observation ids.
    let offsets: Vec<usize> = observations
        .iter()
        .scan(0, |acc, o| {
            let start = *acc;
            *acc += o.len();
            Some(start)
        })
        .collect();
    let total = offsets
        .last()
        .map_or(0, |s| s + observations.last().map_or(0, Vec::len));
    let frame_of: Vec<usize> = observations
        .iter()
        .enumerate()
        .flat_map(|(f, o)| std::iter::repeat_n(f, o.len()))
        .collect();
    let mut all: Vec<(f64, usize, usize)> = Vec::new();
    for pair in &per_pair {
        for &(i, j, d) in &pair.matches {
            all.push((
                d,
                offsets[pair.a] + i as usize,
                offsets[pair.b] + j as usize,
            ));
        }
    }
    let pair_matches = all.len();
    all.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let mut chains = Chains {
        parent: (0..total).collect(),
        frames: frame_of.iter().map(|&f| vec![f]).collect(),
    };
    let mut conflicts = 0;
    let mut accepted = Vec::with_capacity(all.len());
    for &(_, x, y) in &all {
        if chains.join(x, y) {
            accepted.push((x, y));
        } else {
            conflicts += 1;
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> =
        std::collections::BTreeMap::new();
    for g in 0..total {
        let r = chains.find(g);
        groups.entry(r).or_default().push(g);
    }
    // Position of each observation within its group, and each group's edges.
    let mut position = vec![0usize; total];
    for members in groups.values() {
        for (k, &g) in members.iter().enumerate() {
            position[g] = k;
        }
    }
    let mut group_edges: std::collections::HashMap<usize, Vec<(usize, usize)>> =
        std::collections::HashMap::new();
    for &(x, y) in &accepted {
        let r = chains.find(x);
        group_edges
            .entry(r)
            .or_default()
            .push((position[x], position[y]));
    }
    let chained: Vec<ChainedTrack> = groups
        .into_iter()
        .filter(|(_, g)| g.len() >= 2)
        .map(|(root, g)| {
            let views = g
                .into_iter()
                .map(|id| {
                    let frame = frame_of[id];
                    let obs = id - offsets[frame];
                    TrackView {
                        frame,
                        obs,
                        centre: observations[frame][obs].centre(),
                        corrected: None,
                        partner: None,
                        roundness: None,
                    }
                })
                .collect();
            (views, group_edges.remove(&root).unwrap_or_default())
        })
        .collect();
    let tracks: Vec<Track> = chained
        .into_par_iter()
        .flat_map_iter(|(views, edges)| {
            split_track(
                views,
                &edges,
                cameras,
                observations,
                &index,
                prior_sigma,
                config,
            )
        })
        .collect();
    let (tracks, consolidation) = if config.merge_tracks && config.robust_triangulation {
        super::tracks::consolidate(
            tracks,
            cameras,
            observations,
            &index,
            image_size,
            config.correction(),
        )
    } else {
        (tracks, super::tracks::Consolidation::default())
    };
    let before = tracks.len();
    let tracks: Vec<Track> = match config.min_roundness {
        Some(least) => tracks
            .into_iter()
            .filter(|t| t.roundness().is_none_or(|q| q >= least))
            .collect(),
        None => tracks,
    };
    Matching {
        not_round: before - tracks.len(),
        tracks,
        candidates,
        pair_matches,
        conflicts,
        consolidation,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The grid walk returns every centre within the band (compared with brute force), for
    /// lines of every direction, inside and outside the image.
    #[test]
    fn grid_walk_finds_every_centre_near_a_line() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (w, h) = (1920.0, 1080.0);
        let centres: Vec<Vector2<f64>> = (0..400)
            .map(|_| {
                Vector2::new(
                    rng.random_range(-50.0..w + 50.0),
                    rng.random_range(-50.0..h + 50.0),
                )
            })
            .collect();
        let grid = CentreGrid::new(&centres, w, h, 60.0);
        let mut near = Vec::new();
        for _ in 0..500 {
            let angle: f64 = rng.random_range(0.0..std::f64::consts::PI);
            let through = Vector2::new(
                rng.random_range(-200.0..w + 200.0),
                rng.random_range(-200.0..h + 200.0),
            );
            let n = Vector2::new(angle.cos(), angle.sin());
            let line = Vector3::new(n.x, n.y, -n.dot(&through)) * rng.random_range(0.1..10.0);
            let tol = rng.random_range(0.5..40.0);
            grid.near_line(&line, tol, &mut near);
            for (i, c) in centres.iter().enumerate() {
                let d = (n.dot(c) - n.dot(&through)).abs();
                if d <= tol {
                    assert!(
                        near.contains(&(i as u32)),
                        "centre {c} at {d} from the line (tol {tol}) missed"
                    );
                }
            }
        }
    }

    #[test]
    fn chains_refuse_two_views_of_one_frame() {
        // Observations 0, 1 in frame 0; 2 in frame 1; 3 in frame 2.
        let mut c = Chains {
            parent: (0..4).collect(),
            frames: vec![vec![0], vec![0], vec![1], vec![2]],
        };
        assert!(c.join(0, 2));
        assert!(c.join(2, 3));
        assert!(!c.join(1, 3), "frame 0 twice");
        assert_eq!(c.find(0), c.find(3));
        assert_ne!(c.find(1), c.find(0));
    }
}
