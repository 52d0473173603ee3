//! Poses consistent with the intrinsics they are used with.
//!
//! An SfM model's poses were adjusted together with the SfM program's own camera (COLMAP's
//! SIMPLE_RADIAL with its focal length and k): they absorb that camera's errors, so with
//! another camera — a device profile, or the intrinsics of a calibration iteration — the
//! model's features no longer reproject (on a real panel 6.7 px instead of COLMAP's 0.23 px).
//! Before anything is triangulated with new intrinsics, Algorithm 1 step 4 is run with those
//! intrinsics held fixed: the inlier feature tracks adjusted with the poses and points (Huber
//! loss, free network aligned to the model's points so that the frame stays the model's), the
//! tracks re-triangulated robustly with the new poses, and adjusted once more on the new
//! inliers. The pairs' `F` then come from the adjusted cameras ([`super::pipeline::
//! refresh_pairs`]): on near-planar scenes the features' robust `F` is ill-conditioned, the
//! poses' is not.

use super::pipeline::{CalibrateError, adjust_feature_tracks, feature_problem, refresh_pairs};
use super::refine::{Algorithm1, RefineConfig, algorithm1, retriangulate};
use super::views::FrameCamera;
use crate::adjust::{AdjustConfig, AdjustSummary};
use crate::camera::Intrinsics;
use crate::io::colmap::Reconstruction;

/// Algorithm 1 on poses re-adjusted to fixed intrinsics.
#[derive(Clone, Debug)]
pub struct ConsistentPoses {
    /// Algorithm 1 with the re-adjusted cameras: its frames carry the new poses, its tracks are
    /// triangulated with them, its pairs' `F` come from them.
    pub a1: Algorithm1,
    /// Algorithm 1's reprojection σ (px) with the model's poses and the new intrinsics.
    pub sigma_before_px: f64,
    /// The same after the re-adjustment (px).
    pub sigma_after_px: f64,
    /// The last adjustment's summary.
    pub summary: AdjustSummary,
}

impl ConsistentPoses {
    /// The frames' cameras (intrinsics and re-adjusted poses), in the model's image-id order.
    #[must_use]
    pub fn cameras(&self) -> Vec<FrameCamera> {
        self.a1.frames.iter().map(|f| f.camera).collect()
    }
}

/// Algorithm 1 steps 1–4 with `intrinsics` held fixed: the model's poses and feature points
/// re-adjusted to them (two rounds of adjustment and robust re-triangulation).
///
/// # Errors
///
/// [`CalibrateError`] when the model's camera cannot be used, it has too few feature tracks
/// with three inlier views, or the adjustment fails.
pub fn consistent_poses(
    model: &Reconstruction,
    intrinsics: &Intrinsics,
    refine: &RefineConfig,
    adjust: &AdjustConfig,
) -> Result<ConsistentPoses, CalibrateError> {
    let mut a1 = algorithm1(model, Some(intrinsics), refine)?;
    let sigma_before_px = a1.reprojection_sigma;
    round(model, &mut a1, refine, adjust)?;
    let summary = round(model, &mut a1, refine, adjust)?;
    let cameras: Vec<FrameCamera> = a1.frames.iter().map(|f| f.camera).collect();
    refresh_pairs(&mut a1.pairs, &cameras);
    Ok(ConsistentPoses {
        sigma_before_px,
        sigma_after_px: a1.reprojection_sigma,
        a1,
        summary,
    })
}

/// One round: the inlier tracks adjusted with the frames' intrinsics fixed, then the tracks
/// re-triangulated with the new poses.
fn round(
    model: &Reconstruction,
    a1: &mut Algorithm1,
    refine: &RefineConfig,
    adjust: &AdjustConfig,
) -> Result<AdjustSummary, CalibrateError> {
    let cameras: Vec<FrameCamera> = a1.frames.iter().map(|f| f.camera).collect();
    let (summary, _, poses) = adjust_feature_tracks(model, a1, &cameras, &[], adjust)?;
    for (frame, pose) in a1.frames.iter_mut().zip(poses) {
        frame.camera.cam_from_world = pose;
    }
    retriangulate(model, a1, refine);
    Ok(summary)
}

/// Covariance (σ0²·Q, minimum trace over the poses) of the frames' pose steps `(δω, δt)`
/// ([`crate::geometry::pose::retract`]) at the re-adjusted cameras, all frames jointly (6 rows
/// per frame, image-id order): the inlier tracks' problem with every intrinsic fixed, its
/// reduced covariance without the (pinned) intrinsics' rows. `None` when the network's
/// precision cannot be computed.
#[must_use]
pub fn pose_covariance(
    model: &Reconstruction,
    poses: &ConsistentPoses,
) -> Option<nalgebra::DMatrix<f64>> {
    let a1 = &poses.a1;
    let cameras = poses.cameras();
    let mut problem = feature_problem(model, a1, &cameras).ok()?;
    problem.fixed.global = (0..problem.global.len()).collect();
    let precision = crate::adjust::precision(
        &problem,
        crate::adjust::PrecisionRequest {
            poses: true,
            points: false,
        },
    )
    .ok()?;
    let reduced = precision.reduced_covariance?;
    let dg = problem.global.len();
    let n = reduced.nrows().checked_sub(dg)?;
    (n == 6 * cameras.len()).then(|| reduced.view((dg, dg), (n, n)).into_owned())
}
