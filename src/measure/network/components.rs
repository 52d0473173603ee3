//! Step 2 of the network: the connected pieces of what the planes left, on a grid.

use nalgebra::Vector3;

use super::super::cloud::Cloud;
use super::NetworkConfig;

/// Step 2: the connected components of the positions `remaining` on a grid of
/// [`NetworkConfig::cell_m`] (26-neighbourhood), those with at least the cylinder search's
/// fewest inliers, largest first.
pub(super) fn components(
    cloud: &Cloud,
    remaining: &[usize],
    config: &NetworkConfig,
) -> Vec<Vec<usize>> {
    use rayon::prelude::*;
    // Each point's cell, then the points sorted by cell: a cell is a run of the sorted list.
    let mut keyed: Vec<([i64; 3], usize)> = remaining
        .par_iter()
        .map(|&pos| {
            let p: Vector3<f64> = cloud.point_at(pos) / config.cell_m;
            (
                [p.x.floor() as i64, p.y.floor() as i64, p.z.floor() as i64],
                pos,
            )
        })
        .collect();
    keyed.par_sort_unstable();
    let runs: Vec<&[([i64; 3], usize)]> = keyed.chunk_by(|a, b| a.0 == b.0).collect();
    let index: CellMap<usize> = runs
        .iter()
        .enumerate()
        .map(|(id, run)| (run[0].0, id))
        .collect();
    let mut parent: Vec<usize> = (0..runs.len()).collect();
    fn find(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    for (id, run) in runs.iter().enumerate() {
        let [x, y, z] = run[0].0;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(&other) = index.get(&[x + dx, y + dy, z + dz]) {
                        let (a, b) = (find(&mut parent, id), find(&mut parent, other));
                        if a != b {
                            parent[a.max(b)] = a.min(b);
                        }
                    }
                }
            }
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for (id, run) in runs.iter().enumerate() {
        let root = find(&mut parent, id);
        groups
            .entry(root)
            .or_default()
            .extend(run.iter().map(|&(_, pos)| pos));
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

/// A hash map keyed by grid cells, hashed by the curve's cell hasher: the default SipHash was
/// most of the components' time on a million points, and cell keys need no protection
/// against adversarial collisions.
pub(super) type CellMap<V> = std::collections::HashMap<
    [i64; 3],
    V,
    std::hash::BuildHasherDefault<super::super::zorder::CellHasher>,
>;
