//! Whether a candidate's points are a round surface: how its normals turn with the points
//! about the axis, how far they lie off the radial direction, and how the points depart from
//! the circle, per azimuth bin.
//!
//! The normals these tests read are not the cloud's per-point ones (16 nearest neighbours):
//! on a dense, noisy cloud — a multi-view stereo cloud of a thin pipe, a millimetre of noise
//! at a millimetre's spacing — a 16-point neighbourhood is three millimetres across and its
//! normal mostly noise (a 2-inch pipe came out 15° off radial, and was refused as flat
//! faces). They come from [`Patches`]: every point of the cloud in the candidate's band
//! within a patch of the candidate's own scale (a third of its radius), so that their noise
//! averages out while a box's face, a column's edge or a thin conduit beside another still
//! shows its own orientation. Where the cloud is sparser than that (a laser scan's far pipe),
//! its own 16-point neighbourhoods are already as wide, and their normals are read.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::super::cloud::{Cloud, NORMAL_NEIGHBOURS, smallest_eigen};
use super::super::cylinder::{Cylinder, filled_arc};
use super::super::shell::Shell;
use super::components::CellMap;
use crate::robust::{MAD_TO_SIGMA, upper_median};

/// A patch's radius as a fraction of the candidate's radius ([`Patches`]): wide enough to
/// average millimetres of noise, narrow enough (19° of arc) that the surface within it is
/// nearly flat.
const PATCH_RADIUS_FRACTION: f64 = 1.0 / 3.0;
/// Fewest points for a patch's normal.
const MIN_PATCH_POINTS: usize = 8;
/// How many times as wide a patch is read where the candidate's own holds too few points
/// ([`Patches::normal`]): 2 holds four times the points, and at a third of the radius each
/// the patch still spans only 38° of the pipe's arc.
const SPARSE_PATCH_SCALE: i64 = 2;
/// Most points whose patch normals a test reads (an even stride through the inliers).
pub(super) const SHAPE_SAMPLE: usize = 4096;

/// A point with its outward normal from its patch (input frame).
#[derive(Clone, Copy, Debug)]
pub(super) struct Oriented {
    /// The point.
    pub(super) point: Vector3<f64>,
    /// Its patch's normal, turned away from the axis.
    pub(super) normal: Vector3<f64>,
}

/// The cloud's points near a candidate's surface, for normals at the candidate's scale and
/// for the radial profile around its surface. Its **band** is the surface's own thickness,
/// three times the inliers' robust residual scale; the patches hold the cloud's points within
/// the band over the inliers' span along the axis and a patch beyond, on a grid of cells one
/// patch wide (a face crossing the band leaves a strip of its own orientation there, not a
/// sliver of the surface behind it); the **flanks** count the points just inside and just
/// outside the band ([`Flanks`]).
pub(super) struct Patches {
    radius: f64,
    /// Whether the cloud is denser than a patch ([`patch_radius`]): otherwise the cloud's
    /// own normals are read.
    dense: bool,
    cells: CellMap<Vec<Vector3<f64>>>,
    /// The radial profile around the surface.
    pub(super) flanks: Flanks,
}

/// How the points lie across a candidate's surface over its inliers' span: in its band
/// (residual within ±band), just inside (−3 band … −band) and just outside (band … 3 band).
/// A surface the sensor sampled has its points in the band and its noise's tail beside it; a
/// candidate that is the flank of another surface — the noise or the outliers just off a
/// denser pipe, fitted as a wider or narrower cylinder — has more points on one side of its
/// band than in it, and flat faces tangent to it (a column's edge) go on beyond its band.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Flanks {
    /// Half-width of the band (m).
    pub(super) band_m: f64,
    /// Points in the band.
    pub(super) band: usize,
    /// Points just inside it.
    pub(super) inside: usize,
    /// Points just outside it.
    pub(super) outside: usize,
}

/// Width of a flank ([`Flanks`]) in bands.
const FLANK_BANDS: f64 = 2.0;
/// The narrowest band (m): a surface's points are never thinner than this, whatever the
/// residuals' robust scale says.
const MIN_BAND_M: f64 = 1e-4;

impl Patches {
    /// The patches of the candidate `c` whose inliers are `inliers` (cloud indices).
    pub(super) fn new(cloud: &Cloud, c: &Cylinder, inliers: &[usize]) -> Self {
        let (radius, dense) = patch_radius(cloud, c, inliers);
        let mut abs: Vec<f64> = inliers
            .par_iter()
            .map(|&k| c.residual(&(cloud.point(k) + cloud.origin)).abs())
            .collect();
        let band = (3.0 * MAD_TO_SIGMA * upper_median(&mut abs)).max(MIN_BAND_M);
        let along = |p: &Vector3<f64>| (p + cloud.origin - c.point).dot(&c.direction);
        // Minimum and maximum are exact in any order: the same span on any number of threads.
        let none = || (f64::INFINITY, f64::NEG_INFINITY);
        let (t0, t1) = inliers
            .par_iter()
            .map(|&k| along(&cloud.point(k)))
            .fold(none, |(a, b), t| (a.min(t), b.max(t)))
            .reduce(none, |x, y| (x.0.min(y.0), x.1.max(y.1)));
        let local = Cylinder {
            point: c.point - cloud.origin,
            ..*c
        };
        let reach = (1.0 + FLANK_BANDS) * band;
        // Per point near the surface: (point, residual, within the inliers' span).
        let near = |q: Vector3<f64>| {
            let t = (q - local.point).dot(&local.direction);
            if t < t0 - radius || t > t1 + radius {
                return None;
            }
            let e = local.residual(&q);
            (e.abs() <= reach).then_some((q, e, (t0..=t1).contains(&t)))
        };
        let shell = Shell {
            point: local.point,
            direction: local.direction,
            inner: local.radius - reach,
            outer: local.radius + reach,
            along: Some((t0 - radius, t1 + radius)),
        };
        let points = cloud.scan_shell(&shell, |pos| near(cloud.point_at(pos)));
        let mut cells: CellMap<Vec<Vector3<f64>>> = CellMap::default();
        let mut flanks = Flanks {
            band_m: band,
            ..Flanks::default()
        };
        for (q, e, within) in points {
            if e.abs() <= band {
                cells.entry(cell_of(&q, radius)).or_default().push(q);
                flanks.band += usize::from(within);
            } else if within && e < 0.0 {
                flanks.inside += 1;
            } else if within {
                flanks.outside += 1;
            }
        }
        Patches {
            radius,
            dense,
            cells,
            flanks,
        }
    }

    /// The normal at the cloud's point `k`: on a dense cloud its patch's ([`Patches::patch`]),
    /// else the cloud's own. Where the patch holds too few points — a long pipe's far end,
    /// which a laser samples several times more sparsely than its near end — a patch
    /// [`SPARSE_PATCH_SCALE`] times as wide.
    pub(super) fn normal(&self, cloud: &Cloud, k: usize) -> Option<Vector3<f64>> {
        if self.dense {
            let q = cloud.point(k);
            self.patch(&q, 1)
                .or_else(|| self.patch(&q, SPARSE_PATCH_SCALE))
        } else {
            Some(cloud.local(k).0)
        }
    }

    /// The unit normal of the plane through the points within `scale` patch radii of the
    /// local point `q`, `None` with fewer than [`MIN_PATCH_POINTS`] or no single plane.
    fn patch(&self, q: &Vector3<f64>, scale: i64) -> Option<Vector3<f64>> {
        let [x, y, z] = cell_of(q, self.radius);
        let reach = self.radius * scale as f64;
        let r2 = reach * reach;
        let (mut n, mut sum) = (0usize, Vector3::zeros());
        let mut c = [0.0f64; 6];
        for dx in -scale..=scale {
            for dy in -scale..=scale {
                for dz in -scale..=scale {
                    let Some(pts) = self.cells.get(&[x + dx, y + dy, z + dz]) else {
                        continue;
                    };
                    for v in pts {
                        let d = v - q;
                        if d.norm_squared() > r2 {
                            continue;
                        }
                        n += 1;
                        sum += d;
                        c[0] += d.x * d.x;
                        c[1] += d.x * d.y;
                        c[2] += d.x * d.z;
                        c[3] += d.y * d.y;
                        c[4] += d.y * d.z;
                        c[5] += d.z * d.z;
                    }
                }
            }
        }
        if n < MIN_PATCH_POINTS {
            return None;
        }
        let m = sum / n as f64;
        let f = 1.0 / n as f64;
        let cov = nalgebra::Matrix3::new(
            c[0] * f - m.x * m.x,
            c[1] * f - m.x * m.y,
            c[2] * f - m.x * m.z,
            c[1] * f - m.x * m.y,
            c[3] * f - m.y * m.y,
            c[4] * f - m.y * m.z,
            c[2] * f - m.x * m.z,
            c[4] * f - m.y * m.z,
            c[5] * f - m.z * m.z,
        );
        smallest_eigen(&cov).map(|(normal, _)| normal)
    }

    /// The points `idx` (cloud indices; at most [`SHAPE_SAMPLE`] of them, an even stride)
    /// with their patch normals turned away from `c`'s axis; points without a patch normal are
    /// left out.
    pub(super) fn oriented(&self, cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> Vec<Oriented> {
        let step = idx.len().div_ceil(SHAPE_SAMPLE).max(1);
        idx.par_iter()
            .step_by(step)
            .filter_map(|&k| {
                let point = cloud.point(k) + cloud.origin;
                let n = self.normal(cloud, k)?;
                let radial = c.offset(&point);
                let normal = if n.dot(&radial) < 0.0 { -n } else { n };
                Some(Oriented { point, normal })
            })
            .collect()
    }
}

/// The grid cell of a local point for cells of side `size`.
fn cell_of(q: &Vector3<f64>, size: f64) -> [i64; 3] {
    [
        (q.x / size).floor() as i64,
        (q.y / size).floor() as i64,
        (q.z / size).floor() as i64,
    ]
}

/// The patch radius of the candidate `c` ([`Patches`]), [`PATCH_RADIUS_FRACTION`] of its
/// radius, and whether the cloud is dense there: whether the cloud's own 16-point
/// neighbourhoods, at its inliers' density (their count over the surface they fill: the arc
/// they cover times the radius times their span along the axis), are narrower than a patch.
/// Where they are not, they already average over as much of the surface as a patch would,
/// and a wider patch on a sparse cloud would reach round the pipe's curve.
fn patch_radius(cloud: &Cloud, c: &Cylinder, inliers: &[usize]) -> (f64, bool) {
    let (e1, e2) = c.cross_section_basis();
    let (mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY);
    let arc = filled_arc(inliers.iter().map(|&k| {
        let p = cloud.point(k) + cloud.origin;
        let t = (p - c.point).dot(&c.direction);
        t0 = t0.min(t);
        t1 = t1.max(t);
        let off = c.offset(&p);
        off.dot(&e2).atan2(off.dot(&e1))
    }));
    let area = arc.max(std::f64::consts::FRAC_PI_2) * c.radius * (t1 - t0).max(c.radius);
    let density = inliers.len() as f64 / area.max(f64::MIN_POSITIVE);
    let neighbourhood = (NORMAL_NEIGHBOURS as f64 / (std::f64::consts::PI * density)).sqrt();
    let radius = PATCH_RADIUS_FRACTION * c.radius;
    (radius, neighbourhood < radius)
}

/// The arc the normals of the points `pts` fill about `c`'s axis.
pub(super) fn normal_arc(c: &Cylinder, pts: &[Oriented]) -> f64 {
    let (e1, e2) = c.cross_section_basis();
    filled_arc(
        pts.iter()
            .map(|o| o.normal.dot(&e2).atan2(o.normal.dot(&e1))),
    )
}

/// How the normals turn with the points about `c`'s axis: per 10° bin of the points'
/// azimuths (with at least 5 points), the azimuth of their mean outward normal; the median
/// over neighbouring bins of the normal's turn per turn of the points. 1 on a cylinder (the
/// normal is the radial direction), near 0 on a box's faces (one normal per face), whatever
/// the noise. `None` with fewer than three filled bins.
pub(super) fn normal_turn(c: &Cylinder, pts: &[Oriented]) -> Option<f64> {
    const BINS: usize = 36;
    let (e1, e2) = c.cross_section_basis();
    let mut sums = [(0usize, 0.0f64, 0.0f64); BINS];
    for o in pts {
        let n = o.normal;
        let radial = c.offset(&o.point);
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
pub(super) fn shape_departure(cloud: &Cloud, c: &Cylinder, idx: &[usize]) -> f64 {
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
    let sigma = MAD_TO_SIGMA * upper_median(&mut abs);
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

/// The median angle between the normals of the points `pts` and `c`'s radial direction (rad).
pub(super) fn normal_deviation(c: &Cylinder, pts: &[Oriented]) -> f64 {
    let mut angles: Vec<f64> = pts
        .iter()
        .map(|o| o.normal.dot(&c.radial(&o.point)).abs().min(1.0).acos())
        .collect();
    if angles.is_empty() {
        return std::f64::consts::FRAC_PI_2;
    }
    upper_median(&mut angles)
}
