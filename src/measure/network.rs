//! The pipe network of a cluttered cloud (issue 20): every physical pipe once, split into
//! straight segments with their axis endpoints, and what was refused and why.
//!
//! 1. **Planes out**: walls, floor and ceiling (and any plane at least
//!    [`NetworkConfig::plane_min_width_m`] wide across) are found by consensus on the points'
//!    own normals and removed, so that the cylinder search samples pipes, not walls.
//! 2. **Components**: the rest is cut into connected pieces on a grid of
//!    [`NetworkConfig::cell_m`] cells; each piece is searched on its own, so a small pipe gets
//!    the same sampling as a large one.
//! 3. **Candidates**: in each piece, [`fit_cylinder_among`] repeatedly (fit, remove inliers):
//!    axes with their inliers.
//! 4. **Segments**: each candidate's inliers along its axis, cut at gaps longer than
//!    [`NetworkConfig::gap_m`] (a valve, an occlusion too long to bridge); each piece re-fitted
//!    alone ([`refit_among`]), its endpoints the extreme inliers along the axis.
//! 5. **Tests**, best supported first: a piece on the axis of an accepted segment with the same
//!    radius is merged into it, with another radius refused (a flange, a nozzle, an insulated
//!    stretch); a piece whose inliers fill less than [`NetworkConfig::min_coverage_rad`] of the
//!    circumference is a strip of a larger curved surface; a piece shorter than
//!    [`NetworkConfig::min_length_m`] or than [`NetworkConfig::min_length_diameters`] diameters
//!    is a fitting or a housing (a pump's volute is a short, wide cylinder).
//!
//! The radius of interest ([`CylinderConfig::radius_min`], `radius_max`) bounds what can be a
//! pipe: a wall's gentle bow fits a cylinder of metres.

use std::sync::atomic::{AtomicU64, Ordering};

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::cloud::{Cloud, CloudError, plane_of};
use super::cylinder::{
    Cylinder, CylinderConfig, CylinderError, filled_arc, fit_cylinder_among, refit_among,
};
use super::nominal::{NominalSize, PipeMaterial, nominal_size};
use crate::robust::upper_median;

/// How to extract the network.
#[derive(Clone, Debug, PartialEq)]
pub struct NetworkConfig {
    /// The cylinder search (radius of interest, seed, fewest inliers).
    pub cylinder: CylinderConfig,
    /// Most planes removed.
    pub max_planes: usize,
    /// Fewest points of a plane to remove it.
    pub plane_min_points: usize,
    /// Smallest width of a plane to remove (m): the standard deviation of its points across
    /// their main direction (a strip along a pipe is narrower).
    pub plane_min_width_m: f64,
    /// Largest angle between a point's normal and a plane's (rad).
    pub plane_normal_angle: f64,
    /// Grid cell of the connected components (m).
    pub cell_m: f64,
    /// Most candidates per component.
    pub max_candidates_per_component: usize,
    /// Gap along an axis that splits a run into segments (m).
    pub gap_m: f64,
    /// Shortest segment (m).
    pub min_length_m: f64,
    /// Shortest segment in diameters.
    pub min_length_diameters: f64,
    /// Smallest arc of the circumference a segment's inliers fill (rad).
    pub min_coverage_rad: f64,
    /// Smallest turn of the normals per turn of the points about the axis (1 on a cylinder,
    /// near 0 on flat faces; a thin pipe far from the scanner, whose normals average over
    /// much of its arc, turns 0.3–0.6).
    pub min_normal_turn: f64,
    /// Largest median angle between the normals and the radial direction (rad): a few
    /// degrees on a pipe (8° on a thin one far away), more on two thin conduits side by side.
    pub max_normal_deviation: f64,
    /// Largest systematic departure of the points from the circle (m; per 10° of azimuth the
    /// mean residual, their RMS less the noise's share): a tenth of a millimetre on a round pipe (ASTM A530's out-of-roundness, 1.5 % of the
    /// outside diameter, is 0.3 mm RMS on a 2-inch pipe), millimetres on a box's edge.
    pub max_shape_departure_m: f64,
    /// Largest angle between two axes that are one (rad).
    pub coaxial_angle: f64,
    /// Largest distance between two axes that are one, as a fraction of the smaller radius.
    pub coaxial_offset: f64,
    /// The material whose standard sizes are reported.
    pub material: PipeMaterial,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        NetworkConfig {
            cylinder: CylinderConfig {
                radius_min: 0.015,
                radius_max: 0.35,
                ..CylinderConfig::default()
            },
            max_planes: 16,
            plane_min_points: 2000,
            plane_min_width_m: 0.2,
            plane_normal_angle: 20f64.to_radians(),
            cell_m: 0.05,
            max_candidates_per_component: 24,
            gap_m: 0.25,
            min_length_m: 0.3,
            min_length_diameters: 2.0,
            min_coverage_rad: std::f64::consts::FRAC_PI_2,
            min_normal_turn: 0.2,
            max_normal_deviation: 12f64.to_radians(),
            max_shape_departure_m: 1.2e-3,
            coaxial_angle: 5f64.to_radians(),
            coaxial_offset: 0.5,
            material: PipeMaterial::Steel,
        }
    }
}

/// One straight pipe segment.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PipeSegment {
    /// Index in the network's list.
    pub id: usize,
    /// Axis start (input frame, m).
    pub start: [f64; 3],
    /// Axis end (m).
    pub end: [f64; 3],
    /// Length of the axis (m).
    pub length_m: f64,
    /// Outside radius (m).
    pub radius_m: f64,
    /// Its σ from the fit (m).
    pub radius_std_m: f64,
    /// RMS of the inliers' residuals (m).
    pub rmse_m: f64,
    /// Inliers.
    pub inliers: usize,
    /// Inliers among the points searched: `inliers` unless the scan was decimated for the
    /// search and the segment re-fitted on every point ([`super::scan`]).
    pub searched_inliers: usize,
    /// Arc of the circumference the inliers fill (degrees).
    pub coverage_deg: f64,
    /// Median angle between the inliers' normals and the radial direction (degrees).
    pub normal_deviation_deg: f64,
    /// How the normals turn with the points about the axis (1 on a cylinder).
    pub normal_turn: f64,
    /// The points' systematic departure from the circle (m).
    pub shape_departure_m: f64,
    /// The closest standard size.
    pub nominal: NominalSize,
    /// The inliers (indices into the cloud's finite points).
    #[serde(skip)]
    pub inlier_indices: Vec<usize>,
}

impl PipeSegment {
    /// The segment's axis as (start, unit direction, length).
    #[must_use]
    pub fn axis(&self) -> (Vector3<f64>, Vector3<f64>, f64) {
        let a = Vector3::from(self.start);
        let d = Vector3::from(self.end) - a;
        let l = d.norm();
        (a, d / l.max(f64::MIN_POSITIVE), l)
    }
}

/// Why a candidate is not a pipe segment.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "kebab-case")]
pub enum Refusal {
    /// On the axis of segment `segment` with another radius.
    SecondRadius {
        /// The segment that holds the axis.
        segment: usize,
        /// Its radius (m).
        segment_radius_m: f64,
    },
    /// Its inliers fill too small an arc.
    NarrowArc {
        /// The arc (degrees).
        coverage_deg: f64,
    },
    /// Its points are not a round surface: flat faces (a box, a column, a support) whose
    /// normals hold a few directions instead of turning with them about the axis, or several
    /// thin objects side by side (normals off the radial direction, points off the circle).
    Facets {
        /// The arc the points fill (degrees).
        coverage_deg: f64,
        /// The arc their normals fill (degrees).
        normal_arc_deg: f64,
        /// How their normals turn with them about the axis (1 on a cylinder).
        normal_turn: f64,
        /// The median angle between their normals and the radial direction (degrees).
        normal_deviation_deg: f64,
        /// Their systematic departure from the circle (mm).
        shape_departure_mm: f64,
    },
    /// Too short for a pipe segment.
    TooShort {
        /// Its length (m).
        length_m: f64,
        /// The shortest accepted (m).
        min_length_m: f64,
    },
    /// Its inliers could not be re-fitted alone.
    NoFit,
    /// Re-fitted alone, its radius left the radius of interest.
    RadiusOutOfRange {
        /// Smallest radius of interest (m).
        min_m: f64,
        /// Largest (m).
        max_m: f64,
    },
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::SecondRadius {
                segment,
                segment_radius_m,
            } => write!(
                f,
                "on the axis of segment {segment} (r {:.1} mm) with another radius: a flange, nozzle or fitting",
                segment_radius_m * 1e3
            ),
            Refusal::NarrowArc { coverage_deg } => write!(
                f,
                "its points fill {coverage_deg:.0}° of the circumference: a strip of a larger surface"
            ),
            Refusal::TooShort {
                length_m,
                min_length_m,
            } => write!(
                f,
                "{:.2} m long, shorter than {:.2} m: a fitting, flange or housing",
                length_m, min_length_m
            ),
            Refusal::Facets {
                coverage_deg,
                normal_arc_deg,
                normal_turn,
                normal_deviation_deg,
                shape_departure_mm,
            } => write!(
                f,
                "not a round surface (points over {coverage_deg:.0}°, normals over {normal_arc_deg:.0}° turning {normal_turn:.2}× with them, {normal_deviation_deg:.0}° off radial, {shape_departure_mm:.2} mm RMS off the circle): flat faces (a box, a column, a support) or several thin objects"
            ),
            Refusal::NoFit => write!(f, "its points alone do not fit a cylinder"),
            Refusal::RadiusOutOfRange { min_m, max_m } => write!(
                f,
                "outside the radius of interest {:.1}–{:.1} mm",
                min_m * 1e3,
                max_m * 1e3
            ),
        }
    }
}

/// A refused candidate.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RefusedCandidate {
    /// Axis start (m).
    pub start: [f64; 3],
    /// Axis end (m).
    pub end: [f64; 3],
    /// Radius (m).
    pub radius_m: f64,
    /// Inliers.
    pub inliers: usize,
    /// Median angle between the inliers' normals and the radial direction (degrees).
    pub normal_deviation_deg: f64,
    /// How the normals turn with the points about the axis (1 on a cylinder).
    pub normal_turn: f64,
    /// The points' systematic departure from the circle (m).
    pub shape_departure_m: f64,
    /// Why.
    #[serde(flatten)]
    pub refusal: Refusal,
}

/// A plane that was removed before the cylinder search.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RemovedPlane {
    /// Unit normal.
    pub normal: [f64; 3],
    /// A point of it (the inliers' mean, input frame).
    pub point: [f64; 3],
    /// Its points.
    pub points: usize,
}

/// The extracted network.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Network {
    /// Finite points of the cloud.
    pub points: usize,
    /// Planes removed first.
    pub planes: Vec<RemovedPlane>,
    /// Connected components searched.
    pub components: usize,
    /// Every pipe segment, the best supported first.
    pub segments: Vec<PipeSegment>,
    /// Every refused candidate.
    pub refused: Vec<RefusedCandidate>,
}

/// Why no network could be extracted.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NetworkError {
    /// The cloud cannot be prepared.
    #[error(transparent)]
    Cloud(#[from] CloudError),
    /// A setting is out of range.
    #[error(transparent)]
    Config(#[from] CylinderError),
}

/// Extracts the pipe network of `points` (input frame).
///
/// Deterministic for a given seed, whatever the thread count.
///
/// # Errors
///
/// [`NetworkError`] when the cloud cannot be prepared or a setting is out of range. A cloud
/// without pipes is a network with no segments (and what was refused).
pub fn extract_network(
    points: &[Vector3<f64>],
    config: &NetworkConfig,
) -> Result<Network, NetworkError> {
    config.cylinder.validate()?;
    let cloud = Cloud::new(points)?;
    let all: Vec<usize> = (0..cloud.len()).collect();
    cloud.prepare_at(&all);
    let (planes, remaining) = remove_planes(&cloud, all, config);
    let components = components(&cloud, &remaining, config);
    // Each component searched as a cloud of its own: its noise scale and consensus
    // thresholds are its own (a thin pipe far from the scanner is noisier than the walls
    // that set the whole cloud's), and a sample of it is all pipe and fittings.
    let mut pieces: Vec<Piece> = Vec::new();
    for comp in &components {
        let pts: Vec<Vector3<f64>> = comp
            .iter()
            .map(|&pos| cloud.point_at(pos) + cloud.origin)
            .collect();
        let Ok(sub) = Cloud::new(&pts) else {
            continue;
        };
        let mut left: Vec<usize> = (0..sub.len()).collect();
        let mut candidates: Vec<(Cylinder, Vec<usize>)> = Vec::new();
        for _ in 0..config.max_candidates_per_component {
            let Ok(fit) = fit_cylinder_among(&sub, &left, &config.cylinder) else {
                break;
            };
            let mut taken = vec![false; sub.len()];
            for &k in &fit.inlier_indices {
                taken[k] = true;
            }
            left.retain(|&k| !taken[k]);
            candidates.push((fit.cylinder, fit.inlier_indices));
            if left.len() < config.cylinder.min_inliers {
                break;
            }
        }
        // Pieces along each axis, re-fitted alone, their points renamed into the whole cloud.
        let found: Vec<Piece> = candidates
            .par_iter()
            .flat_map_iter(|(cyl, inliers)| pieces_of(&sub, cyl, inliers, config))
            .collect();
        pieces.extend(found.into_iter().map(|mut p| {
            p.indices = p.indices.iter().map(|&k| cloud.index_at(comp[k])).collect();
            p.indices.sort_unstable();
            p
        }));
    }
    // Best supported first.
    pieces.sort_by(|a, b| {
        b.indices
            .len()
            .cmp(&a.indices.len())
            .then(a.start.x.total_cmp(&b.start.x))
    });
    let (segments, refused) = accept(&cloud, pieces, config);
    Ok(Network {
        points: cloud.len(),
        planes,
        components: components.len(),
        segments,
        refused,
    })
}

/// A stretch of a candidate's inliers along its axis, re-fitted.
#[derive(Clone, Debug)]
struct Piece {
    cylinder: Cylinder,
    radius_std: f64,
    rmse: f64,
    coverage: f64,
    /// The arc the inliers' normals fill about the axis (rad): a cylinder's turn with the
    /// points, a box's faces each hold one direction.
    normal_arc: f64,
    /// The median angle between the inliers' normals and the radial direction (rad): a few
    /// degrees on a cylinder, tens on the faces of a box's edge.
    normal_deviation: f64,
    /// [`normal_turn`]: 1 on a cylinder, near 0 on a box's faces.
    normal_turn: f64,
    /// [`shape_departure`] (m).
    departure: f64,
    start: Vector3<f64>,
    end: Vector3<f64>,
    /// The extreme inliers before the straight part was cut, on the axis, in `start`/`end`
    /// order (an end cut by mixed pixels at a wall still finds the wall from there).
    raw: [Vector3<f64>; 2],
    /// Its inliers (cloud indices), sorted.
    indices: Vec<usize>,
    fitted: bool,
}

/// The candidate's inliers cut at gaps along its axis, each stretch re-fitted alone, with its
/// extreme inliers as endpoints.
fn pieces_of(
    cloud: &Cloud,
    cyl: &Cylinder,
    inliers: &[usize],
    config: &NetworkConfig,
) -> Vec<Piece> {
    let along =
        |k: usize, c: &Cylinder| (cloud.point(k) + cloud.origin - c.point).dot(&c.direction);
    let mut order: Vec<(f64, usize)> = inliers.iter().map(|&k| (along(k, cyl), k)).collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut out = Vec::new();
    let runs = order
        .chunk_by(|a, b| b.0 - a.0 <= config.gap_m)
        .flat_map(|run| split_unbridged(cloud, cyl, run, config.gap_m));
    for run in runs {
        if run.len() < config.cylinder.min_inliers {
            continue;
        }
        let mut idx: Vec<usize> = run.iter().map(|r| r.1).collect();
        idx.sort_unstable();
        let piece = match refit_straight(cloud, &idx, cyl, config) {
            Some((fit, coverage, raw)) => {
                let c = fit.cylinder;
                let (lo, hi) = fit
                    .inlier_indices
                    .iter()
                    .map(|&k| along(k, &c))
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| {
                        (lo.min(t), hi.max(t))
                    });
                let normal_arc = normal_arc(cloud, &c, &fit.inlier_indices);
                let normal_deviation = normal_deviation(cloud, &c, &fit.inlier_indices);
                let normal_turn = normal_turn(cloud, &c, &fit.inlier_indices).unwrap_or(0.0);
                let departure = shape_departure(cloud, &c, &fit.inlier_indices);
                Piece {
                    cylinder: c,
                    radius_std: fit.radius_std,
                    rmse: fit.rmse,
                    coverage,
                    normal_arc,
                    normal_deviation,
                    normal_turn,
                    departure,
                    start: c.point + c.direction * lo,
                    end: c.point + c.direction * hi,
                    raw: raw.map(|q| c.point + c.direction * (q - c.point).dot(&c.direction)),
                    indices: fit.inlier_indices,
                    fitted: true,
                }
            }
            None => Piece {
                cylinder: *cyl,
                radius_std: f64::NAN,
                rmse: f64::NAN,
                coverage: 0.0,
                normal_arc: 0.0,
                normal_deviation: std::f64::consts::FRAC_PI_2,
                normal_turn: 0.0,
                departure: f64::INFINITY,
                start: cyl.point + cyl.direction * run[0].0,
                end: cyl.point + cyl.direction * run[run.len() - 1].0,
                raw: [
                    cyl.point + cyl.direction * run[0].0,
                    cyl.point + cyl.direction * run[run.len() - 1].0,
                ],
                indices: idx,
                fitted: false,
            },
        };
        out.push(piece);
    }
    out
}

/// Largest angle between a point's normal and the radial direction for the point to hold a
/// run together ([`split_unbridged`]).
const BRIDGE_NORMAL_ANGLE_DEG: f64 = 15.0;

/// The run `run` (inliers `(t, k)` in axial order, no gap over `gap`) split where no point
/// with a radial normal (within [`BRIDGE_NORMAL_ANGLE_DEG`]) lies over more than `gap`: the
/// points in such a stretch are dropped. A pipe's surface has radial normals; where a
/// valve's box or a support's face crosses the candidate's surface, its points pass the
/// inlier test (normals within 30°) along lines at the faces' angle and had joined a
/// valve's two flange rims, 0.66 m apart, into one "pipe". A run without such a stretch is
/// returned whole, unchanged.
fn split_unbridged<'a>(
    cloud: &Cloud,
    cyl: &Cylinder,
    run: &'a [(f64, usize)],
    gap: f64,
) -> Vec<&'a [(f64, usize)]> {
    let cos_max = BRIDGE_NORMAL_ANGLE_DEG.to_radians().cos();
    let radial: Vec<usize> = run
        .iter()
        .enumerate()
        .filter(|&(_, &(_, k))| {
            let (n, _) = cloud.local(k);
            n.dot(&cyl.radial(&(cloud.point(k) + cloud.origin))).abs() >= cos_max
        })
        .map(|(i, _)| i)
        .collect();
    let mut out = Vec::new();
    let mut from = 0;
    for w in radial.windows(2) {
        if run[w[1]].0 - run[w[0]].0 > gap {
            out.push(&run[from..=w[0]]);
            from = w[1];
        }
    }
    out.push(&run[from..]);
    out
}

/// Whether the piece `p` lies on the axis of the accepted piece `k`: within the angle, and
/// both of `p`'s ends within the offset of `k`'s axis line (`k` is the longer, better
/// determined; a short piece's own axis may tilt by a few degrees).
fn coaxial(k: &Piece, p: &Piece, config: &NetworkConfig) -> bool {
    let cos = k.cylinder.direction.dot(&p.cylinder.direction).abs();
    if cos < config.coaxial_angle.cos() {
        return false;
    }
    let offset = config.coaxial_offset * k.cylinder.radius.min(p.cylinder.radius);
    [p.start, p.end, (p.start + p.end) * 0.5]
        .iter()
        .all(|q| k.cylinder.offset(q).norm() <= offset)
}

/// The gap between two pieces' spans along `a`'s axis (negative when they overlap).
fn gap_between(a: &Piece, b: &Piece) -> f64 {
    let d = a.cylinder.direction;
    let t = |p: &Vector3<f64>| p.dot(&d);
    let (a0, a1) = (t(&a.start).min(t(&a.end)), t(&a.start).max(t(&a.end)));
    let (b0, b1) = (t(&b.start).min(t(&b.end)), t(&b.start).max(t(&b.end)));
    (b0 - a1).max(a0 - b1)
}

/// Step 5: merges, refusals and the accepted segments.
fn accept(
    cloud: &Cloud,
    pieces: Vec<Piece>,
    config: &NetworkConfig,
) -> (Vec<PipeSegment>, Vec<RefusedCandidate>) {
    let mut kept: Vec<Piece> = Vec::new();
    let mut refused = Vec::new();
    let refuse = |p: &Piece, refusal: Refusal| RefusedCandidate {
        start: p.start.into(),
        end: p.end.into(),
        radius_m: p.cylinder.radius,
        inliers: p.indices.len(),
        normal_deviation_deg: p.normal_deviation.to_degrees(),
        normal_turn: p.normal_turn,
        shape_departure_m: if p.departure.is_finite() {
            p.departure
        } else {
            -1.0
        },
        refusal,
    };
    'pieces: for p in pieces {
        if !p.fitted {
            refused.push(refuse(&p, Refusal::NoFit));
            continue;
        }
        let r = p.cylinder.radius;
        if r < config.cylinder.radius_min || r > config.cylinder.radius_max {
            refused.push(refuse(
                &p,
                Refusal::RadiusOutOfRange {
                    min_m: config.cylinder.radius_min,
                    max_m: config.cylinder.radius_max,
                },
            ));
            continue;
        }
        for (i, k) in kept.iter_mut().enumerate() {
            if !coaxial(k, &p, config) || gap_between(k, &p) > config.gap_m {
                continue;
            }
            let tolerance = (3.0 * k.radius_std.hypot(p.radius_std)).max(2e-3);
            if (k.cylinder.radius - p.cylinder.radius).abs() > tolerance {
                refused.push(refuse(
                    &p,
                    Refusal::SecondRadius {
                        segment: i,
                        segment_radius_m: k.cylinder.radius,
                    },
                ));
                continue 'pieces;
            }
            // The same pipe found twice: one segment of both inlier sets.
            let mut idx = k.indices.clone();
            idx.extend_from_slice(&p.indices);
            idx.sort_unstable();
            idx.dedup();
            if let Some(m) = pieces_of(cloud, &k.cylinder, &idx, config)
                .into_iter()
                .filter(|m| m.fitted)
                .max_by_key(|m| m.indices.len())
            {
                *k = m;
            }
            continue 'pieces;
        }
        let coverage_deg = p.coverage.to_degrees();
        if p.coverage < config.min_coverage_rad {
            refused.push(refuse(&p, Refusal::NarrowArc { coverage_deg }));
            continue;
        }
        if p.normal_turn < config.min_normal_turn
            || p.normal_deviation > config.max_normal_deviation
            || p.departure > config.max_shape_departure_m
        {
            refused.push(refuse(
                &p,
                Refusal::Facets {
                    coverage_deg,
                    normal_arc_deg: p.normal_arc.to_degrees(),
                    normal_turn: p.normal_turn,
                    normal_deviation_deg: p.normal_deviation.to_degrees(),
                    shape_departure_mm: p.departure * 1e3,
                },
            ));
            continue;
        }
        let length = (p.end - p.start).norm();
        let min_length = config
            .min_length_m
            .max(config.min_length_diameters * 2.0 * p.cylinder.radius);
        if length < min_length {
            refused.push(refuse(
                &p,
                Refusal::TooShort {
                    length_m: length,
                    min_length_m: min_length,
                },
            ));
            continue;
        }
        kept.push(p);
    }
    let segments = kept
        .into_iter()
        .enumerate()
        .map(|(id, p)| {
            let (start, end) = (
                end_of(cloud, &p, p.start, p.end, p.raw[0]),
                end_of(cloud, &p, p.end, p.start, p.raw[1]),
            );
            (id, p, start, end)
        })
        .map(|(id, p, start, end)| PipeSegment {
            id,
            start: start.into(),
            end: end.into(),
            length_m: (end - start).norm(),
            radius_m: p.cylinder.radius,
            radius_std_m: p.radius_std,
            rmse_m: p.rmse,
            inliers: p.indices.len(),
            searched_inliers: p.indices.len(),
            coverage_deg: p.coverage.to_degrees(),
            normal_deviation_deg: p.normal_deviation.to_degrees(),
            normal_turn: p.normal_turn,
            shape_departure_m: p.departure,
            nominal: nominal_size(2e3 * p.cylinder.radius, config.material),
            inlier_indices: p.indices,
        })
        .collect();
    (segments, refused)
}

/// Step 1: the planes at least [`NetworkConfig::plane_min_width_m`] wide, largest first, by
/// consensus on the points' normals over a subsample; returns them and the curve positions
/// left.
fn remove_planes(
    cloud: &Cloud,
    mut remaining: Vec<usize>,
    config: &NetworkConfig,
) -> (Vec<RemovedPlane>, Vec<usize>) {
    let mut rng = ChaCha8Rng::seed_from_u64(config.cylinder.seed ^ 0x91A7E);
    let cos_max = config.plane_normal_angle.cos();
    let floor = (3.0 * cloud.surface_noise).max(1e-6);
    let cap = 3.0 * cloud.noise_cap.max(cloud.surface_noise);
    let on_plane = |pos: usize, n: &Vector3<f64>, d: f64| {
        let (normal, noise) = cloud.local_at(pos);
        let t = (3.0 * noise).min(cap).max(floor);
        (n.dot(&cloud.point_at(pos)) - d).abs() <= t && normal.dot(n).abs() >= cos_max
    };
    let mut planes = Vec::new();
    // The points planes are drawn from: `remaining` less the support of planes refused (a
    // narrow strip along a pipe), so that a refused plane is not drawn again.
    let mut pool = remaining.clone();
    for _ in 0..2 * config.max_planes {
        if planes.len() >= config.max_planes || pool.len() < config.plane_min_points {
            break;
        }
        let sample: Vec<usize> = (0..20_000)
            .map(|_| pool[rng.random_range(0..pool.len())])
            .collect();
        let seeds: Vec<usize> = (0..400)
            .map(|_| sample[rng.random_range(0..sample.len())])
            .collect();
        let best = seeds
            .par_iter()
            .enumerate()
            .map(|(i, &s)| {
                let n = cloud.local_at(s).0;
                let d = n.dot(&cloud.point_at(s));
                let count = sample.iter().filter(|&&q| on_plane(q, &n, d)).count();
                (count, std::cmp::Reverse(i), n, d)
            })
            .max_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)));
        let Some((_, _, mut n, mut d)) = best else {
            break;
        };
        // Least squares on the inliers, twice.
        let mut inliers: Vec<usize> = Vec::new();
        let mut mean = Vector3::zeros();
        for _ in 0..2 {
            inliers = remaining
                .par_iter()
                .copied()
                .filter(|&q| on_plane(q, &n, d))
                .collect();
            let Some((normal, centre, _)) = plane_of(inliers.iter().map(|&q| cloud.point_at(q)))
            else {
                break;
            };
            n = normal;
            mean = centre;
            d = n.dot(&mean);
        }
        let mut drop = vec![false; cloud.len()];
        for &q in &inliers {
            drop[q] = true;
        }
        if inliers.len() < config.plane_min_points
            || in_plane_width(cloud, &inliers, &n) < config.plane_min_width_m
        {
            // Not a plane to remove; neither drawn again. Its seed's own support is dropped
            // too, in case the refit moved the plane off it.
            let before = pool.len();
            pool.retain(|&q| !drop[q]);
            if pool.len() == before {
                break;
            }
            continue;
        }
        // The plane's edges leave the pool with it (see below): a corner's points, whose
        // normals turned half-way, would otherwise lend a later plane through a pipe's strip
        // their metres of extent along the corner.
        let near = |q: usize| drop[q] || (n.dot(&cloud.point_at(q)) - d).abs() <= floor.max(cap);
        remaining.retain(|&q| !near(q));
        pool.retain(|&q| !near(q));
        planes.push(RemovedPlane {
            normal: n.into(),
            point: (mean + cloud.origin).into(),
            points: inliers.len(),
        });
    }
    // The planes' edges and corners: points on a removed plane whose normals turned with the
    // corner (their neighbourhoods straddle two walls) would join everything that touches
    // the walls into one component.
    let near_plane = |q: usize| {
        let p = cloud.point_at(q);
        planes.iter().any(|pl| {
            let n = Vector3::from(pl.normal);
            (n.dot(&(p - (Vector3::from(pl.point) - cloud.origin)))).abs() <= floor.max(cap)
        })
    };
    remaining.retain(|&q| !near_plane(q));
    (planes, remaining)
}

/// Side of the in-plane grid cells whose occupancy measures a plane's filled area (m).
const PLANE_CELL_M: f64 = 0.05;

/// How wide the points of a plane of normal `n` are (m), the smaller of two measures:
/// - the standard deviation across their main direction in the plane: a wall's is metres, a
///   strip along one pipe's is centimetres;
/// - their filled area (cells of [`PLANE_CELL_M`] holding a point) over their length (√12 ×
///   the standard deviation along the main direction): a wall's is metres, while the side
///   strips of a riser and of the run its elbow turns into lie in one plane, an L of strips
///   metres across but centimetres wide.
fn in_plane_width(cloud: &Cloud, idx: &[usize], n: &Vector3<f64>) -> f64 {
    let Some((_, mean, _)) = plane_of(idx.iter().map(|&q| cloud.point_at(q))) else {
        return 0.0;
    };
    let mut c = nalgebra::Matrix3::zeros();
    for &q in idx {
        let v = cloud.point_at(q) - mean;
        let v = v - n * n.dot(&v);
        c += v * v.transpose();
    }
    c /= idx.len() as f64;
    let eig = nalgebra::SymmetricEigen::new(c);
    let mut order: Vec<usize> = (0..3).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    // The two in-plane variances are the two largest; the smaller of them is the width.
    let spread = eig.eigenvalues[order[1]].max(0.0).sqrt();
    let (major, minor) = (
        eig.eigenvectors.column(order[2]).into_owned(),
        eig.eigenvectors.column(order[1]).into_owned(),
    );
    let cells: std::collections::HashSet<(i64, i64)> = idx
        .iter()
        .map(|&q| {
            let v = cloud.point_at(q) - mean;
            (
                (v.dot(&major) / PLANE_CELL_M).floor() as i64,
                (v.dot(&minor) / PLANE_CELL_M).floor() as i64,
            )
        })
        .collect();
    let length = (12.0 * eig.eigenvalues[order[2]].max(0.0)).sqrt();
    let filled = cells.len() as f64 * PLANE_CELL_M * PLANE_CELL_M / length.max(PLANE_CELL_M);
    spread.min(filled)
}

/// Step 2: the connected components of the positions `remaining` on a grid of
/// [`NetworkConfig::cell_m`] (26-neighbourhood), those with at least the cylinder search's
/// fewest inliers, largest first.
fn components(cloud: &Cloud, remaining: &[usize], config: &NetworkConfig) -> Vec<Vec<usize>> {
    use std::collections::HashMap;
    let cell = |p: Vector3<f64>| {
        (
            (p.x / config.cell_m).floor() as i64,
            (p.y / config.cell_m).floor() as i64,
            (p.z / config.cell_m).floor() as i64,
        )
    };
    let mut cells: HashMap<(i64, i64, i64), usize> = HashMap::new();
    let mut members: Vec<Vec<usize>> = Vec::new();
    for &pos in remaining {
        let c = cell(cloud.point_at(pos));
        let id = *cells.entry(c).or_insert_with(|| {
            members.push(Vec::new());
            members.len() - 1
        });
        members[id].push(pos);
    }
    let mut parent: Vec<usize> = (0..members.len()).collect();
    fn find(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    let keys: Vec<((i64, i64, i64), usize)> = cells.iter().map(|(k, v)| (*k, *v)).collect();
    for ((x, y, z), id) in keys {
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(&other) = cells.get(&(x + dx, y + dy, z + dz)) {
                        let (a, b) = (find(&mut parent, id), find(&mut parent, other));
                        if a != b {
                            parent[a.max(b)] = a.min(b);
                        }
                    }
                }
            }
        }
    }
    let mut groups: HashMap<usize, Vec<usize>> = HashMap::new();
    for (id, m) in members.into_iter().enumerate() {
        let root = find(&mut parent, id);
        groups.entry(root).or_default().extend(m);
    }
    let mut out: Vec<Vec<usize>> = groups
        .into_values()
        .filter(|g| g.len() >= config.cylinder.min_inliers)
        .map(|mut g| {
            g.sort_unstable();
            g
        })
        .collect();
    // Largest first, ties by the first position: independent of the hash order.
    out.sort_by(|a, b| b.len().cmp(&a.len()).then(a[0].cmp(&b[0])));
    out
}

/// The clearance between two segments: the smallest distance between their surfaces.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Clearance {
    /// The first segment's id.
    pub a: usize,
    /// The second's.
    pub b: usize,
    /// Surface to surface (m); 0 when they touch or overlap (a tee, an elbow's two legs).
    pub distance_m: f64,
}

/// Every pair's clearance, the classic as-built clash check: each segment a solid cylinder
/// (flat ends at its endpoints), distances from parry3d's GJK distance query.
#[must_use]
pub fn clearances(segments: &[PipeSegment]) -> Vec<Clearance> {
    let shapes: Vec<_> = segments
        .iter()
        .map(|s| {
            crate::geometry::solid::cylinder_between(&s.start.into(), &s.end.into(), s.radius_m)
        })
        .collect();
    let pairs: Vec<(usize, usize)> = (0..segments.len())
        .flat_map(|i| (i + 1..segments.len()).map(move |j| (i, j)))
        .collect();
    pairs
        .par_iter()
        .filter_map(|&(i, j)| {
            let d = parry3d_f64::query::distance(
                &shapes[i].0,
                &shapes[i].1,
                &shapes[j].0,
                &shapes[j].1,
            )
            .ok()?;
            Some(Clearance {
                a: segments[i].id,
                b: segments[j].id,
                distance_m: d.distance,
            })
        })
        .collect()
}

/// The arc the normals of the points `idx` fill about `c`'s axis (each normal turned outward).
fn normal_arc(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> f64 {
    let (e1, e2) = c.cross_section_basis();
    filled_arc(idx.iter().map(|&k| {
        let (n, _) = cloud.local(k);
        let radial = c.offset(&(cloud.point(k) + cloud.origin));
        let n = if n.dot(&radial) < 0.0 { -n } else { n };
        n.dot(&e2).atan2(n.dot(&e1))
    }))
}

/// How the normals turn with the points about `c`'s axis: per 10° bin of the points'
/// azimuths (with at least 5 points), the azimuth of their mean outward normal; the median
/// over neighbouring bins of the normal's turn per turn of the points. 1 on a cylinder (the
/// normal is the radial direction), near 0 on a box's faces (one normal per face), whatever
/// the noise. `None` with fewer than three filled bins.
fn normal_turn(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> Option<f64> {
    const BINS: usize = 36;
    let (e1, e2) = c.cross_section_basis();
    let mut sums = [(0usize, 0.0f64, 0.0f64); BINS];
    for &k in idx {
        let (n, _) = cloud.local(k);
        let radial = c.offset(&(cloud.point(k) + cloud.origin));
        let n = if n.dot(&radial) < 0.0 { -n } else { n };
        let a = radial.dot(&e2).atan2(radial.dot(&e1));
        let b =
            (((a / std::f64::consts::TAU).rem_euclid(1.0) * BINS as f64) as usize).min(BINS - 1);
        let nn = (n.dot(&e1), n.dot(&e2));
        let norm = nn.0.hypot(nn.1).max(f64::MIN_POSITIVE);
        sums[b].0 += 1;
        sums[b].1 += nn.0 / norm;
        sums[b].2 += nn.1 / norm;
    }
    let angle = |b: usize| (sums[b].0 >= 5).then(|| sums[b].2.atan2(sums[b].1));
    let step = std::f64::consts::TAU / BINS as f64;
    let mut slopes: Vec<f64> = (0..BINS)
        .filter_map(|b| {
            let (x, y) = (angle(b)?, angle((b + 1) % BINS)?);
            let turn = (y - x + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            Some(turn / step)
        })
        .collect();
    if slopes.len() < 2 {
        return None;
    }
    Some(upper_median(&mut slopes))
}

/// The points' systematic departure from the circle (m): per 10° bin of their azimuths about
/// `c`'s axis (with at least 5 points) the mean residual; the RMS of those means less what
/// the noise alone gives them (`σ²/n` per bin, σ the residuals' robust scale). A pipe's is
/// a tenth of a millimetre; two thin conduits side by side, a box's edge or a strip of a
/// larger curve depart by millimetres.
fn shape_departure(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> f64 {
    const BINS: usize = 36;
    let (e1, e2) = c.cross_section_basis();
    let mut sums = [(0usize, 0.0f64); BINS];
    let mut abs = Vec::with_capacity(idx.len());
    for &k in idx {
        let p = cloud.point(k) + cloud.origin;
        let off = c.offset(&p);
        let a = off.dot(&e2).atan2(off.dot(&e1));
        let b =
            (((a / std::f64::consts::TAU).rem_euclid(1.0) * BINS as f64) as usize).min(BINS - 1);
        let e = off.norm() - c.radius;
        sums[b].0 += 1;
        sums[b].1 += e;
        abs.push(e.abs());
    }
    if abs.is_empty() {
        return f64::INFINITY;
    }
    let sigma = 1.4826 * upper_median(&mut abs);
    let (mut m2, mut noise, mut bins) = (0.0, 0.0, 0usize);
    for &(n, sum) in sums.iter().filter(|s| s.0 >= 5) {
        let mean = sum / n as f64;
        m2 += mean * mean;
        noise += sigma * sigma / n as f64;
        bins += 1;
    }
    if bins == 0 {
        return f64::INFINITY;
    }
    ((m2 - noise) / bins as f64).max(0.0).sqrt()
}

/// The median angle between the normals of the points `idx` and `c`'s radial direction (rad).
fn normal_deviation(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> f64 {
    let mut angles: Vec<f64> = idx
        .iter()
        .map(|&k| {
            let (n, _) = cloud.local(k);
            let radial = c.radial(&(cloud.point(k) + cloud.origin));
            n.dot(&radial).abs().min(1.0).acos()
        })
        .collect();
    if angles.is_empty() {
        return std::f64::consts::FRAC_PI_2;
    }
    upper_median(&mut angles)
}

/// [`refit_among`] and then again on the straight part of the inliers only
/// ([`straight_span`]): an elbow's first centimetres beyond its tangent point are within the
/// noise of the straight pipe's surface and would lengthen the segment and pull its axis.
/// Also returns the extreme inliers of the first fit (before the straight part was cut), as
/// points on its axis.
fn refit_straight(
    cloud: &Cloud,
    idx: &[usize],
    cyl: &Cylinder,
    config: &NetworkConfig,
) -> Option<(super::CylinderFit, f64, [Vector3<f64>; 2])> {
    let (fit, coverage) = refit_among(cloud, idx, cyl, &config.cylinder)?;
    let c = fit.cylinder;
    let along = |k: usize| (cloud.point(k) + cloud.origin - c.point).dot(&c.direction);
    let (r0, r1) = fit
        .inlier_indices
        .iter()
        .map(|&k| along(k))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| {
            (a.min(t), b.max(t))
        });
    let raw = [c.point + c.direction * r0, c.point + c.direction * r1];
    let Some((lo, hi)) = straight_span(cloud, &c, &fit.inlier_indices) else {
        return Some((fit, coverage, raw));
    };
    let kept: Vec<usize> = idx
        .iter()
        .copied()
        .filter(|&k| (lo..=hi).contains(&along(k)))
        .collect();
    if kept.len() == fit.inlier_indices.len() || kept.len() < config.cylinder.min_inliers {
        return Some((fit, coverage, raw));
    }
    match refit_among(cloud, &kept, &c, &config.cylinder) {
        Some((f, cov)) => Some((f, cov, raw)),
        None => Some((fit, coverage, raw)),
    }
}

/// The span along `c`'s axis (relative to `c.point`) where the inliers `idx` are straight:
/// slabs of max(1.5 cm, r/5) along the axis, in each the shift of the cross-section's centre
/// by least squares (`e ≈ u·δ`, `u` the radial unit vector); a slab is bent when the shift is
/// significant (χ²₂ > 13.8, p = 0.001) and above 0.5 mm. From each end inward, the span
/// starts at the first straight slab within an elbow's reach. `None` with too few slabs.
fn straight_span(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> Option<(f64, f64)> {
    let (e1, e2) = c.cross_section_basis();
    let w = (0.2 * c.radius).max(0.015);
    let rows: Vec<(f64, f64, f64, f64)> = idx
        .iter()
        .map(|&k| {
            let p = cloud.point(k) + cloud.origin;
            let off = c.offset(&p);
            let rho = off.norm().max(f64::MIN_POSITIVE);
            let t = (p - c.point).dot(&c.direction);
            (t, off.dot(&e1) / rho, off.dot(&e2) / rho, rho - c.radius)
        })
        .collect();
    let (t0, t1) = rows
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), r| {
            (a.min(r.0), b.max(r.0))
        });
    let slabs = ((t1 - t0) / w).ceil().max(1.0) as usize;
    if slabs < 4 {
        return None;
    }
    // Per slab: n, Σuuᵀ (3), Σue (2), Σe².
    let mut acc = vec![[0.0f64; 7]; slabs];
    for &(t, ux, uy, e) in &rows {
        let s = (((t - t0) / w) as usize).min(slabs - 1);
        let a = &mut acc[s];
        a[0] += 1.0;
        a[1] += ux * ux;
        a[2] += ux * uy;
        a[3] += uy * uy;
        a[4] += ux * e;
        a[5] += uy * e;
        a[6] += e * e;
    }
    // A slab with less than half the typical slab's inliers cannot tell: where an elbow
    // begins, the band keeps only the few of its points that still lie near the straight
    // surface (its sides near the neutral plane), and they look straight. The more points a
    // scan has, the more such slabs pass a fixed count.
    let mut counts: Vec<f64> = acc.iter().map(|a| a[0]).filter(|&n| n > 0.0).collect();
    let typical = if counts.is_empty() {
        0.0
    } else {
        upper_median(&mut counts)
    };
    // Some(bent) for a slab with enough points to tell.
    let bent: Vec<Option<bool>> = acc
        .iter()
        .map(|a| {
            if a[0] < 12.0f64.max(0.5 * typical) {
                return None;
            }
            let det = a[1] * a[3] - a[2] * a[2];
            if det <= 1e-9 * a[0] * a[0] {
                return None;
            }
            let dx = (a[3] * a[4] - a[2] * a[5]) / det;
            let dy = (a[1] * a[5] - a[2] * a[4]) / det;
            let rss = (a[6] - dx * a[4] - dy * a[5]).max(0.0);
            let s2 = rss / (a[0] - 2.0);
            let chi2 = (dx * (a[1] * dx + a[2] * dy) + dy * (a[2] * dx + a[3] * dy)) / s2;
            Some(chi2 > 13.8 && dx.hypot(dy) > 0.5e-3)
        })
        .collect();
    // From each end inward, past the bent (and unknown) slabs to the first straight one; a
    // bent tail longer than an elbow's reach (max(15 cm, 3 r)) is not an elbow's: a support
    // or bracket touching the pipe bends one stretch, and the pipe goes on beyond it.
    let reach = ((0.15f64).max(3.0 * c.radius) / w).ceil() as usize;
    let tail = |order: &mut dyn Iterator<Item = usize>| -> Option<usize> {
        let mut skipped = 0;
        for s in order {
            match bent[s] {
                Some(false) => return (skipped <= reach).then_some(s),
                _ => skipped += 1,
            }
        }
        None
    };
    let hi = tail(&mut (0..slabs).rev()).unwrap_or(slabs - 1);
    let lo = tail(&mut (0..slabs)).unwrap_or(0);
    if lo >= hi {
        return None;
    }
    Some((t0 + lo as f64 * w, t0 + (hi + 1) as f64 * w))
}

/// Points of an end's neighbourhood: (axial offset beyond the end, residual from the
/// surface, radial unit vector in the cross-section basis, |normal · axis|).
type EndPoint = (f64, f64, [f64; 2], f64);

/// The end `at` of the piece `p` (the other end `other`), refined on every point of the
/// cloud near it:
/// - **a face**: points just beyond the end, off the pipe's surface (up to 10 cm out) with
///   normals along the axis, at one axial position (within 1 cm): a wall, floor or ceiling
///   the pipe enters, a flange or valve it ends at, whose points around the pipe the plane
///   removal or the shadow of the face took: the end is that face;
/// - **an elbow**: the surface leaves the straight pipe's as a parabola
///   (`δ = s²/2R` for a bend of radius `R`, `s` past the tangent point): the end is the
///   tangent point of the best parabola, when it explains the points significantly better
///   than the straight pipe alone;
/// - otherwise the extreme inlier stays.
fn end_of(
    cloud: &Cloud,
    p: &Piece,
    at: Vector3<f64>,
    other: Vector3<f64>,
    raw: Vector3<f64>,
) -> Vector3<f64> {
    let c = &p.cylinder;
    let length = (at - other).norm();
    if length <= 0.0 {
        return at;
    }
    let d = (at - other) / length;
    let (e1, e2) = c.cross_section_basis();
    let tail = (0.15f64).max(3.0 * c.radius).min(0.4 * length);
    // How far the extreme inlier before the straight-part cut lies beyond the end.
    let cut = (raw - at).dot(&d).clamp(0.0, tail);
    let local_at = at - cloud.origin;
    let axis_point = c.point - cloud.origin;
    let pts: Vec<EndPoint> = (0..cloud.len())
        .into_par_iter()
        .with_min_len(4096)
        .filter_map(|pos| {
            let q = cloud.point_at(pos);
            let t = (q - local_at).dot(&d);
            if !(-tail..=0.1 + cut).contains(&t) {
                return None;
            }
            let w = q - axis_point;
            let off = w - c.direction * w.dot(&c.direction);
            let rho = off.norm();
            if rho > c.radius + 0.1 || rho < 0.5 * c.radius {
                return None;
            }
            let (n, _) = cloud.local_at(pos);
            let u = off / rho.max(f64::MIN_POSITIVE);
            Some((t, rho - c.radius, [u.dot(&e1), u.dot(&e2)], n.dot(&d).abs()))
        })
        .collect();
    if let Some(t) = end_face(&pts, 0.08) {
        return at + d * flange_front(&pts, t).unwrap_or(t);
    }
    // Further (an end the straight-part cut shortened at a wall's mixed pixels): a face the
    // straight surface runs up to without a break.
    if let Some(t) = end_face(&pts, 0.1 + cut).filter(|&t| straight_up_to(&pts, t)) {
        return at + d * t;
    }
    let near: Vec<EndPoint> = pts.iter().copied().filter(|p| p.0 <= 0.1).collect();
    if let Some(t) = elbow_tangent(&near, c.radius, tail) {
        return at + d * t;
    }
    if let Some(t) = rim_start(&near) {
        return at + d * t;
    }
    at
}

/// A flange's rim just beyond the end whose faces no station saw (the flange's shadow hides
/// the pipe's last centimetres and its front face): points 4 mm to 10 cm off the pipe's
/// surface within 3 mm of their median offset, normals radial, around at least 120° of the axis;
/// the flange's front is where the rim begins (the 5th percentile of their axial offsets).
fn rim_start(pts: &[EndPoint]) -> Option<f64> {
    let rim = rim_points(pts, -0.01, 0.08, 15)?;
    if filled_arc(rim.iter().map(|p| p.2[1].atan2(p.2[0]))) < 120f64.to_radians() {
        return None;
    }
    Some(rim_front(&rim))
}

/// The points of a rim between the axial offsets `from` and `to`: 4 mm to 10 cm off the
/// pipe's surface, normals radial, within 3 mm of their median offset (the rim's radius; a
/// valve's body behind a flange lies further in); `None` with fewer than `min_points`.
fn rim_points(pts: &[EndPoint], from: f64, to: f64, min_points: usize) -> Option<Vec<&EndPoint>> {
    let rim: Vec<&EndPoint> = pts
        .iter()
        .filter(|p| p.0 >= from && p.0 <= to && p.1 > 0.004 && p.1 < 0.1 && p.3 <= 0.5)
        .collect();
    if rim.len() < min_points {
        return None;
    }
    let mut e: Vec<f64> = rim.iter().map(|p| p.1).collect();
    let radius = upper_median(&mut e);
    let rim: Vec<&EndPoint> = rim
        .into_iter()
        .filter(|p| (p.1 - radius).abs() <= 0.003)
        .collect();
    (rim.len() >= min_points).then_some(rim)
}

/// Where a rim begins along the axis: the 5th percentile of its points' axial offsets.
fn rim_front(rim: &[&EndPoint]) -> f64 {
    let mut t: Vec<f64> = rim.iter().map(|p| p.0).collect();
    t.sort_by(f64::total_cmp);
    t[((t.len() - 1) as f64 * 0.05).round() as usize]
}

/// The axial offset of a face just beyond the end ([`end_of`]), up to `reach`, if there is
/// one: the nearest
/// centimetre-thick layer of at least 15 face points (off the surface, normals along the
/// axis) whose azimuths fill at least 120° around the axis (a face surrounds the pipe; the
/// side of an elbow's other leg lies at one azimuth).
fn end_face(pts: &[EndPoint], reach: f64) -> Option<f64> {
    let cos30 = 30f64.to_radians().cos();
    let mut face: Vec<&EndPoint> = pts
        .iter()
        .filter(|p| (-0.01..=reach).contains(&p.0) && p.1 > 0.004 && p.3 >= cos30)
        .collect();
    face.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut j = 0;
    for i in 0..face.len() {
        while j < face.len() && face[j].0 <= face[i].0 + 0.01 {
            j += 1;
        }
        let layer = &face[i..j];
        if layer.len() >= 15
            && filled_arc(layer.iter().map(|p| p.2[1].atan2(p.2[0]))) >= 120f64.to_radians()
        {
            return Some(layer[layer.len() / 2].0);
        }
    }
    None
}

/// Whether the pipe's straight surface (points within 5 mm of it, normals radial) fills at
/// least 80 % of the centimetres from the end to `face` (a shadow may take a few; an elbow's
/// surface leaves the straight one within centimetres).
fn straight_up_to(pts: &[EndPoint], face: f64) -> bool {
    let bins = (face / 0.01).ceil().max(0.0) as usize;
    let mut seen = vec![false; bins];
    for p in pts {
        if p.0 >= 0.0 && p.0 < face && p.1.abs() <= 0.005 && p.3 <= 0.5 {
            if let Some(b) = seen.get_mut((p.0 / 0.01) as usize) {
                *b = true;
            }
        }
    }
    seen.iter().filter(|&&b| b).count() * 5 >= seen.len() * 4
}

/// When the face at `face` is the back of a flange (its front faces away from every
/// station): the flange's rim ([`rim_points`]) between the end and the face, standing at
/// least 1 cm proud of the pipe (a flange's outside diameter exceeds its pipe's by 5 cm or
/// more, ASME B16.5); the front is where the rim begins. `None` without a rim (a wall, a
/// floor, a flange's front): the few noisy surface points where a pipe enters a wall, 4–7 mm
/// off at scattered offsets, are no rim.
fn flange_front(pts: &[EndPoint], face: f64) -> Option<f64> {
    let rim = rim_points(pts, -0.01, face - 0.002, 10)?;
    let mut e: Vec<f64> = rim.iter().map(|p| p.1).collect();
    (upper_median(&mut e) >= 0.01).then(|| rim_front(&rim))
}

/// Bend radii tried for an elbow, in units of the pipe's outside radius: short-radius
/// elbows (ASME B16.9: R = 1.0 × the nominal size, 1.7–2 r), long-radius ones (1.5 ×, 2.5–3 r)
/// and 3D–5D bends (6–10 r).
const BEND_RADII: [f64; 13] = [
    1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0,
];

/// The tangent point of an elbow beyond the end ([`end_of`]): the surface points (within
/// 15 mm of the straight surface, normals radial) beyond the tangent point `te` lie on a
/// torus, the elbow's surface — its centre line a circle of radius `R` leaving the axis at
/// `te` toward the bend direction `θ`, its tube the pipe's radius. `te`, `θ` and `R`
/// minimise the truncated squared residuals (`min(e², c²)`, `c = max(3σ, 2 mm)`: points of
/// a support, a flange or the next leg saturate) over a grid refined once; the tangent is
/// kept when it explains the points significantly better than the straight pipe alone
/// (25 σ², σ from the straight part).
///
/// A parabola (`δ = s²/2R`) fits only the first centimetres past the tangent: on the
/// elbow's inside the surface leaves the straight one `R/(R − r)` times faster than the
/// centre line, on its outside `R/(R + r)` times slower, and a free parabola fitted to both
/// put the tangent 1.5–2.6 cm early on photogrammetric clouds.
fn elbow_tangent(pts: &[EndPoint], radius: f64, tail: f64) -> Option<f64> {
    let cos30 = 30f64.to_radians().cos();
    let mut surface: Vec<[f64; 4]> = pts
        .iter()
        .filter(|p| p.1.abs() <= 0.015 && p.3 <= (1.0 - cos30 * cos30).sqrt())
        .map(|p| {
            let rho = radius + p.1;
            [p.0, p.1, p.2[0] * rho, p.2[1] * rho]
        })
        .collect();
    let mut straight: Vec<f64> = surface
        .iter()
        .filter(|p| p[0] < -0.5 * tail)
        .map(|p| p[1] * p[1])
        .collect();
    if straight.len() < 20 || surface.len() < 40 {
        return None;
    }
    let sigma2 = upper_median(&mut straight) / 0.455;
    let c2 = (9.0 * sigma2).max(4e-6);
    surface.sort_by(|a, b| a[0].total_cmp(&b[0]));
    // prefix[k]: the straight pipe's truncated cost of the first k points.
    let mut prefix = Vec::with_capacity(surface.len() + 1);
    prefix.push(0.0);
    for p in &surface {
        prefix.push(prefix[prefix.len() - 1] + (p[1] * p[1]).min(c2));
    }
    let straight_cost = prefix[surface.len()];
    // The smallest cost found so far, as bits (non-negative doubles order as their bits): a
    // cell whose partial sum passes it cannot be the minimum (the terms are non-negative), so
    // its sum stops there. The minimum and its ties are never cut, so the grid's answer is the
    // one the full sums give, on any thread count.
    let best_bits = AtomicU64::new(f64::INFINITY.to_bits());
    let cost = |theta: f64, bend: f64, te: f64| -> f64 {
        let bound = f64::from_bits(best_bits.load(Ordering::Relaxed));
        let (sin, cos) = theta.sin_cos();
        let from = surface.partition_point(|p| p[0] <= te);
        let mut sum = prefix[from];
        for p in &surface[from..] {
            if sum > bound {
                return f64::INFINITY;
            }
            // w = q − C, C = te·axis + R·v; n = axis × v = (−sin θ, cos θ, 0).
            let (wx, wy, wz) = (p[2] - bend * cos, p[3] - bend * sin, p[0] - te);
            let h = -wx * sin + wy * cos;
            let in_plane = (wx * wx + wy * wy + wz * wz - h * h).max(0.0).sqrt();
            // Not `hypot`: libm's overflow-safe form was a fifth of the main command's time
            // on a cluttered million points, and these are metres.
            let a = in_plane - bend;
            let e = (a * a + h * h).sqrt() - radius;
            sum += (e * e).min(c2);
        }
        best_bits.fetch_min(sum.to_bits(), Ordering::Relaxed);
        sum
    };
    let te_min = -tail;
    let te_max = 0.05;
    // Coarse grid (θ 15°, te 4 mm, every bend radius), then around its best (θ 2.5°,
    // te 1 mm, the neighbouring radii). Ties go to the lowest index: the same answer on any
    // thread count.
    let best_of = |grid: Vec<(f64, usize, f64)>| -> Option<(f64, (f64, usize, f64))> {
        grid.into_par_iter()
            .map(|(theta, k, te)| (cost(theta, BEND_RADII[k] * radius, te), (theta, k, te)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
    };
    let te_steps = ((te_max - te_min) / 0.004).floor() as usize;
    let coarse: Vec<(f64, usize, f64)> = (0..24)
        .flat_map(|i| {
            (0..BEND_RADII.len()).flat_map(move |k| {
                (0..=te_steps)
                    .map(move |j| ((i as f64 * 15.0).to_radians(), k, te_min + j as f64 * 0.004))
            })
        })
        .collect();
    let (_, (theta0, k0, te0)) = best_of(coarse)?;
    let fine: Vec<(f64, usize, f64)> = (-4..=4)
        .flat_map(|i| {
            (k0.saturating_sub(1)..(k0 + 2).min(BEND_RADII.len())).flat_map(move |k| {
                (-4..=4).map(move |j| {
                    (
                        theta0 + (i as f64 * 2.5).to_radians(),
                        k,
                        (te0 + j as f64 * 0.001).clamp(te_min, te_max),
                    )
                })
            })
        })
        .collect();
    let (best, (_, _, te)) = best_of(fine)?;
    (straight_cost - best > 25.0 * sigma2).then_some(te)
}

/// Test scenery shared by the network's and the pipe of interest's tests: a 3 × 3 m floor at
/// z = 0 (x −0.5…2.5, y −1.5…1.5, `noise()` in z) and a 0.4 m box (its four sides and top, at
/// x 2.2–2.6, y −0.2…0.2, `noise()` on every coordinate).
#[cfg(test)]
pub(crate) fn floor_and_box(noise: &mut dyn FnMut() -> f64) -> Vec<Vector3<f64>> {
    let mut points = Vec::new();
    for i in 0..300 {
        for j in 0..300 {
            let (x, y) = (-0.5 + 3.0 * i as f64 / 300.0, -1.5 + 3.0 * j as f64 / 300.0);
            points.push(Vector3::new(x, y, noise()));
        }
    }
    for i in 0..80 {
        for j in 0..80 {
            let (u, v) = (0.4 * i as f64 / 80.0, 0.4 * j as f64 / 80.0);
            let (x0, y0) = (2.2, -0.2);
            for p in [
                Vector3::new(x0 + u, y0, v),
                Vector3::new(x0 + u, y0 + 0.4, v),
                Vector3::new(x0, y0 + u, v),
                Vector3::new(x0 + 0.4, y0 + u, v),
                Vector3::new(x0 + u, y0 + v, 0.4),
            ] {
                points.push(p + Vector3::new(noise(), noise(), noise()));
            }
        }
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    fn segment(id: usize, start: [f64; 3], end: [f64; 3], r: f64) -> PipeSegment {
        PipeSegment {
            id,
            start,
            end,
            length_m: (Vector3::from(end) - Vector3::from(start)).norm(),
            radius_m: r,
            radius_std_m: 0.0,
            rmse_m: 0.0,
            inliers: 0,
            searched_inliers: 0,
            coverage_deg: 0.0,
            normal_deviation_deg: 0.0,
            normal_turn: 1.0,
            shape_departure_m: 0.0,
            nominal: nominal_size(2e3 * r, PipeMaterial::Steel),
            inlier_indices: Vec::new(),
        }
    }

    /// Clearances against exact geometry: two parallel runs 0.5 m apart (0.5 − r1 − r2), a
    /// crossing 0.4 m below (0.4 − r1 − r3), a tee touching its run (0).
    #[test]
    fn clearances_are_the_surface_distances() {
        let segments = [
            segment(0, [0.0, 0.0, 2.0], [4.0, 0.0, 2.0], 0.05),
            segment(1, [0.0, 0.5, 2.0], [4.0, 0.5, 2.0], 0.03),
            segment(2, [2.0, -1.0, 1.6], [2.0, 1.0, 1.6], 0.02),
            segment(3, [1.0, 0.0, 1.95], [1.0, 0.0, 1.0], 0.02),
        ];
        let c = clearances(&segments);
        assert_eq!(c.len(), 6);
        let get = |a, b| c.iter().find(|x| x.a == a && x.b == b).unwrap().distance_m;
        // GJK converges to a micrometre.
        assert!((get(0, 1) - 0.42).abs() < 1e-6, "{}", get(0, 1));
        assert!((get(0, 2) - 0.33).abs() < 1e-6, "{}", get(0, 2));
        assert!((get(1, 2) - 0.35).abs() < 1e-6, "{}", get(1, 2));
        assert!(get(0, 3).abs() < 1e-6, "{}", get(0, 3));
    }

    /// A plane's width ([`in_plane_width`]) on exact points 1 cm apart in the plane y = 0: a
    /// 2 × 2 m patch is a wall (its standard deviation across, 2/√12 = 0.577 m, is the smaller
    /// measure); an L of two 5 cm strips, 2.8 m up and 6 m along (a riser's side and its
    /// run's), spreads 1 m and more across but fills 5 cm per metre of length: not a plane.
    #[test]
    fn a_plane_is_filled_an_l_of_strips_is_not() {
        let grid = |x0: f64, x1: f64, z0: f64, z1: f64| {
            let mut pts = Vec::new();
            let (nx, nz) = (((x1 - x0) / 0.01) as usize, ((z1 - z0) / 0.01) as usize);
            for i in 0..nx {
                for k in 0..nz {
                    pts.push(Vector3::new(
                        x0 + (i as f64 + 0.5) * 0.01,
                        0.0,
                        z0 + (k as f64 + 0.5) * 0.01,
                    ));
                }
            }
            pts
        };
        let width = |pts: &[Vector3<f64>]| {
            let cloud = Cloud::new(pts).unwrap();
            let all: Vec<usize> = (0..cloud.len()).collect();
            in_plane_width(&cloud, &all, &Vector3::y())
        };
        let wall = width(&grid(0.0, 2.0, 0.0, 2.0));
        assert!((wall - 2.0 / 12f64.sqrt()).abs() < 1e-3, "{wall}");
        let mut l = grid(0.0, 0.05, 0.0, 2.8);
        l.extend(grid(0.05, 6.05, 2.75, 2.8));
        let strips = width(&l);
        // Filled: (2.8 + 6) m × 5 cm (a strip lying across the cells fills one or two) over
        // the L's length along its main direction (about 6.8 m): 0.06–0.13 m, under the plane
        // test's 0.2 m, where the spread across alone is about 0.9 m.
        assert!((0.06..0.13).contains(&strips), "{strips}");
        assert!(strips < NetworkConfig::default().plane_min_width_m);
    }

    /// Points on a pipe (r 57.15 mm, 0.5 mm noise) from x = 0.2 to 1.7 m at 1 m height, on a
    /// floor and beside a 0.4 m box: one segment, at the pipe's radius and ends; the floor
    /// removed as a plane; nothing of the box reported.
    #[test]
    fn a_pipe_beside_a_box_on_a_floor_is_one_segment() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut noise = || (rng.random::<f64>() - 0.5) * 1e-3 * 12f64.sqrt() * 0.5;
        let mut points = Vec::new();
        let r = 0.05715;
        for i in 0..1500 {
            let x = 0.2 + 1.5 * (i as f64 + 0.5) / 1500.0;
            for k in 0..60 {
                let a = std::f64::consts::TAU * k as f64 / 60.0;
                let rr = r + noise();
                points.push(Vector3::new(x, rr * a.cos(), 1.0 + rr * a.sin()));
            }
        }
        points.extend(floor_and_box(&mut noise));
        let network = extract_network(&points, &NetworkConfig::default()).unwrap();
        assert_eq!(network.segments.len(), 1, "{:#?}", network.refused);
        let s = &network.segments[0];
        assert!((s.radius_m - r).abs() < 0.2e-3, "{}", s.radius_m);
        let (lo, hi) = if s.start[0] < s.end[0] {
            (s.start, s.end)
        } else {
            (s.end, s.start)
        };
        assert!(
            (lo[0] - 0.2).abs() < 0.01 && (hi[0] - 1.7).abs() < 0.01,
            "{lo:?} {hi:?}"
        );
        assert_eq!(s.nominal.nps, Some("4"));
        assert!(network.planes.iter().any(|p| p.normal[2].abs() > 0.99));
    }

    /// End points ([`EndPoint`]) of a pipe (r 30.15 mm, 0.7 mm noise) straight up to its
    /// tangent point at −3 cm, then a long-radius 90° elbow (R 76.2 mm, ASME B16.9 NPS 2)
    /// bending toward 40°: the tangent from the torus within 3 mm; the straight pipe alone
    /// has none.
    #[test]
    fn an_elbow_s_tangent_is_where_its_torus_leaves_the_pipe() {
        let (r, bend, te, theta) = (0.03015, 0.0762, -0.03, 40f64.to_radians());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut noise = || (rng.random::<f64>() - 0.5) * 0.7e-3 * 12f64.sqrt();
        let v = Vector3::new(theta.cos(), theta.sin(), 0.0);
        let b = Vector3::z().cross(&v);
        let end_point = |q: Vector3<f64>, n: Vector3<f64>| -> Option<EndPoint> {
            let rho = q.xy().norm();
            (q.z <= 0.1 && rho >= 0.5 * r && rho <= r + 0.1)
                .then(|| (q.z, rho - r, [q.x / rho, q.y / rho], n.z.abs()))
        };
        let ring = |psi: f64, m: Vector3<f64>| m * psi.cos() + b * psi.sin();
        let mut straight = Vec::new();
        for i in 0..300 {
            let t = -0.15 + (te + 0.15) * (i as f64 + 0.5) / 300.0;
            for k in 0..24 {
                let n = ring(std::f64::consts::TAU * k as f64 / 24.0, v);
                let q = Vector3::new(0.0, 0.0, t) + n * (r + noise());
                straight.extend(end_point(q, n));
            }
        }
        assert_eq!(elbow_tangent(&straight, r, 0.15), None);
        let mut pts = straight;
        for i in 0..200 {
            let phi = std::f64::consts::FRAC_PI_2 * (i as f64 + 0.5) / 200.0;
            let centre = Vector3::new(0.0, 0.0, te)
                + v * bend * (1.0 - phi.cos())
                + Vector3::z() * bend * phi.sin();
            let m = v * phi.cos() - Vector3::z() * phi.sin();
            for k in 0..24 {
                let n = ring(std::f64::consts::TAU * k as f64 / 24.0, m);
                pts.extend(end_point(centre + n * (r + noise()), n));
            }
        }
        let found = elbow_tangent(&pts, r, 0.15).expect("an elbow");
        assert!((found - te).abs() < 3e-3, "{found}");
    }

    /// A valve between two flanges, no pipe: two flange rims (r 141 mm, 6 cm long) 0.6 m
    /// apart and the valve's box between them (0.248 m square), whose faces cross the rims'
    /// cylinder along lines with normals 28° off radial (inside the inlier test's 30°, outside
    /// the 15° that holds a run together). No segment of the rims' radius; with 30° the box
    /// joins the rims into one 0.4 m "NPS 10 pipe".
    #[test]
    fn a_valve_s_box_does_not_join_its_flange_rims() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut noise = || (rng.random::<f64>() - 0.5) * 0.5e-3 * 12f64.sqrt();
        let (r, h) = (0.141, 0.124);
        let mut points = Vec::new();
        for y0 in [0.0, 0.66] {
            for i in 0..30 {
                let y = y0 + 0.06 * (i as f64 + 0.5) / 30.0;
                for k in 0..220 {
                    let a = std::f64::consts::TAU * k as f64 / 220.0;
                    let rr = r + noise();
                    points.push(Vector3::new(rr * a.cos(), y, 2.0 + rr * a.sin()));
                }
            }
        }
        for i in 0..120 {
            let y = 0.06 + 0.6 * (i as f64 + 0.5) / 120.0;
            for j in 0..46 {
                let u = -h + 2.0 * h * (j as f64 + 0.5) / 46.0;
                for (x, z) in [(u, -h), (u, h), (-h, u), (h, u)] {
                    points.push(Vector3::new(x + noise(), y, 2.0 + z + noise()));
                }
            }
        }
        let network = extract_network(&points, &NetworkConfig::default()).unwrap();
        let rims: Vec<_> = network
            .segments
            .iter()
            .filter(|s| (s.radius_m - r).abs() < 0.01)
            .collect();
        assert!(rims.is_empty(), "{rims:#?}");
    }
}
