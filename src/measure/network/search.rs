//! Step 3 of the network: candidates in each connected component, searched as a cloud of its
//! own, and then in the pieces of what they leave.
//!
//! Each component is searched on its own so that its noise scale and consensus thresholds are
//! its own (a thin pipe far from the scanner is noisier than the walls that set the whole
//! cloud's) and a sample of it is all pipe and fittings. A component can still be mostly
//! something else: a tank with its nozzles, flanges and the runs that leave it joins them all,
//! and a short pipe between two elbows is a few hundred of its hundred thousand points — too
//! few for a consensus over the whole to find. So when the search of a component stops, what
//! it left is cut into components again: with the pipes found removed, the short pipe and its
//! elbows stand apart, and are searched as a cloud of their own.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::super::cloud::Cloud;
use super::super::cylinder::{Cylinder, fit_cylinder_among};
use super::NetworkConfig;
use super::components::components;
use super::segments::{Piece, pieces_of};

/// How many times what a search left is cut into components and searched again: each cut
/// follows the removal of the pipes found before it, and a run of pipes and fittings falls
/// apart within two or three.
const MAX_RESEARCH_DEPTH: usize = 3;

/// Steps 3 and 4 for the components `roots` (curve positions of `cloud`, largest first):
/// the pieces of every candidate, their points named as the cloud's indices.
pub(super) fn search_components(
    cloud: &Cloud,
    roots: Vec<Vec<usize>>,
    config: &NetworkConfig,
) -> Vec<Piece> {
    let mut pieces = Vec::new();
    // Level by level, the components of a level searched in parallel (each on its own, so
    // the result does not depend on the thread count); their leftovers make the next level.
    let mut level = roots;
    for depth in 0..=MAX_RESEARCH_DEPTH {
        let searched: Vec<(Vec<Piece>, Vec<usize>)> = level
            .par_iter()
            .map(|comp| search_one(cloud, comp, config))
            .collect();
        let mut next = Vec::new();
        for (found, left) in searched {
            pieces.extend(found);
            if depth >= MAX_RESEARCH_DEPTH || left.len() < config.cylinder.min_inliers {
                continue;
            }
            // What was left, cut again: only when it falls apart (otherwise the same points
            // would be searched the same way again).
            let parts = components(cloud, &left, config);
            if parts.len() == 1 && parts[0].len() == left.len() {
                continue;
            }
            next.extend(parts);
        }
        level = next;
    }
    pieces
}

/// Searches the component `comp` (curve positions of `cloud`) as a cloud of its own: its
/// candidates' pieces (points named as `cloud`'s indices) and the positions no candidate
/// took, when any was found (else none: nothing was removed, so what is left is `comp`).
fn search_one(cloud: &Cloud, comp: &[usize], config: &NetworkConfig) -> (Vec<Piece>, Vec<usize>) {
    let pts: Vec<Vector3<f64>> = comp
        .iter()
        .map(|&pos| cloud.point_at(pos) + cloud.origin)
        .collect();
    let Ok(sub) = Cloud::new(&pts) else {
        return (Vec::new(), Vec::new());
    };
    let mut left: Vec<usize> = (0..sub.len()).collect();
    let mut candidates: Vec<(Cylinder, Vec<usize>)> = Vec::new();
    for _ in 0..config.max_candidates_per_component {
        if !candidates.is_empty() && !on_surfaces(&sub, &left) {
            break;
        }
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
        .map(|mut p| {
            p.indices = p.indices.iter().map(|&k| cloud.index_at(comp[k])).collect();
            p.indices.sort_unstable();
            p
        })
        .collect();
    let left = if candidates.is_empty() {
        Vec::new()
    } else {
        let mut left: Vec<usize> = left.iter().map(|&k| comp[k]).collect();
        left.sort_unstable();
        left
    };
    (found, left)
}

/// Points of what is left of a component whose local noise is read ([`on_surfaces`]).
const LEFTOVER_SAMPLE: usize = 1024;
/// What is left of a component is no surface when its points' median local noise exceeds
/// this many times the component's: a volume of outliers (16 times the median at 30 % of a
/// cloud), where every further fit finds a chance alignment that the tests then refuse.
const LEFTOVER_NOISE_MULTIPLE: f64 = 5.0;

/// Whether the points `left` of the component `sub` still lie on surfaces (their median
/// local noise within [`LEFTOVER_NOISE_MULTIPLE`] of the component's typical), on an even
/// stride of at most [`LEFTOVER_SAMPLE`] of them.
fn on_surfaces(sub: &Cloud, left: &[usize]) -> bool {
    let step = left.len().div_ceil(LEFTOVER_SAMPLE).max(1);
    let sample: Vec<usize> = left.iter().step_by(step).copied().collect();
    sub.prepare(&sample);
    let mut noise: Vec<f64> = sample.iter().map(|&k| sub.local(k).1).collect();
    let typical = sub.surface_noise / crate::robust::MAD_TO_SIGMA;
    crate::robust::upper_median(&mut noise) <= LEFTOVER_NOISE_MULTIPLE * typical
}
