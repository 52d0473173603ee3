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
