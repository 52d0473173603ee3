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
//!
//! Frames from a rolling-shutter video ([`consistent_poses_rolling`]): with the device's
//! readout time known (its profile), each frame also gets its motion during the readout (an
//! angular and a linear velocity, [`crate::camera::rolling`]; Hedborg et al. 2012, "Rolling
//! shutter bundle adjustment", with the readout calibrated), adjusted with the poses, so that
//! whatever is triangulated afterwards can use each row's own pose ([`RollingPoses::row_pose`]).

use super::pipeline::{
    CalibrateError, adjust_feature_tracks, adjust_tracks_free_network, feature_problem,
    refresh_pairs,
};
use super::refine::{Algorithm1, RefineConfig, algorithm1, retriangulate};
use super::views::FrameCamera;
use crate::adjust::{AdjustConfig, AdjustSummary, BrownModel, CameraModel as _};
use crate::camera::Intrinsics;
use crate::camera::rolling::{Motion, RowTiming, exp_so3};
use crate::geometry::Rigid3;
use crate::io::colmap::Reconstruction;
use crate::robust::{CHI2_MEDIAN_2DOF, lower_median};

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
    /// Each frame's motion during the readout, when the poses were adjusted with a rolling
    /// shutter ([`consistent_poses_rolling`]).
    pub rolling: Option<RollingPoses>,
}

/// The frames' rolling-shutter motions about their re-adjusted poses.
#[derive(Clone, Debug, PartialEq)]
pub struct RollingPoses {
    /// The row timing (the device's readout time, the frames' height).
    pub timing: RowTiming,
    /// Per frame (order of [`Algorithm1::frames`]), its motion (camera frame, the model's units).
    pub motions: Vec<Motion>,
    /// The adjustment's robust reprojection σ (px) with the motions, `sqrt(median r² / 1.3863)`.
    pub sigma_px: f64,
    /// The same adjustment without them (the global-shutter round before), for the log.
    pub sigma_global_px: f64,
}

impl RollingPoses {
    /// The pose of frame `frame`'s row at pixel height `v` (observed pixels): the frame's pose
    /// `pose` moved by the frame's motion over the row's time from the frame time,
    /// `R(s) = exp(s·[ω]×)·R`, `T(s) = exp(s·[ω]×)·T + s·ν`.
    #[must_use]
    pub fn row_pose(&self, frame: usize, pose: &Rigid3, v: f64) -> Rigid3 {
        let s = self.timing.time_of_row(v, 0.0);
        self.motions
            .get(frame)
            .map_or(*pose, |m| pose_after(pose, m, s))
    }
}

/// `pose` moved by `motion` over `s` seconds ([`crate::camera::rolling::Motion::point_at`]).
#[must_use]
pub fn pose_after(pose: &Rigid3, motion: &Motion, s: f64) -> Rigid3 {
    let r = exp_so3(&(motion.angular * s));
    let rotation = nalgebra::UnitQuaternion::from_matrix(
        &(r * pose.rotation.to_rotation_matrix().into_inner()),
    );
    let translation = r * pose.translation.vector + motion.linear * s;
    Rigid3::from_parts(translation.into(), rotation)
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
        rolling: None,
    })
}

/// [`consistent_poses`] for frames of a rolling-shutter video with the device's row timing
/// known: after the global-shutter rounds, the inlier feature tracks are adjusted once more
/// with a motion per frame (6 unknowns; the intrinsics and the readout time held), and the
/// poses are the frame-time (middle-row) poses of that adjustment. Its frame is the model's
/// (free network aligned to the tracks' points), so the motions are in the model's units.
///
/// # Errors
///
/// As [`consistent_poses`]; also when the rolling-shutter adjustment fails.
pub fn consistent_poses_rolling(
    model: &Reconstruction,
    intrinsics: &Intrinsics,
    timing: RowTiming,
    refine: &RefineConfig,
    adjust: &AdjustConfig,
) -> Result<ConsistentPoses, CalibrateError> {
    let mut poses = consistent_poses(model, intrinsics, refine, adjust)?;
    let a1 = &mut poses.a1;
    let cameras: Vec<FrameCamera> = a1.frames.iter().map(|f| f.camera).collect();
    let global = feature_problem(model, a1, &cameras)?;
    let sigma_global_px = robust_sigma(&global);
    let mut problem = global.with_rolling_shutter(timing.height_px, timing.readout_s);
    problem.fixed.global = (0..problem.global.len()).collect();
    let summary = adjust_tracks_free_network(&mut problem, a1.reprojection_sigma, adjust)?;
    let sigma_px = robust_sigma(&problem);
    for (frame, pose) in a1.frames.iter_mut().zip(&problem.cam_from_world) {
        frame.camera.cam_from_world = *pose;
    }
    let motions = problem.motions();
    retriangulate(model, a1, refine);
    let cameras: Vec<FrameCamera> = a1.frames.iter().map(|f| f.camera).collect();
    refresh_pairs(&mut a1.pairs, &cameras);
    poses.summary = summary;
    poses.rolling = Some(RollingPoses {
        timing,
        motions,
        sigma_px,
        sigma_global_px,
    });
    Ok(poses)
}

/// Robust reprojection σ of a problem's observations, `sqrt(median r² / 1.3863)` (the χ²₂
/// median), as Algorithm 1 reports it.
fn robust_sigma(problem: &crate::adjust::Problem<BrownModel>) -> f64 {
    let mut r2: Vec<f64> = problem
        .observations
        .iter()
        .filter_map(|o| problem.residual(o))
        .map(|r| r.norm_squared())
        .filter(|r| r.is_finite())
        .collect();
    if r2.is_empty() {
        return f64::NAN;
    }
    (lower_median(&mut r2) / CHI2_MEDIAN_2DOF).sqrt()
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
/// ([`crate::geometry::pose::retract`]) at the re-adjusted cameras, all frames jointly (image-id
/// order): the inlier tracks' problem with every intrinsic fixed, its reduced covariance
/// without the (pinned) intrinsics' rows. 6 rows per frame; 12 when the poses were adjusted
/// with rolling-shutter motions (the pose step, then the motion's `(δω, δν)`), so that what is
/// sampled from it moves the rows' poses as the adjustment knows them. `None` when the
/// network's precision cannot be computed.
#[must_use]
pub fn pose_covariance(
    model: &Reconstruction,
    poses: &ConsistentPoses,
) -> Option<nalgebra::DMatrix<f64>> {
    let a1 = &poses.a1;
    let cameras = poses.cameras();
    let mut problem = feature_problem(model, a1, &cameras).ok()?;
    if let Some(r) = &poses.rolling {
        problem = problem.with_rolling_shutter(r.timing.height_px, r.timing.readout_s);
        problem.local = r
            .motions
            .iter()
            .flat_map(|m| m.angular.iter().chain(m.linear.iter()).copied())
            .collect();
    }
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
    let block = 6 + problem.model.local_len();
    (n == block * cameras.len()).then(|| reduced.view((dg, dg), (n, n)).into_owned())
}
