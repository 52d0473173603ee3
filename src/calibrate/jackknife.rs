//! The calibration's uncertainty checked against the scatter of the frames themselves: a
//! grouped (delete-a-group) jackknife over the frames (Quenouille 1956, Tukey 1958; for
//! clustered data Efron & Stein 1981, and for camera calibration the cross-validation mrcal
//! recommends, "Interpreting the results": cameras from different subsets of the frames).
//!
//! The adjustment's covariance assumes independent observations. On a hand-held video the
//! errors that remain are correlated within a frame: each frame's motion over the readout time
//! and over `±1/fps` to its neighbours is a fourth-order polynomial, and hand tremor at 4–12 Hz
//! bends the true motion beyond it by a different amount in every frame — one error per frame,
//! shared by all its targets, which the covariance counts as many independent ones. The frames
//! are split into [`JACKKNIFE_GROUPS`] interleaved groups (frame `i` in group `i mod g`, so
//! each subset keeps the whole path), the model is adjusted again without each group in turn
//! (same terms, same weights, from the full solution), and the spread of the `g` cameras
//!
//! ```text
//! C_J = (g − 1)/g · Σ_k (θ_k − θ̄)(θ_k − θ̄)ᵀ
//! ```
//!
//! is the intrinsics' covariance estimated from the frames' own scatter, whatever its source.
//! Its rank is at most `g − 1`, too few for the ten intrinsics' full covariance, so it scales
//! the adjustment's: the projection σ maps of both over the frame give the factor
//! `k² = Σ σ_J²(x) / Σ σ_F²(x)` (the grid's mean variance ratio), and the covariance is
//! multiplied by `max(1, k²)` — never made smaller than the adjustment's own.

use nalgebra::DMatrix;
use rayon::prelude::*;

use crate::adjust::{AdjustConfig, AdjustError, CameraModel, Observation, Problem, bundle_adjust};
use crate::calibrate::checks::projection_uncertainty;
use crate::camera::Intrinsics;

/// Number of frame groups of the jackknife: each replicate leaves a tenth of the frames out.
pub const JACKKNIFE_GROUPS: usize = 10;

/// The jackknife over the frames of an adjusted calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameJackknife {
    /// Number of groups (replicates).
    pub groups: usize,
    /// Each replicate's shared intrinsics (the problem's `global` vector).
    pub replicates: Vec<Vec<f64>>,
    /// `C_J` of the shared intrinsics (module docs).
    pub covariance: DMatrix<f64>,
}

impl FrameJackknife {
    /// Jackknife σ of shared value `k`.
    #[must_use]
    pub fn std(&self, k: usize) -> f64 {
        self.covariance[(k, k)].max(0.0).sqrt()
    }
}

/// The sub-problem of the cameras with `keep[c]`: cameras, their per-camera values and fixed
/// parameters renumbered, points seen by fewer than two kept cameras left out. `None` when
/// nothing is left.
#[must_use]
pub fn keep_frames<M: CameraModel + Clone>(
    problem: &Problem<M>,
    keep: &[bool],
) -> Option<Problem<M>> {
    let n_local = problem.model.local_len();
    let mut camera_of = vec![None; problem.num_cameras()];
    let mut next = 0;
    for (c, slot) in camera_of.iter_mut().enumerate() {
        if keep.get(c).copied().unwrap_or(false) {
            *slot = Some(next);
            next += 1;
        }
    }
    // Points seen by two or more kept cameras.
    let mut seen: Vec<Vec<usize>> = vec![Vec::new(); problem.points.len()];
    for o in &problem.observations {
        if camera_of[o.camera].is_some() && !seen[o.point].contains(&o.camera) {
            seen[o.point].push(o.camera);
        }
    }
    let mut point_of = vec![None; problem.points.len()];
    let mut points = Vec::new();
    for (p, cams) in seen.iter().enumerate() {
        if cams.len() >= 2 {
            point_of[p] = Some(points.len());
            points.push(problem.points[p]);
        }
    }
    let observations: Vec<_> = problem
        .observations
        .iter()
        .filter_map(|o| {
            Some(Observation {
                camera: camera_of[o.camera]?,
                point: point_of[o.point]?,
                ..*o
            })
        })
        .collect();
    if observations.is_empty() {
        return None;
    }
    let kept: Vec<usize> = (0..problem.num_cameras())
        .filter(|&c| camera_of[c].is_some())
        .collect();
    let mut sub = problem.clone();
    sub.cam_from_world = kept.iter().map(|&c| problem.cam_from_world[c]).collect();
    sub.local = kept
        .iter()
        .flat_map(|&c| {
            problem.local[c * n_local..(c + 1) * n_local]
                .iter()
                .copied()
        })
        .collect();
    sub.points = points;
    sub.observations = observations;
    sub.fixed.poses = problem
        .fixed
        .poses
        .iter()
        .filter_map(|&c| camera_of[c])
        .collect();
    sub.fixed.camera_local = problem
        .fixed
        .camera_local
        .iter()
        .filter_map(|&(c, k)| Some((camera_of[c]?, k)))
        .collect();
    Some(sub)
}

/// The grouped jackknife of an adjusted `problem` over its frames ([`JACKKNIFE_GROUPS`]
/// interleaved groups; module docs): each replicate adjusted with `adjust` from the problem's
/// values, with the same fixed parameters.
///
/// # Errors
/// [`AdjustError`] when a replicate cannot be adjusted or leaves nothing to adjust (fewer
/// frames than groups), or a replicate's solve is not usable.
pub fn frame_jackknife<M: CameraModel + Clone + Send + Sync>(
    problem: &Problem<M>,
    adjust: &AdjustConfig,
) -> Result<FrameJackknife, AdjustError> {
    let groups = JACKKNIFE_GROUPS;
    let n = problem.num_cameras();
    if n < 2 * groups {
        return Err(AdjustError::Invalid(format!(
            "{n} frames are too few for a jackknife over {groups} groups of frames"
        )));
    }
    let replicates: Vec<Vec<f64>> = (0..groups)
        .into_par_iter()
        .map(|g| {
            let keep: Vec<bool> = (0..n).map(|c| c % groups != g).collect();
            let mut sub = keep_frames(problem, &keep).ok_or_else(|| {
                AdjustError::Invalid(format!("jackknife group {g} leaves no observation"))
            })?;
            let summary = bundle_adjust(&mut sub, adjust)?;
            if !summary.is_usable() {
                return Err(AdjustError::Invalid(format!(
                    "the adjustment without jackknife group {g} did not converge ({:?})",
                    summary.termination
                )));
            }
            Ok(sub.global)
        })
        .collect::<Result<_, AdjustError>>()?;
    Ok(FrameJackknife {
        groups,
        covariance: jackknife_covariance(&replicates),
        replicates,
    })
}

/// `(g − 1)/g · Σ (θ_k − θ̄)(θ_k − θ̄)ᵀ` of `g` replicates (zero without replicates).
#[must_use]
pub fn jackknife_covariance(replicates: &[Vec<f64>]) -> DMatrix<f64> {
    let g = replicates.len();
    let d = replicates.first().map_or(0, Vec::len);
    let mut cov = DMatrix::zeros(d, d);
    if g < 2 {
        return cov;
    }
    let mean: Vec<f64> = (0..d)
        .map(|i| replicates.iter().map(|r| r[i]).sum::<f64>() / g as f64)
        .collect();
    for r in replicates {
        for i in 0..d {
            for j in 0..d {
                cov[(i, j)] += (r[i] - mean[i]) * (r[j] - mean[j]);
            }
        }
    }
    cov * ((g - 1) as f64 / g as f64)
}

/// The factor `max(1, k²)` (module docs) by which the adjustment's covariance `formal` of the
/// intrinsics (10×10, the order of [`crate::camera::Term::ALL`]) is multiplied so that its
/// projection σ over the frame of `size` reaches, on average over the grid, the jackknife's
/// `jackknife` (10×10).
#[must_use]
pub fn variance_inflation(
    intrinsics: &Intrinsics,
    formal: &DMatrix<f64>,
    jackknife: &DMatrix<f64>,
    size: (u32, u32),
) -> f64 {
    let f = projection_uncertainty(intrinsics, formal, size);
    let j = projection_uncertainty(intrinsics, jackknife, size);
    let (mut num, mut den) = (0.0, 0.0);
    for (a, b) in j.values.iter().flatten().zip(f.values.iter().flatten()) {
        if a.is_finite() && b.is_finite() {
            num += a * a;
            den += b * b;
        }
    }
    if den > 0.0 { (num / den).max(1.0) } else { 1.0 }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Vector2, Vector3};

    use super::*;
    use crate::adjust::{BrownModel, Observation};
    use crate::geometry::Rigid3;

    #[test]
    fn the_jackknife_covariance_is_the_scaled_spread_of_the_replicates() {
        // Two replicates 1 and 3: mean 2, Σ(θ − θ̄)² = 2, times (g − 1)/g = 1/2.
        let c = jackknife_covariance(&[vec![1.0, 10.0], vec![3.0, 6.0]]);
        assert_eq!(c[(0, 0)], 1.0);
        assert_eq!(c[(1, 1)], 4.0);
        assert_eq!(c[(0, 1)], -2.0);
        assert_eq!(jackknife_covariance(&[vec![1.0]])[(0, 0)], 0.0);
    }

    #[test]
    fn keeping_frames_renumbers_cameras_and_points() {
        // Three cameras; point 0 seen by all, point 1 by cameras 0 and 1, point 2 by 1 and 2.
        let mut observations = Vec::new();
        for (c, p) in [(0u8, 0u8), (1, 0), (2, 0), (0, 1), (1, 1), (1, 2), (2, 2)] {
            let uv = Vector2::new(f64::from(c), f64::from(p));
            observations.push(Observation::new(usize::from(c), usize::from(p), uv));
        }
        let poses = (0..3u8)
            .map(|c| Rigid3::translation(f64::from(c), 0.0, 5.0))
            .collect();
        let mut problem = Problem::new(
            BrownModel::rolling_shutter(100.0),
            poses,
            (0..18).map(f64::from).collect(),
            vec![1000.0, 50.0, 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.02],
            (0..3)
                .map(|p| Vector3::new(f64::from(p), 0.0, 0.0))
                .collect(),
            observations,
        )
        .unwrap();
        problem.fixed.camera_local = vec![(0, 4), (2, 5)];
        // Without camera 1: point 1 is seen by camera 0 only, point 2 by camera 2 only.
        let sub = keep_frames(&problem, &[true, false, true]).unwrap();
        assert_eq!(sub.num_cameras(), 2);
        assert_eq!(sub.cam_from_world[1], problem.cam_from_world[2]);
        assert_eq!(sub.local_of(1), problem.local_of(2));
        assert_eq!(sub.points, vec![problem.points[0]]);
        let pairs: Vec<(usize, usize)> = sub
            .observations
            .iter()
            .map(|o| (o.camera, o.point))
            .collect();
        assert_eq!(pairs, vec![(0, 0), (1, 0)]);
        assert_eq!(sub.observations[1].uv, Vector2::new(2.0, 0.0));
        assert_eq!(sub.fixed.camera_local, vec![(0, 4), (1, 5)]);
        assert!(sub.validate().is_ok());
        assert!(keep_frames(&problem, &[true, false, false]).is_none());
    }
}
