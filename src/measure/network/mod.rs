//! The pipe network of a cluttered cloud: every physical pipe once, split into
//! straight segments with their axis endpoints, and what was refused and why.
//!
//! 1. **Planes out**: walls, floor and ceiling (and any plane at least
//!    [`NetworkConfig::plane_min_width_m`] wide across) are found by consensus on the points'
//!    own normals and removed, so that the cylinder search samples pipes, not walls.
//! 2. **Components**: the rest is cut into connected pieces on a grid of
//!    [`NetworkConfig::cell_m`] cells; each piece is searched on its own, so a small pipe gets
//!    the same sampling as a large one.
//! 3. **Candidates**: in each piece, [`super::cylinder::fit_cylinder_among`] repeatedly
//!    (fit, remove inliers): axes with their inliers; what the search of a piece leaves is
//!    cut into pieces again and searched the same way (module `search`: a short pipe between two
//!    elbows is a few hundred of the hundred thousand points of a tank and the runs it joins).
//! 4. **Segments**: each candidate's inliers along its axis, cut at gaps longer than
//!    [`NetworkConfig::gap_m`] (a valve, an occlusion too long to bridge) and at the shorter
//!    gaps a flange pair stands in (module `rings`); each piece re-fitted alone
//!    (`cylinder::refit_among`), its endpoints the extreme inliers along the axis.
//! 5. **Tests**, best supported first: a piece on the axis of an accepted segment with the same
//!    radius is merged into it unless a flange pair stands between them; with another radius
//!    it is refused (a flange, a nozzle, an insulated stretch) unless it is a pipe of its own
//!    length beyond the segment's end, the next pipe through a reducer; a piece whose inliers
//!    fill less than [`NetworkConfig::min_coverage_rad`] of the circumference is a strip of a
//!    larger curved surface; a piece shorter than [`NetworkConfig::min_length_m`] or than
//!    [`NetworkConfig::min_length_diameters`] diameters is a fitting or a housing (a pump's
//!    volute is a short, wide cylinder).
//! 6. **Ends** (module `ends`): each segment's ends refined on every point near them — a face it
//!    enters, a flange's rim, an elbow's or a reducer's tangent point (module `bends`).
//!
//! The radius of interest ([`CylinderConfig::radius_min`], `radius_max`) bounds what can be a
//! pipe: a wall's gentle bow fits a cylinder of metres.

use nalgebra::Vector3;
use serde::Serialize;

use super::cloud::{Cloud, CloudError};
use super::cylinder::{CylinderConfig, CylinderError};
use super::nominal::{NominalSize, PipeMaterial, nominal_size};

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
    /// Largest share of a candidate's points that may lie just inside or just outside its
    /// band, relative to those in it: a sampled surface's noise leaves a few per cent there
    /// (0.3 % for Gaussian noise, 1–2 % on the laser rooms' pipes, up to 10 % on the simulated
    /// multi-view stereo clouds with 2–5 % outliers); the faces of a column's edge, tangent to
    /// the circle fitted to it, leave 42–45 % (they go on beyond the band), and the flank of
    /// another surface more than the band holds.
    pub max_flank_ratio: f64,
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
            max_flank_ratio: 0.3,
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
    /// Its points are not a surface of its own: too many lie just inside or just outside its
    /// band (the noise or outliers just off another pipe, faces that go on beyond it).
    Flank {
        /// Points in its band.
        band_points: usize,
        /// Points just inside it.
        inside_points: usize,
        /// Points just outside it.
        outside_points: usize,
        /// Half-width of the band (mm).
        band_mm: f64,
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
            Refusal::Flank {
                band_points,
                inside_points,
                outside_points,
                band_mm,
            } => write!(
                f,
                "not a surface of its own: {band_points} points within ±{band_mm:.1} mm of it, {inside_points} just inside and {outside_points} just outside (the noise or outliers beside another surface, or flat faces going on beyond it)"
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
    // Normals are computed where the planes' tests and the ends need them, not for every
    // point: a scan's clutter and outliers far from any plane never need one.
    let (planes, remaining) = remove_planes(&cloud, all, config);
    let components = components(&cloud, &remaining, config);
    let searched = components.len();
    let mut pieces = search_components(&cloud, components, config);
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
        components: searched,
        segments,
        refused,
    })
}

mod bends;
mod clearance;
mod components;
mod ends;
mod planes;
mod rings;
mod search;
mod segments;
mod shape;

pub use clearance::{Clearance, clearances};
use components::components;
use ends::end_of;
use planes::remove_planes;
use search::search_components;
use segments::{Piece, axial_fill, coaxial, gap_between, pieces_of, ring_between};

/// Smallest share of its span a pipe beyond a reducer fills with its surface
/// ([`axial_fill`]).
const MIN_AXIAL_FILL: f64 = 0.6;

/// How far two coaxial pieces of different radii may overlap along the axis and still be two
/// pipes joined by a reducer (m): a concentric reducer's cone, fitted by neither, leaves a gap;
/// the re-fits' ends move by a centimetre or two.
const REDUCER_OVERLAP_M: f64 = 0.03;

/// Step 5: merges, refusals and the accepted segments.
///
/// Kept whole (one function over 150 lines): the merge and refusal rules run in order over one
/// list of candidates with shared indices; each rule's test is its own function
/// ([`gap_between`], [`axial_fill`], the shape tests), the loop that orders them is what
/// remains.
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
        let length = (p.end - p.start).norm();
        let min_length = config
            .min_length_m
            .max(config.min_length_diameters * 2.0 * p.cylinder.radius);
        for (i, k) in kept.iter_mut().enumerate() {
            if !coaxial(k, &p, config) || gap_between(k, &p) > config.gap_m {
                continue;
            }
            // Two pipes bolted together at a flange pair: each a segment of its own.
            if ring_between(k, &p) {
                continue;
            }
            let tolerance = (3.0 * k.radius_std.hypot(p.radius_std)).max(2e-3);
            if (k.cylinder.radius - p.cylinder.radius).abs() > tolerance {
                // A pipe of its own length beside the segment, not along it, whose surface
                // fills its length (not a valve's two flange rims), is the next pipe through a
                // reducer.
                if gap_between(k, &p) >= -REDUCER_OVERLAP_M
                    && length >= min_length
                    && axial_fill(cloud, &p) >= MIN_AXIAL_FILL
                {
                    continue;
                }
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
        let flanks = p.flanks;
        if (flanks.inside.max(flanks.outside) as f64) > config.max_flank_ratio * flanks.band as f64
        {
            refused.push(refuse(
                &p,
                Refusal::Flank {
                    band_points: flanks.band,
                    inside_points: flanks.inside,
                    outside_points: flanks.outside,
                    band_mm: flanks.band_m * 1e3,
                },
            ));
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
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

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
