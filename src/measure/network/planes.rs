//! Step 1 of the network: walls, floor, ceiling and any wide plane, found by consensus on the
//! points' normals and removed before the cylinder search.

use nalgebra::Vector3;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::super::cloud::{Cloud, plane_of};
use super::{NetworkConfig, RemovedPlane};
use crate::robust::{MAD_TO_SIGMA, upper_median};

/// Step 1: the planes at least [`NetworkConfig::plane_min_width_m`] wide, largest first, by
/// consensus on the points' normals over a subsample, each a surface (its points in its band,
/// not beside it: [`flank_ratio`]); returns them and the curve positions left. Only the
/// subsample's normals are computed.
pub(super) fn remove_planes(
    cloud: &Cloud,
    mut remaining: Vec<usize>,
    config: &NetworkConfig,
) -> (Vec<RemovedPlane>, Vec<usize>) {
    let mut rng = ChaCha8Rng::seed_from_u64(config.cylinder.seed ^ 0x91A7E);
    let cos_max = config.plane_normal_angle.cos();
    let floor = (3.0 * cloud.surface_noise).max(1e-6);
    let cap = 3.0 * cloud.noise_cap.max(cloud.surface_noise);
    // The band within which every point leaves with an accepted plane (its edges, a corner).
    let widest = floor.max(cap);
    let mut planes = Vec::new();
    // The points planes are drawn from: `remaining` less the support of planes refused (a
    // narrow strip along a pipe), so that a refused plane is not drawn again.
    let mut pool = remaining.clone();
    // The sample planes are scored on: the first PLANE_SAMPLE points still in the pool of one
    // seeded random order, so that each round scores mostly the same points and their
    // normals are computed once, not a fresh sample's every round.
    let mut order = remaining.clone();
    order.shuffle(&mut rng);
    let mut in_pool = vec![false; cloud.len()];
    let mut refused_in_a_row = 0;
    for _ in 0..2 * config.max_planes {
        if planes.len() >= config.max_planes || pool.len() < config.plane_min_points {
            break;
        }
        in_pool.iter_mut().for_each(|b| *b = false);
        for &q in &pool {
            in_pool[q] = true;
        }
        order.retain(|&q| in_pool[q]);
        let sample: Vec<usize> = order.iter().take(PLANE_SAMPLE).copied().collect();
        let seeds: Vec<usize> = (0..PLANE_SEEDS)
            .map(|_| sample[rng.random_range(0..sample.len())])
            .collect();
        // The sample's points, normals and bands, read once: the seeds' counts are then plain
        // arithmetic (400 × 20,000 tests a plane).
        let mut sorted = sample.clone();
        sorted.par_sort_unstable();
        sorted.dedup();
        cloud.prepare_at(&sorted);
        let geometry: Vec<(Vector3<f64>, Vector3<f64>, f64)> = sample
            .iter()
            .map(|&q| {
                let (normal, noise) = cloud.local_at(q);
                (cloud.point_at(q), normal, (3.0 * noise).min(cap).max(floor))
            })
            .collect();
        let best = seeds
            .par_iter()
            .enumerate()
            .map(|(i, &s)| {
                let n = cloud.local_at(s).0;
                let d = n.dot(&cloud.point_at(s));
                let count = geometry
                    .iter()
                    .filter(|(p, normal, t)| {
                        (n.dot(p) - d).abs() <= *t && normal.dot(&n).abs() >= cos_max
                    })
                    .count();
                (count, std::cmp::Reverse(i), n, d)
            })
            .max_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)));
        let Some((_, _, mut n, mut d)) = best else {
            break;
        };
        // The plane's inliers are the points within the cloud's floor band of it (three times
        // its typical surface noise), by their distance alone (no normal is computed beyond the
        // sample's); the plane their least squares, twice. A band from the seed's support in
        // the sample would widen with the outliers that pass its per-point thresholds, and a
        // slice of a volume of outliers through a pipe became a "plane" of 280,000 points.
        let band = floor;
        let mut inliers: Vec<usize> = Vec::new();
        let mut mean = Vector3::zeros();
        for _ in 0..2 {
            inliers = remaining
                .par_iter()
                .copied()
                .filter(|&q| (n.dot(&cloud.point_at(q)) - d).abs() <= band)
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
            || flank_ratio(cloud, &remaining, &inliers, &n, d) > config.max_flank_ratio
        {
            // Not a plane to remove; neither drawn again. Its seed's own support is dropped
            // too, in case the refit moved the plane off it.
            let before = pool.len();
            pool.retain(|&q| !drop[q]);
            refused_in_a_row += 1;
            if pool.len() == before || refused_in_a_row >= MAX_REFUSED_IN_A_ROW {
                break;
            }
            continue;
        }
        // The plane's edges leave the pool with it (see below): a corner's points, whose
        // normals turned half-way, would otherwise lend a later plane through a pipe's strip
        // their metres of extent along the corner.
        let near = |q: usize| drop[q] || (n.dot(&cloud.point_at(q)) - d).abs() <= widest;
        remaining.retain(|&q| !near(q));
        pool.retain(|&q| !near(q));
        refused_in_a_row = 0;
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

/// Points the planes are scored on ([`remove_planes`]): a wall of 2 % of the points holds
/// 160 of them; their normals are most of the planes' time on a cloud of a million.
const PLANE_SAMPLE: usize = 8_000;
/// Seeds (a point and its normal) scored per plane.
const PLANE_SEEDS: usize = 400;
/// Refused candidates in a row after which no plane is sought any more: each round takes the
/// best-supported candidate left, so once several in a row are strips of pipes or slices of
/// clutter, what is left has no plane worth removing (the laser rooms' walls, floor and
/// ceiling come first; what later rounds still accepted were equipment faces of a few
/// thousand points, which the cylinder search refuses as well).
const MAX_REFUSED_IN_A_ROW: usize = 4;

/// How the points lie across a plane of normal `n` and offset `d` whose inliers are
/// `inliers`: the larger count of the points of `pool` just beside its band on either side
/// (one to three bands off; the band three times the inliers' robust scale), over the
/// inliers. A wall has its points in its band and almost nothing beside it (its noise's tail,
/// whatever stands close to it); a slice through a volume of outliers, or the plane tangent
/// to a pipe along a strip, has as many just beside it as in it (the pipe's surface curves
/// away within the next band).
fn flank_ratio(cloud: &Cloud, pool: &[usize], inliers: &[usize], n: &Vector3<f64>, d: f64) -> f64 {
    let mut abs: Vec<f64> = inliers
        .iter()
        .map(|&q| (n.dot(&cloud.point_at(q)) - d).abs())
        .collect();
    let band = (3.0 * MAD_TO_SIGMA * upper_median(&mut abs)).max(f64::MIN_POSITIVE);
    let (below, above) = pool
        .par_iter()
        .map(|&q| {
            let e = n.dot(&cloud.point_at(q)) - d;
            let beside = e.abs() > band && e.abs() <= 3.0 * band;
            (
                usize::from(beside && e < 0.0),
                usize::from(beside && e > 0.0),
            )
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    below.max(above) as f64 / inliers.len().max(1) as f64
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
pub(super) fn in_plane_width(cloud: &Cloud, idx: &[usize], n: &Vector3<f64>) -> f64 {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
