//! Robust cylinder fitting in the spirit of Maalek et al. (2019), paper "Evaluation of Impact
//! of Calibration on Pipe Reconstruction":
//!
//! 1. **hypotheses** from pairs of oriented points: the axis `d = n1 × n2`, both points and
//!    normals projected onto the plane orthogonal to `d`, the centre where the two normal
//!    lines meet, the radius the mean distance to it;
//! 2. **consensus** scored by MSAC on a subsample, the threshold `3σ` with `σ` the data's own
//!    noise scale (the normals' robust plane scatter, then the residuals' MAD), never a
//!    user-tuned value; a point counts only if its normal also points at the axis (within
//!    30°), so walls and floors tangent to the pipe do not vote;
//! 3. **geometric least squares** of the five cylinder parameters (axis direction 2, axis point
//!    2, radius 1) on the inliers, minimising `distance to axis − r` — unbiased, unlike fits of
//!    `distance²` that return `sqrt(r² + σ²)` — with inliers re-selected at 3σ of the residuals'
//!    robust scale until they stop changing; the radius σ from `σ̂²·(JᵀJ)⁻¹`.

use std::num::NonZero;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix5, Vector3, Vector5};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::cloud::{BOX_RUN, Cloud, plane_of};
use super::shell::Shell;
use crate::robust::upper_median;

/// A cylinder: the axis through `point` along unit `direction`, and the radius.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Cylinder {
    /// A point on the axis.
    pub point: Vector3<f64>,
    /// Unit axis direction.
    pub direction: Vector3<f64>,
    /// Radius (m).
    pub radius: f64,
}

impl Cylinder {
    /// Signed distance of `p` from the surface (positive outside).
    #[must_use]
    pub fn residual(&self, p: &Vector3<f64>) -> f64 {
        (p - self.point).cross(&self.direction).norm() - self.radius
    }

    /// An orthonormal basis `(e1, e2)` of the plane orthogonal to the axis.
    #[must_use]
    pub fn cross_section_basis(&self) -> (Vector3<f64>, Vector3<f64>) {
        let d = self.direction;
        let e1 = if d.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = (e1 - e1.dot(&d) * d).normalize();
        (e1, d.cross(&e1))
    }

    /// The outward unit radial direction at `p`.
    #[must_use]
    pub fn radial(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.offset(p).normalize()
    }

    /// The vector from the axis to `p`, orthogonal to the axis (its length is `p`'s distance
    /// from the axis).
    #[must_use]
    pub fn offset(&self, p: &Vector3<f64>) -> Vector3<f64> {
        let w = p - self.point;
        w - w.dot(&self.direction) * self.direction
    }
}

/// How to fit.
#[derive(Clone, Debug, PartialEq)]
pub struct CylinderConfig {
    /// Smallest radius to accept (m).
    pub radius_min: f64,
    /// Largest radius to accept (m).
    pub radius_max: f64,
    /// Hypotheses drawn.
    pub hypotheses: usize,
    /// Points the hypotheses are scored on (a random subsample).
    pub score_sample: usize,
    /// Largest angle between a point's normal and the radial direction of an inlier (rad).
    pub max_normal_angle: f64,
    /// Only axes within this angle of the hint (rad), if given.
    pub axis_hint: Option<(Vector3<f64>, f64)>,
    /// Fewest inliers for a cylinder to count as found.
    pub min_inliers: usize,
    /// Seed of the sampling.
    pub seed: u64,
}

impl Default for CylinderConfig {
    fn default() -> Self {
        CylinderConfig {
            radius_min: 0.005,
            radius_max: 2.0,
            hypotheses: 2000,
            score_sample: 4000,
            max_normal_angle: 30f64.to_radians(),
            axis_hint: None,
            min_inliers: 100,
            seed: 1,
        }
    }
}

/// A fitted cylinder with its statistics.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CylinderFit {
    /// The cylinder in the input frame.
    pub cylinder: Cylinder,
    /// σ of the radius from the adjustment (m).
    pub radius_std: f64,
    /// RMS of the inliers' residuals (m).
    pub rmse: f64,
    /// Inlier count.
    pub inliers: usize,
    /// Robust noise scale the inliers were selected with (m).
    pub noise_scale: f64,
    /// Indices of the inliers (into the cloud's finite points).
    #[serde(skip)]
    pub inlier_indices: Vec<usize>,
}

/// Why no cylinder was reported.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CylinderError {
    /// No hypothesis gathered enough support.
    #[error(
        "no cylinder found: the best candidate has {best} inliers, at least {required} are needed"
    )]
    NotFound {
        /// Inliers of the best candidate.
        best: usize,
        /// Inliers required.
        required: usize,
    },
    /// The pipe-network search found no pipe of interest (none at all, or none along the axis
    /// hint).
    #[error(
        "no pipe found: {}; {refused} candidates refused as walls, boxes, narrow arcs or too short (`pipemeasure pipes` lists why)",
        if *.segments == 0 { "no pipe segment".to_string() } else { format!("{} pipe segments, none along the axis hint", .segments) }
    )]
    NoPipe {
        /// Pipe segments found (none of them along the hint).
        segments: usize,
        /// Candidates refused.
        refused: usize,
    },
    /// A configuration value is out of range.
    #[error("cylinder setting `{field}` is out of range: {value}")]
    Config {
        /// The field.
        field: &'static str,
        /// Its value.
        value: String,
    },
    /// The cloud cannot be prepared (too few finite points).
    #[error(transparent)]
    Cloud(#[from] super::cloud::CloudError),
}

impl CylinderConfig {
    /// Checks the fields.
    ///
    /// # Errors
    /// [`CylinderError::Config`] naming the field.
    pub fn validate(&self) -> Result<(), CylinderError> {
        let bad = |field: &'static str, value: String| Err(CylinderError::Config { field, value });
        if !(self.radius_min.is_finite() && self.radius_min >= 0.0) {
            return bad("radius_min", self.radius_min.to_string());
        }
        if !(self.radius_max.is_finite() && self.radius_max > self.radius_min) {
            return bad("radius_max", self.radius_max.to_string());
        }
        if self.hypotheses == 0 || self.score_sample < 10 {
            return bad("hypotheses", self.hypotheses.to_string());
        }
        if let Some((hint, angle)) = self.axis_hint
            && !((hint.norm() - 1.0).abs() < 1e-9
                && (0.0..=std::f64::consts::FRAC_PI_2).contains(&angle))
        {
            return bad(
                "axis_hint",
                format!(
                    "({}, {}, {}) within {angle} rad: expected a unit direction and an angle in [0, π/2]",
                    hint.x, hint.y, hint.z
                ),
            );
        }
        Ok(())
    }
}

/// A hypothesis from two oriented points (step 1), `None` when degenerate or out of range.
fn hypothesis(
    p1: &Vector3<f64>,
    n1: &Vector3<f64>,
    p2: &Vector3<f64>,
    n2: &Vector3<f64>,
    config: &CylinderConfig,
) -> Option<Cylinder> {
    let d = n1.cross(n2);
    if d.norm() < 0.05 {
        return None;
    }
    let d = d.normalize();
    if let Some((hint, angle)) = config.axis_hint
        && d.dot(&hint).abs() < angle.cos()
    {
        return None;
    }
    let flat = |v: &Vector3<f64>| v - v.dot(&d) * d;
    let (q1, q2) = (flat(p1), flat(p2));
    let (m1, m2) = (flat(n1).normalize(), flat(n2).normalize());
    // Closest points of the lines q1 + t·m1 and q2 + s·m2 (coplanar: they meet).
    let w = q1 - q2;
    let b = m1.dot(&m2);
    let denom = 1.0 - b * b;
    if denom < 1e-6 {
        return None;
    }
    let (dd, e) = (m1.dot(&w), m2.dot(&w));
    let t = (b * e - dd) / denom;
    let s = (e - b * dd) / denom;
    let c = 0.5 * ((q1 + t * m1) + (q2 + s * m2));
    let r = 0.5 * ((q1 - c).norm() + (q2 - c).norm());
    (r >= config.radius_min && r <= config.radius_max && r.is_finite()).then_some(Cylinder {
        point: c,
        direction: d,
        radius: r,
    })
}

/// Whether the point at curve position `k` ([`Cloud::position`]) supports `cyl` within its own
/// threshold ([`point_threshold`] over `floor`), its normal within `cos_max` of the radial
/// direction: its residual and threshold.
/// The point's local geometry is read (computed if need be) only when the residual is within
/// the largest threshold any point can have.
fn supports(
    cloud: &Cloud,
    k: usize,
    cyl: &Cylinder,
    floor: f64,
    cos_max: f64,
) -> Option<(f64, f64)> {
    support_of(
        cloud,
        &cloud.point_at(k),
        || cloud.local_at(k),
        cyl,
        floor,
        cos_max,
    )
}

/// Relative margin of [`support_of`]'s squared-distance pre-test: far above the rounding
/// of a square and a square root, so the pre-test never refuses a point the exact test takes.
const SQUARED_TEST_MARGIN: f64 = 1e-9;

/// [`supports`] for the point `p` whose local geometry `local` gives.
fn support_of(
    cloud: &Cloud,
    p: &Vector3<f64>,
    local: impl FnOnce() -> (Vector3<f64>, f64),
    cyl: &Cylinder,
    floor: f64,
    cos_max: f64,
) -> Option<(f64, f64)> {
    // The radial vector once: its length gives the residual, and the normal test compares
    // |n·v| with cos_max·|v| (no second square root, no division).
    let v = cyl.offset(p);
    let t_max = max_threshold(cloud, floor);
    // Most points are far from the surface: refused on the squared distance first, with a
    // margin that leaves every point near the band's edges to the exact test below.
    let rho2 = v.norm_squared();
    let outer = cyl.radius + t_max;
    let inner = (cyl.radius - t_max).max(0.0);
    if rho2 > outer * outer * (1.0 + SQUARED_TEST_MARGIN)
        || rho2 < inner * inner * (1.0 - SQUARED_TEST_MARGIN)
    {
        return None;
    }
    let rho = v.norm();
    let e = rho - cyl.radius;
    if e.abs() > t_max {
        return None;
    }
    let (normal, noise) = local();
    let t = point_threshold(noise, cloud, floor);
    (e.abs() <= t && normal.dot(&v).abs() >= cos_max * rho).then_some((e, t))
}

/// MSAC cost of a supporter's residual `e` and threshold `t` ((e/t)²), 1 for a point that
/// does not support.
fn msac_term(support: Option<(f64, f64)>) -> f64 {
    support.map_or(1.0, |(e, t)| (e / t).powi(2))
}

/// MSAC cost of the point at curve position `k` for `cyl` ([`msac_term`]).
fn msac_cost(cloud: &Cloud, k: usize, cyl: &Cylinder, floor: f64, cos_max: f64) -> f64 {
    msac_term(supports(cloud, k, cyl, floor, cos_max))
}

/// A pool of curve positions (sorted) cut into its runs within one box of
/// [`Cloud::run_box`].
fn box_runs(pool: &[usize]) -> Vec<&[usize]> {
    pool.chunk_by(|a, b| a / BOX_RUN == b / BOX_RUN).collect()
}

/// The curve positions of the pool (cut by [`box_runs`]) within the largest threshold of
/// `cyl` (those whose local geometry [`supports`] may read), in the pool's order.
fn near(cloud: &Cloud, runs: &[&[usize]], cyl: &Cylinder, floor: f64) -> Vec<usize> {
    let t = max_threshold(cloud, floor);
    // A box whose points' axis distances (the centre's ± the half diagonal) all miss
    // `radius ± t` is skipped whole.
    let shell = Shell {
        point: cyl.point,
        direction: cyl.direction,
        inner: cyl.radius - t,
        outer: cyl.radius + t,
        along: None,
    };
    let parts: Vec<Vec<usize>> = runs
        .par_chunks(16)
        .map(|chunk| {
            let mut part = Vec::new();
            for run in chunk {
                let (centre, half) = cloud.run_box(run[0] / BOX_RUN);
                if !shell.may_meet(&centre, half) {
                    continue;
                }
                part.extend(
                    run.iter()
                        .copied()
                        .filter(|&k| cyl.residual(&cloud.point_at(k)).abs() <= t),
                );
            }
            part
        })
        .collect();
    // Per chunk, then concatenated: a filtered parallel collect grows and links its pieces
    // element by element, at three times the cost.
    parts.concat()
}

/// Nearest sample neighbours the local half of the pairs draws its second point from.
const LOCAL_NEIGHBOURS: usize = 32;
/// Best hypotheses checked for angular coverage.
const TOP_HYPOTHESES: usize = 1000;
/// Hypotheses refined before the best is chosen.
const REFINED_HYPOTHESES: usize = 24;
/// Hypotheses refined at most, best first, in search of [`REFINED_HYPOTHESES`] that
/// refine: in a cluttered component the best-scored are strips of flat faces that fail their
/// refinement and a short pipe's come later (a process room's spool between two elbows was
/// missed with a cap of 24 or 32 and found with 48), while a component with no pipe left
/// would otherwise refine every one of its [`TOP_HYPOTHESES`] that passes the coverage test.
const MAX_REFINE_ATTEMPTS: usize = 4 * REFINED_HYPOTHESES;
/// Refined hypotheses tried in turn, best first, when the best does not settle on every
/// candidate point ([`fit_cylinder_among`]'s step 3).
const MAX_SETTLE_ATTEMPTS: usize = 4;
/// Smallest arc (rad) of the circumference the supporting points must fill (90°): a strip of
/// a plane tangent to a large cylinder has support but no arc, and a bent strip of a stereo
/// scan's table fills less than a quarter turn (with 60°, table artefacts beat the mug of the
/// real scan for most seeds; with 120°, the mug's sparse subsample fails the test too often).
pub const MIN_COVERAGE: f64 = std::f64::consts::FRAC_PI_2;

/// Angular bins of [`normal_coverage`] (10° each).
const COVERAGE_BINS: usize = 36;
/// A bin is filled when it holds at least this fraction of the mean count of the non-empty
/// bins.
const FILLED_BIN_FRACTION: f64 = 0.2;

/// The arc (rad) of the circumference the points at curve positions `idx` that support `cyl`
/// fill: the number of filled 10° bins of their azimuths about the axis, times 10°. A span
/// alone is not enough: a slightly bent strip of a plane (a stereo scan's table top) plus a few
/// stray supporters on the far side spans a wide arc but fills a narrow one.
fn normal_coverage(
    cloud: &Cloud,
    idx: &[usize],
    cyl: &Cylinder,
    threshold: f64,
    cos_max: f64,
) -> f64 {
    let (e1, e2) = cyl.cross_section_basis();
    // Counts per chunk, added up: integers, so the same bins on any number of threads.
    idx.par_chunks(COVERAGE_CHUNK)
        .map(|chunk| {
            let mut arc = ArcBins::new();
            for &k in chunk {
                if supports(cloud, k, cyl, threshold, cos_max).is_some() {
                    arc.add(azimuth(&cyl.radial(&cloud.point_at(k)), &e1, &e2));
                }
            }
            arc
        })
        .reduce(ArcBins::new, ArcBins::merged)
        .filled()
}

/// Points per parallel task of [`normal_coverage`].
const COVERAGE_CHUNK: usize = 4096;

/// The azimuth (rad, in [−π, π]) of the unit radial vector `u` in the cross-section basis
/// `(e1, e2)`.
fn azimuth(u: &Vector3<f64>, e1: &Vector3<f64>, e2: &Vector3<f64>) -> f64 {
    u.dot(e2).atan2(u.dot(e1))
}

/// Azimuths counted in [`COVERAGE_BINS`] bins of the turn ([`filled_arc`]).
#[derive(Clone, Copy, Debug)]
struct ArcBins([usize; COVERAGE_BINS]);

impl ArcBins {
    /// No azimuth counted.
    const fn new() -> Self {
        Self([0; COVERAGE_BINS])
    }

    /// Counts the azimuth `a` (from `atan2`, in [−π, π]).
    fn add(&mut self, a: f64) {
        let turn = a / std::f64::consts::TAU + 0.5;
        let bin = ((turn * COVERAGE_BINS as f64) as usize).min(COVERAGE_BINS - 1);
        self.0[bin] += 1;
    }

    /// Both counts together.
    fn merged(mut self, other: Self) -> Self {
        for (a, b) in self.0.iter_mut().zip(other.0) {
            *a += b;
        }
        self
    }

    /// The arc (rad) the counted azimuths fill: the number of filled bins (each holding at
    /// least [`FILLED_BIN_FRACTION`] of the mean count of the non-empty bins) times the bin's
    /// width; 0 for fewer than three azimuths.
    fn filled(&self) -> f64 {
        let bins = &self.0;
        let non_empty = bins.iter().filter(|&&c| c > 0).count();
        if non_empty == 0 || bins.iter().sum::<usize>() < 3 {
            return 0.0;
        }
        let mean = bins.iter().sum::<usize>() as f64 / non_empty as f64;
        let filled = bins
            .iter()
            .filter(|&&c| c as f64 >= FILLED_BIN_FRACTION * mean)
            .count();
        filled as f64 * std::f64::consts::TAU / COVERAGE_BINS as f64
    }
}

/// The arc (rad) that azimuths (from `atan2`, in [−π, π]) fill ([`ArcBins::filled`]).
pub(crate) fn filled_arc(azimuths: impl Iterator<Item = f64>) -> f64 {
    let mut arc = ArcBins::new();
    azimuths.for_each(|a| arc.add(a));
    arc.filled()
}

/// RMS distance of the points at curve positions `idx` from their least-squares plane.
fn plane_rms(cloud: &Cloud, idx: &[usize]) -> f64 {
    plane_of(idx.iter().map(|&k| cloud.point_at(k))).map_or(0.0, |(_, _, l)| l.sqrt())
}

/// The consensus threshold of a point of local noise `noise`: 3 × it, at least `floor`, at
/// most [`max_threshold`].
fn point_threshold(noise: f64, cloud: &Cloud, floor: f64) -> f64 {
    (3.0 * noise).min(3.0 * cloud.noise_cap).max(floor)
}

/// The largest consensus threshold: 3 × the cloud's noise cap, at least `floor`.
fn max_threshold(cloud: &Cloud, floor: f64) -> f64 {
    (3.0 * cloud.noise_cap).max(floor)
}

/// Step 3: Gauss–Newton on (axis direction, axis point, radius) over the curve positions
/// `idx`, minimising `Σ (|(p − a)×d| − r)²`. Returns the cylinder and `(JᵀJ)⁻¹` at the
/// solution.
fn refine(cloud: &Cloud, idx: &[usize], start: Cylinder) -> Option<(Cylinder, Matrix5<f64>, f64)> {
    let mut cyl = start;
    let mut cov = Matrix5::zeros();
    let mut ss = 0.0;
    for _ in 0..20 {
        let d = cyl.direction;
        let (e1, e2) = cyl.cross_section_basis();
        // Fixed-size chunks summed in order: the same result on any number of threads.
        let parts: Vec<(Matrix5<f64>, Vector5<f64>, f64)> = idx
            .par_chunks(4096)
            .map(|chunk| {
                // JᵀJ's upper triangle (products commute exactly: mirrored, the same matrix).
                let mut upper = [0.0; 15];
                let mut acc = (Matrix5::zeros(), Vector5::zeros(), 0.0);
                for &k in chunk {
                    let w = cloud.point_at(k) - cyl.point;
                    let wd = w.dot(&d);
                    let v = w - wd * d;
                    let rho = v.norm().max(1e-300);
                    let u = v / rho;
                    let r = rho - cyl.radius;
                    let j = Vector5::new(
                        -wd * u.dot(&e1),
                        -wd * u.dot(&e2),
                        -u.dot(&e1),
                        -u.dot(&e2),
                        -1.0,
                    );
                    let mut i = 0;
                    for a in 0..5 {
                        for b in a..5 {
                            upper[i] += j[a] * j[b];
                            i += 1;
                        }
                    }
                    acc.1 += j * r;
                    acc.2 += r * r;
                }
                let mut i = 0;
                for a in 0..5 {
                    for b in a..5 {
                        acc.0[(a, b)] = upper[i];
                        acc.0[(b, a)] = upper[i];
                        i += 1;
                    }
                }
                acc
            })
            .collect();
        let (mut jtj, mut jtr, mut sum) = (Matrix5::zeros(), Vector5::zeros(), 0.0);
        for (a, b, c) in parts {
            jtj += a;
            jtr += b;
            sum += c;
        }
        cov = jtj.try_inverse()?;
        ss = sum;
        let step = -(cov * jtr);
        let dir = (d + step[0] * e1 + step[1] * e2).normalize();
        let point = cyl.point + step[2] * e1 + step[3] * e2;
        // Keep the axis point the one nearest the local origin (it slides along the axis).
        let point = point - point.dot(&dir) * dir;
        cyl = Cylinder {
            point,
            direction: dir,
            radius: cyl.radius + step[4],
        };
        // Quadratic convergence: the error after a step of 1e-10 is far below 1e-12 m.
        if step.norm() < 1e-10 * (1.0 + cyl.radius) {
            break;
        }
    }
    Some((cyl, cov, ss))
}

/// Fits the best-supported cylinder of a prepared cloud.
///
/// Deterministic: the same cloud and seed give the same fit on any number of threads.
///
/// # Errors
/// [`CylinderError::NotFound`] when no candidate reaches `min_inliers`;
/// [`CylinderError::Config`] for bad settings.
pub fn fit_cylinder(cloud: &Cloud, config: &CylinderConfig) -> Result<CylinderFit, CylinderError> {
    let all: Vec<usize> = (0..cloud.len()).collect();
    // Every index, and every curve position in order.
    fit_among(cloud, &all, &all, config)
}

/// [`fit_cylinder`] restricted to the points `candidates` (a region of interest, or what
/// earlier fits left).
///
/// # Errors
/// See [`fit_cylinder`].
pub fn fit_cylinder_among(
    cloud: &Cloud,
    candidates: &[usize],
    config: &CylinderConfig,
) -> Result<CylinderFit, CylinderError> {
    let mut pool: Vec<usize> = candidates.iter().map(|&k| cloud.position(k)).collect();
    pool.par_sort_unstable();
    pool.dedup();
    fit_among(cloud, candidates, &pool, config)
}

/// [`fit_cylinder_among`] with the candidates also given as their curve positions `pool`
/// (sorted): the subsample is drawn from `candidates`, the passes over every candidate run
/// over `pool`, reading the points and their local geometry in memory order.
///
/// Kept whole (one function over 150 lines): its stages (draw, MSAC scoring with the arc,
/// refinement of the covering hypotheses in rank order, the settle check) share the subsample's
/// cached geometry and the ranked list in place; split, each would take most of them as
/// arguments.
fn fit_among(
    cloud: &Cloud,
    candidates: &[usize],
    pool: &[usize],
    config: &CylinderConfig,
) -> Result<CylinderFit, CylinderError> {
    config.validate()?;
    let not_found = |best| CylinderError::NotFound {
        best,
        required: config.min_inliers,
    };
    let cos_max = config.max_normal_angle.cos();
    if candidates.len() < config.min_inliers.max(3) {
        return Err(not_found(0));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let n = candidates.len();
    let sample: Vec<usize> = if n <= config.score_sample {
        candidates.to_vec()
    } else {
        (0..config.score_sample)
            .map(|_| candidates[rng.random_range(0..n)])
            .collect()
    };
    let sample: Vec<usize> = sample.iter().map(|&k| cloud.position(k)).collect();
    cloud.prepare_at(&sample);
    // Half the pairs anywhere in the sample, half local: the second point among the first's
    // nearest sample neighbours, so that small cylinders in large scenes get pairs on them.
    let entries: Vec<[f64; 3]> = sample.iter().map(|&k| cloud.point_at(k).into()).collect();
    let tree: ImmutableKdTree<f64, 3> =
        ImmutableKdTree::new_from_slice(&entries).map_err(|_| not_found(0))?;
    let local_k = NonZero::new(LOCAL_NEIGHBOURS.min(sample.len())).unwrap_or(NonZero::<usize>::MIN);
    let pairs: Vec<(usize, usize)> = (0..config.hypotheses)
        .map(|h| {
            let a = rng.random_range(0..sample.len());
            let b = if h % 2 == 0 {
                rng.random_range(0..sample.len())
            } else {
                let nb = tree
                    .query(&entries[a])
                    .nearest_n::<SquaredEuclidean<f64>>(local_k)
                    .execute();
                // Never empty for finite points (the cloud's extent is bounded); guarded all
                // the same, since an empty range would panic.
                if nb.is_empty() {
                    rng.random_range(0..sample.len())
                } else {
                    nb[rng.random_range(0..nb.len())].item as usize
                }
            };
            (sample[a], sample[b])
        })
        .collect();
    // The floor of every point's threshold: 3 × the cloud's typical local noise.
    let threshold = (3.0 * cloud.surface_noise).max(1e-6);
    // The subsample's points and local geometry side by side: every hypothesis reads them.
    let oriented: Vec<(Vector3<f64>, Vector3<f64>, f64)> = sample
        .iter()
        .map(|&k| {
            let (normal, noise) = cloud.local_at(k);
            (cloud.point_at(k), normal, noise)
        })
        .collect();
    // Step 2: MSAC over the subsample, hypotheses in parallel, ties broken by index; the
    // arc the supporters fill ([`normal_coverage`]) in the same pass, for step 3's test.
    let mut scored: Vec<(f64, usize, Cylinder, f64)> = pairs
        .par_iter()
        .enumerate()
        .filter_map(|(h, &(a, b))| {
            let cyl = hypothesis(
                &cloud.point_at(a),
                &cloud.local_at(a).0,
                &cloud.point_at(b),
                &cloud.local_at(b).0,
                config,
            )?;
            // MSAC with each point's own threshold (3 × its local noise), normalised.
            let (e1, e2) = cyl.cross_section_basis();
            let mut arc = ArcBins::new();
            let mut cost = 0.0;
            for (p, normal, noise) in &oriented {
                let local = || (*normal, *noise);
                let support = support_of(cloud, p, local, &cyl, threshold, cos_max);
                if support.is_some() {
                    arc.add(azimuth(&cyl.radial(p), &e1, &e2));
                }
                cost += msac_term(support);
            }
            Some((cost, h, cyl, arc.filled()))
        })
        .collect();
    scored.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    // The best few hypotheses whose supporting normals turn around the axis (a strip of a
    // plane tangent to a large cylinder has support but one normal direction), each refined
    // on its sample support; the one with the least MSAC cost after refinement wins.
    // The refined candidates compete on every candidate point, not the subsample: a small
    // object (a mug: 3 % of a scan) has too few sample points for the sample's cost to rank it
    // reliably against artefacts of similar support.
    // MSAC over every candidate: the points beyond the largest threshold cost 1 each, the
    // near ones (`near`, in curve order) are scored.
    // Blocks of 16 chunks of 4096, the chunks' sums added in order; stops (None) as soon as
    // the cost exceeds `bound` (every cost is at least 0, so the total would too).
    let msac_within = |c: &Cylinder, near: &[usize], bound: f64| -> Option<f64> {
        let outside = (pool.len() - near.len()) as f64;
        let mut inside = 0.0;
        for block in near.chunks(16 * 4096) {
            if outside + inside > bound {
                return None;
            }
            let sums: Vec<f64> = block
                .par_chunks(4096)
                .map(|chunk| {
                    chunk
                        .iter()
                        .map(|&k| msac_cost(cloud, k, c, threshold, cos_max))
                        .sum::<f64>()
                })
                .collect();
            inside = sums.iter().fold(inside, |a, b| a + b);
        }
        Some(outside + inside)
    };
    let select = |c: &Cylinder, pool: &[usize]| -> Vec<usize> {
        pool.iter()
            .copied()
            .filter(|&k| supports(cloud, k, c, threshold, cos_max).is_some())
            .collect()
    };
    let runs = box_runs(pool);
    let in_range = |c: &Cylinder| c.radius >= config.radius_min && c.radius <= config.radius_max;
    // The first REFINED_HYPOTHESES of the best TOP_HYPOTHESES whose sample support turns
    // around the axis and still does once refined, checked in parallel batches (the same ones
    // as one by one). One that fails its refinement does not take a place: in a cluttered
    // component (a beam with a short pipe on it) the best-scored hypotheses are strips of
    // flat faces that fail, and the pipe's come later; at most MAX_REFINE_ATTEMPTS are
    // refined.
    let refine_one = |c: &Cylinder| -> Option<Cylinder> {
        let support = select(c, &sample);
        if support.len() < 6 {
            return None;
        }
        let (r, _, ss) = refine(cloud, &support, *c)?;
        let cyl_rms = (ss / support.len() as f64).sqrt();
        // A patch of a plane fits a large cylinder too: refuse support that a plane
        // explains (no curvature beyond the noise).
        let curved = plane_rms(cloud, &support) > 3.0 * cyl_rms;
        let around = normal_coverage(cloud, &support, &r, threshold, cos_max) >= MIN_COVERAGE;
        (in_range(&r) && curved && around).then_some(r)
    };
    let mut refined: Vec<Cylinder> = Vec::with_capacity(REFINED_HYPOTHESES);
    let mut attempts = 0;
    for batch in scored[..scored.len().min(TOP_HYPOTHESES)].chunks(2 * REFINED_HYPOTHESES) {
        let covering: Vec<&Cylinder> = batch
            .iter()
            .filter(|h| h.3 >= MIN_COVERAGE)
            .map(|h| &h.2)
            .collect();
        let take = covering.len().min(MAX_REFINE_ATTEMPTS - attempts);
        attempts += take;
        let found: Vec<Option<Cylinder>> =
            covering[..take].par_iter().map(|c| refine_one(c)).collect();
        refined.extend(found.into_iter().flatten());
        if refined.len() >= REFINED_HYPOTHESES || attempts >= MAX_REFINE_ATTEMPTS {
            break;
        }
    }
    refined.truncate(REFINED_HYPOTHESES);
    // The first with the least cost wins. A candidate whose points beyond its band alone
    // cost more than the best so far is dropped before its band's local geometry is computed;
    // one whose cost passes the best part way is dropped there.
    let best_of = |refined: &[Cylinder]| -> Option<usize> {
        let mut best: Option<(f64, usize)> = None;
        for (i, r) in refined.iter().enumerate() {
            let bound = best.as_ref().map_or(f64::INFINITY, |b| b.0);
            let band = near(cloud, &runs, r, threshold);
            if (pool.len() - band.len()) as f64 > bound {
                continue;
            }
            cloud.prepare_at(&band);
            if let Some(cost) = msac_within(r, &band, bound).filter(|&cost| cost < bound) {
                best = Some((cost, i));
            }
        }
        best.map(|b| b.1)
    };
    // Step 3: inliers over every candidate (each point's own threshold), geometric LS, until
    // the inliers stop changing. A winner that does not settle (its band grows over a flat
    // face beside it until the radius leaves the range) gives way to the next best.
    let settle = |mut cyl: Cylinder| -> Result<CylinderFit, CylinderError> {
        let mut inliers: Vec<usize> = Vec::new();
        let mut result = None;
        for _ in 0..10 {
            let band = near(cloud, &runs, &cyl, threshold);
            cloud.prepare_at(&band);
            let parts: Vec<Vec<usize>> = band
                .par_chunks(4096)
                .map(|chunk| select(&cyl, chunk))
                .collect();
            let next = parts.concat();
            if next.len() < config.min_inliers.max(6) {
                return Err(not_found(next.len()));
            }
            let same = next == inliers;
            inliers = next;
            let Some((c, cov, ss)) = refine(cloud, &inliers, cyl) else {
                return Err(not_found(inliers.len()));
            };
            cyl = c;
            if !in_range(&cyl) {
                return Err(not_found(0));
            }
            let dof = (inliers.len() - 5) as f64;
            result = Some((cov[(4, 4)] * ss / dof, ss));
            if same {
                break;
            }
        }
        let (var_r, ss) = result.ok_or_else(|| not_found(0))?;
        Ok(summarise(cloud, &inliers, &cyl, var_r, ss))
    };
    let mut failure = not_found(0);
    for _ in 0..MAX_SETTLE_ATTEMPTS {
        let Some(i) = best_of(&refined) else {
            break;
        };
        match settle(refined.remove(i)) {
            Ok(fit) => return Ok(fit),
            Err(e) => failure = e,
        }
    }
    Err(failure)
}

/// The fit's statistics from its inliers (curve positions), its cylinder (local frame), the
/// radius's variance and the residuals' sum of squares.
fn summarise(cloud: &Cloud, inliers: &[usize], cyl: &Cylinder, var_r: f64, ss: f64) -> CylinderFit {
    // The median absolute residual: non-negative floats order like their bits.
    let mut abs: Vec<u64> = inliers
        .par_iter()
        .map(|&k| cyl.residual(&cloud.point_at(k)).abs().to_bits())
        .collect();
    let middle = abs.len() / 2;
    let scale = abs.select_nth_unstable(middle).1.to_owned();
    let scale = crate::robust::MAD_TO_SIGMA * f64::from_bits(scale);
    let mut inlier_indices: Vec<usize> = inliers.iter().map(|&pos| cloud.index_at(pos)).collect();
    inlier_indices.par_sort_unstable();
    CylinderFit {
        cylinder: Cylinder {
            point: cyl.point + cloud.origin,
            direction: cyl.direction,
            radius: cyl.radius,
        },
        radius_std: var_r.max(0.0).sqrt(),
        rmse: (ss / inliers.len() as f64).sqrt(),
        inliers: inliers.len(),
        noise_scale: scale,
        inlier_indices,
    }
}

/// Inlier sets that differ by at most one point in this many are settled ([`refit_among`]):
/// on a pipe of 375,000 inliers a few dozen points at the band's edge flip at every pass, and
/// each pass moves the radius by a thousandth of its σ.
const SETTLED_POINTS: usize = 10_000;

/// Whether the sorted inlier sets `a` and `b` differ by at most one point in
/// [`SETTLED_POINTS`] (their symmetric difference, counted in one merge).
fn settled(a: &[usize], b: &[usize]) -> bool {
    let allowed = a.len().max(b.len()) / SETTLED_POINTS;
    let (mut i, mut j, mut differ) = (0, 0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            std::cmp::Ordering::Equal => {
                i += 1;
                j += 1;
            }
            std::cmp::Ordering::Less => {
                differ += 1;
                i += 1;
            }
            std::cmp::Ordering::Greater => {
                differ += 1;
                j += 1;
            }
        }
        if differ > allowed {
            return false;
        }
    }
    differ + (a.len() - i) + (b.len() - j) <= allowed
}

/// A cylinder fitted again to the points `indices` alone (a segment of a pipe that
/// [`fit_cylinder_among`] found on a longer axis), from `start` (input frame): step 3 on the
/// supporters among them until they stop changing. Returns the fit and the arc (rad) of the
/// circumference its inliers fill (10° bins); `None` with fewer than six supporters.
#[must_use]
pub fn refit_among(
    cloud: &Cloud,
    indices: &[usize],
    start: &Cylinder,
    config: &CylinderConfig,
) -> Option<(CylinderFit, f64)> {
    refit_warm(cloud, indices, start, &[], config)
}

/// [`refit_among`] from a fit that already holds: `inliers` (cloud indices) are the points
/// `start` was fitted to. When the first selection settles on them, the iterations stop
/// after one adjustment instead of three or four over every point.
pub(crate) fn refit_warm(
    cloud: &Cloud,
    indices: &[usize],
    start: &Cylinder,
    inliers: &[usize],
    config: &CylinderConfig,
) -> Option<(CylinderFit, f64)> {
    let cos_max = config.max_normal_angle.cos();
    let threshold = (3.0 * cloud.surface_noise).max(1e-6);
    let mut pool: Vec<usize> = indices.iter().map(|&k| cloud.position(k)).collect();
    pool.par_sort_unstable();
    pool.dedup();
    cloud.prepare_at(&pool);
    let mut cyl = Cylinder {
        point: start.point - cloud.origin,
        ..*start
    };
    let mut inliers: Vec<usize> = inliers.iter().map(|&k| cloud.position(k)).collect();
    inliers.par_sort_unstable();
    let mut result = None;
    for _ in 0..10 {
        // An order-keeping parallel filter: the same list on any number of threads.
        let next: Vec<usize> = pool
            .par_iter()
            .copied()
            .filter(|&k| supports(cloud, k, &cyl, threshold, cos_max).is_some())
            .collect();
        if next.len() < 6 {
            return None;
        }
        let same = settled(&next, &inliers);
        inliers = next;
        let (c, cov, ss) = refine(cloud, &inliers, cyl)?;
        cyl = c;
        let dof = (inliers.len() - 5) as f64;
        result = Some((cov[(4, 4)] * ss / dof, ss));
        if same {
            break;
        }
    }
    let (mut var_r, mut ss) = result?;
    // Then with the band the residuals themselves give, 3 × their robust scale (at least the
    // cloud's floor): a neighbourhood's noise on a thin pipe far from the scanner includes
    // its curvature, and so wide a band takes in the mixed pixels behind its silhouette,
    // which all lie outside it.
    for _ in 0..10 {
        let mut abs: Vec<f64> = inliers
            .par_iter()
            .map(|&k| cyl.residual(&cloud.point_at(k)).abs())
            .collect();
        let band =
            (3.0 * crate::robust::MAD_TO_SIGMA * upper_median(&mut abs)).max(threshold.min(1e-3));
        let next: Vec<usize> = pool
            .par_iter()
            .copied()
            .filter(|&k| {
                supports(cloud, k, &cyl, threshold, cos_max).is_some()
                    && cyl.residual(&cloud.point_at(k)).abs() <= band
            })
            .collect();
        if next.len() < 6 || settled(&next, &inliers) {
            break;
        }
        inliers = next;
        let (c, cov, s) = refine(cloud, &inliers, cyl)?;
        cyl = c;
        var_r = cov[(4, 4)] * s / (inliers.len() - 5) as f64;
        ss = s;
    }
    let coverage = normal_coverage(cloud, &inliers, &cyl, threshold, cos_max);
    Some((summarise(cloud, &inliers, &cyl, var_r, ss), coverage))
}

/// Every cylinder of the cloud, best supported first: fit, remove its inliers, repeat until
/// none is found (at most `max_count`).
#[must_use]
pub fn fit_all_cylinders(
    cloud: &Cloud,
    config: &CylinderConfig,
    max_count: usize,
) -> Vec<CylinderFit> {
    let mut remaining: Vec<usize> = (0..cloud.len()).collect();
    let mut out = Vec::new();
    while out.len() < max_count {
        let Ok(fit) = fit_cylinder_among(cloud, &remaining, config) else {
            break;
        };
        let taken: std::collections::HashSet<usize> = fit.inlier_indices.iter().copied().collect();
        remaining.retain(|k| !taken.contains(k));
        out.push(fit);
    }
    out
}
