//! The points of a cloud near a candidate pipe: a thick cylindrical shell about its axis, and
//! the scan that reads them, skipping the runs of the Z-order whose bounding box misses it.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::cloud::{BOX_RUN, Cloud};

/// A thick cylindrical shell about an axis, in the cloud's local frame (points less
/// [`Cloud::origin`]): the points at a distance from the axis within `inner..=outer` and, when
/// `along` is given, at a coordinate along the axis (from `point`) within it. What the scans
/// around a candidate pipe read ([`Cloud::scan_shell`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shell {
    /// A point of the axis (local frame).
    pub point: Vector3<f64>,
    /// The axis's unit direction.
    pub direction: Vector3<f64>,
    /// Least distance from the axis.
    pub inner: f64,
    /// Largest distance from the axis.
    pub outer: f64,
    /// The span along the axis, if limited.
    pub along: Option<(f64, f64)>,
}

impl Shell {
    /// Whether a box (its centre and half diagonal: [`Cloud::run_box`]) may hold a point of
    /// the shell: false only when every point within `half` of `centre` misses it. A margin
    /// of 10⁻⁹ of the centre's distance covers the rounding of that distance.
    #[must_use]
    pub fn may_meet(&self, centre: &Vector3<f64>, half: f64) -> bool {
        let w = centre - self.point;
        let rho = w.cross(&self.direction).norm();
        let slack = half + 1e-9 * (1.0 + rho);
        if rho - slack > self.outer || rho + slack < self.inner {
            return false;
        }
        self.along.is_none_or(|(lo, hi)| {
            let t = w.dot(&self.direction);
            t + slack >= lo && t - slack <= hi
        })
    }
}

impl Cloud {
    /// `read` of every curve position in a run whose box may meet `shell` ([`Shell::may_meet`]),
    /// those it keeps, in curve order; runs in parallel. `read` decides what is in the shell.
    pub fn scan_shell<T: Send>(
        &self,
        shell: &Shell,
        read: impl Fn(usize) -> Option<T> + Sync,
    ) -> Vec<T> {
        let parts: Vec<Vec<T>> = (0..self.len().div_ceil(BOX_RUN))
            .into_par_iter()
            .with_min_len(64)
            .map(|run| {
                let (centre, half) = self.run_box(run);
                if !shell.may_meet(&centre, half) {
                    return Vec::new();
                }
                (run * BOX_RUN..((run + 1) * BOX_RUN).min(self.len()))
                    .filter_map(&read)
                    .collect()
            })
            .collect();
        parts.into_iter().flatten().collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`Cloud::scan_shell`] skips only boxes that hold no point of the shell: on 20,000 points
    /// scattered in a 2 m cube around a tilted axis, it keeps exactly the points a scan of
    /// every point finds (axis distance and span tested exactly), in curve order, for shells
    /// thin and thick, with and without a span.
    #[test]
    fn a_shell_scan_finds_every_point_of_the_shell() {
        let mut state = 7u64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let points: Vec<Vector3<f64>> = (0..20_000)
            .map(|_| Vector3::new(uniform(), uniform(), uniform()) * 2.0 - Vector3::repeat(1.0))
            .collect();
        let cloud = Cloud::new(&points).unwrap();
        let direction = Vector3::new(1.0, 2.0, 0.5).normalize();
        let point = Vector3::new(0.1, -0.2, 0.05) - cloud.origin;
        for (inner, outer, along) in [
            (0.3, 0.31, None),
            (0.0, 0.5, Some((-0.2, 0.4))),
            (0.55, 0.9, Some((0.0, 0.05))),
        ] {
            let shell = Shell {
                point,
                direction,
                inner,
                outer,
                along,
            };
            let inside = |pos: usize| {
                let w = cloud.point_at(pos) - point;
                let t = w.dot(&direction);
                let rho = w.cross(&direction).norm();
                ((inner..=outer).contains(&rho)
                    && along.is_none_or(|(lo, hi)| (lo..=hi).contains(&t)))
                .then_some(pos)
            };
            let every: Vec<usize> = (0..cloud.len()).filter_map(inside).collect();
            assert!(every.len() > 50, "{} points in the shell", every.len());
            assert_eq!(cloud.scan_shell(&shell, inside), every);
        }
    }
}
