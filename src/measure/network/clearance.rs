//! Clearances between segments: the classic as-built clash check.

use rayon::prelude::*;
use serde::Serialize;

use super::PipeSegment;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::nominal::{PipeMaterial, nominal_size};
    use nalgebra::Vector3;

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
}
