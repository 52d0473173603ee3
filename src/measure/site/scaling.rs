//! The scale (or the similarity) of the site, paper "Summary of Methods" on site: the targets
//! detected in the frames, matched and corrected (Algorithms 2–3) with the profile's camera
//! and the re-adjusted poses (rolling-shutter rows when the profile has a readout time),
//! triangulated, and their distances compared with the TLS targets' ([`super::super::scale`]).

use std::path::{Path, PathBuf};

use nalgebra::{Point3, Vector2};

use super::workspace::{is_model, model_image_size, resolve, site_intrinsics};
use super::{SiteError, SiteInput, SiteRequest};
use crate::adjust::AdjustConfig;
use crate::calibrate::matching::MatchConfig;
use crate::calibrate::poses::{
    ConsistentPoses, RollingPoses, consistent_poses, consistent_poses_rolling,
};
use crate::calibrate::refine::RefineConfig;
use crate::calibrate::views::FrameCamera;
use crate::camera::Intrinsics;
use crate::camera::rolling::RowTiming;
use crate::detect::{DetectConfig, detect_frame_files};
use crate::geometry::triangulation::{Observation, triangulate};
use crate::io::colmap::Reconstruction;
use crate::io::tls::{TlsTarget, read_targets};
use crate::measure::scale::ReconstructedTarget;
use crate::measure::scale::{ScaleConfig, ScaleEstimate, estimate_scale};
use crate::measure::targets::{SiteTargets, match_site_targets};
use crate::profile::load_device;

/// The targets' scale, with what was used.
#[derive(Clone, Debug)]
pub struct SiteScale {
    /// The scale (and similarity) from the targets.
    pub estimate: ScaleEstimate,
    /// The TLS ids used, in the order of the estimate's indices.
    pub tls_ids: Vec<String>,
    /// Their coordinates, same order.
    pub tls_points: Vec<Point3<f64>>,
    /// Per reconstructed target, its views.
    pub views: Vec<usize>,
    /// The device.
    pub device: String,
    /// The model's folder.
    pub sfm: PathBuf,
    /// The TLS target list.
    pub tls_targets: PathBuf,
    /// Whether the frames were already undistorted.
    pub undistorted_frames: bool,
    /// The model.
    pub model: Reconstruction,
    /// The intrinsics the targets were observed with.
    pub intrinsics: Intrinsics,
    /// The poses re-adjusted to them.
    pub poses: ConsistentPoses,
    /// Per reconstructed target (the estimate's indices), its views.
    pub tracks: Vec<Vec<Ray>>,
}

/// One view of a point: the frame (index into the re-adjusted poses' frames), its ideal or
/// undistorted image coordinates, and the row it was seen in (observed pixels; a rolling
/// shutter's row time follows from it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Frame index.
    pub frame: usize,
    /// Image coordinates (ideal for the cloud's rays, undistorted pixels for the targets').
    pub xy: Vector2<f64>,
    /// Row in the frame as recorded (px from the top).
    pub row_px: f64,
}

/// The pose a ray was seen from: the frame's `pose`, moved to the ray's row time when the
/// frames have rolling-shutter motions.
pub(super) fn ray_pose(
    rolling: Option<&RollingPoses>,
    ray: &Ray,
    pose: &crate::geometry::Rigid3,
) -> crate::geometry::Rigid3 {
    rolling.map_or(*pose, |r| r.row_pose(ray.frame, pose, ray.row_px))
}

/// A target triangulated from its views' undistorted centres through `intrinsics` and the
/// frames' `poses` (each view at its row's pose under a rolling shutter).
pub(super) fn triangulate_target(
    views: &[Ray],
    intrinsics: &Intrinsics,
    poses: &dyn Fn(usize) -> crate::geometry::Rigid3,
    rolling: Option<&RollingPoses>,
) -> Option<Point3<f64>> {
    let obs: Vec<Observation> = views
        .iter()
        .map(|ray| Observation {
            p: FrameCamera {
                intrinsics: *intrinsics,
                cam_from_world: ray_pose(rolling, ray, &poses(ray.frame)),
            }
            .p(),
            xy: ray.xy,
        })
        .collect();
    triangulate(&obs)
}

/// The matched targets with their views as rays (row: where the detection's centre was
/// observed; the middle row when unknown), triangulated again with each view's row pose when
/// the frames have rolling-shutter motions (Algorithm 2 matched and triangulated them with
/// the frame-time poses); otherwise Algorithm 2's points.
#[must_use]
pub fn row_targets(
    targets: &SiteTargets,
    cameras: &[FrameCamera],
    intrinsics: &Intrinsics,
    rolling: Option<&RollingPoses>,
    height_px: u32,
) -> (Vec<ReconstructedTarget>, Vec<Vec<Ray>>) {
    let tracks: Vec<Vec<Ray>> = targets
        .matching
        .tracks
        .iter()
        .map(|t| {
            t.views
                .iter()
                .map(|v| Ray {
                    frame: v.frame,
                    xy: v.best_centre(),
                    row_px: targets
                        .observations
                        .get(v.frame)
                        .and_then(|o| o.get(v.obs))
                        .map_or(f64::from(height_px) / 2.0, |o| o.detected.centre().y),
                })
                .collect()
        })
        .collect();
    let mut reconstructed = targets.reconstructed();
    if let Some(rolling) = rolling {
        for (target, views) in reconstructed.iter_mut().zip(&tracks) {
            if let Some(p) = triangulate_target(
                views,
                intrinsics,
                &|f| cameras[f].cam_from_world,
                Some(rolling),
            ) {
                target.point = p;
            }
        }
    }
    (reconstructed, tracks)
}

/// The median angular speed (°/s) of the frames' motions.
pub(super) fn median_angular_speed_deg_s(motions: &[crate::camera::rolling::Motion]) -> f64 {
    let mut speeds: Vec<f64> = motions
        .iter()
        .map(|m| m.angular.norm().to_degrees())
        .collect();
    if speeds.is_empty() {
        return 0.0;
    }
    speeds.sort_by(f64::total_cmp);
    speeds[speeds.len() / 2]
}

/// The TLS targets of the list, only those the request selects when it does; at least two.
fn selected_tls_targets(
    request: &SiteRequest,
    tls_path: &Path,
) -> Result<Vec<TlsTarget>, SiteError> {
    let mut tls = read_targets(tls_path)?;
    if !request.tls_ids.is_empty() {
        for id in &request.tls_ids {
            if !tls.iter().any(|t| &t.id == id) {
                return Err(SiteError::UnknownTlsId {
                    id: id.clone(),
                    path: tls_path.to_path_buf(),
                    known: tls.iter().map(|t| t.id.clone()).collect(),
                });
            }
        }
        tls.retain(|t| request.tls_ids.contains(&t.id));
    }
    if tls.len() < 2 {
        return Err(SiteError::TooFewTlsTargets {
            path: tls_path.to_path_buf(),
            found: tls.len(),
        });
    }
    Ok(tls)
}

/// The log lines of the poses re-adjusted to the profile, with or without the rolling shutter.
fn log_poses(
    request: &SiteRequest,
    poses: &ConsistentPoses,
    undistorted: bool,
    log: &dyn Fn(&str),
) {
    log(&format!(
        "Algorithm 1: reprojection σ {:.2} px with the model's poses and {}, {:.2} px after re-adjusting the poses to it",
        poses.sigma_before_px,
        if undistorted {
            "its pinhole camera"
        } else {
            "the profile's intrinsics"
        },
        poses.sigma_after_px
    ));
    match &poses.rolling {
        Some(r) => log(&format!(
            "rolling shutter: readout {:.1} ms ({}); a motion per frame adjusted with the poses: reprojection σ {:.2} px without, {:.2} px with; median angular speed {:.1} °/s",
            r.timing.readout_s * 1e3,
            if request.readout_time_s.is_some() {
                "given"
            } else {
                "the profile's"
            },
            r.sigma_global_px,
            r.sigma_px,
            median_angular_speed_deg_s(&r.motions)
        )),
        None => log(if request.global_shutter {
            "rolling shutter: left out (--rolling-shutter off)"
        } else {
            "rolling shutter: not modelled (the profile has no readout time; give --readout-time MS for video frames)"
        }),
    }
}

/// Scale from the targets: the profile's intrinsics, the model's poses re-adjusted to them, the
/// targets detected (in parallel; `progress(frames)` once per frame done), matched and corrected, and the scale
/// against the TLS targets.
///
/// # Errors
///
/// [`SiteError`] naming the input and step that failed.
pub fn scale_from_targets(
    request: &SiteRequest,
    log: &dyn Fn(&str),
    progress: &(dyn Fn(usize) + Sync),
) -> Result<SiteScale, SiteError> {
    let cloud = &request.cloud;
    let Some(device) = request.device.as_deref() else {
        return Err(SiteError::NoDevice);
    };
    let sfm = resolve(
        request.sfm.as_ref(),
        cloud,
        &["sparse", "sparse/0"],
        is_model,
        SiteInput::Sfm,
    )?;
    let frames = resolve(
        request.frames.as_ref(),
        cloud,
        &["images", "frames"],
        Path::is_dir,
        SiteInput::Frames,
    )?;
    let tls_path = resolve(
        request.tls_targets.as_ref(),
        cloud,
        &["tls_targets.csv"],
        Path::is_file,
        SiteInput::TlsTargets,
    )?;
    let tls = selected_tls_targets(request, &tls_path)?;
    let model = Reconstruction::read(&sfm)?;
    if model.images.is_empty() {
        return Err(SiteError::NoImages(sfm));
    }
    let (profile_path, profile) = load_device(device)?;
    let (intrinsics, undistorted) =
        site_intrinsics(device, &profile_path, &profile.camera(), &model)?;
    let size = model_image_size(&model)?;
    let readout_s = match (request.global_shutter, request.readout_time_s) {
        (true, _) => None,
        (false, Some(r)) => Some(r),
        (false, None) => profile.rolling_shutter.as_ref().map(|r| r.readout_s),
    }
    .filter(|&r| r > 0.0);
    let poses = match readout_s {
        Some(readout_s) => consistent_poses_rolling(
            &model,
            &intrinsics,
            RowTiming {
                readout_s,
                height_px: f64::from(size.1),
            },
            &RefineConfig::default(),
            &AdjustConfig::default(),
        ),
        None => consistent_poses(
            &model,
            &intrinsics,
            &RefineConfig::default(),
            &AdjustConfig::default(),
        ),
    }
    .map_err(|source| SiteError::Poses {
        path: sfm.clone(),
        source,
    })?;
    log_poses(request, &poses, undistorted, log);
    let names: Vec<String> = poses.a1.frames.iter().map(|f| f.name.clone()).collect();
    let config = DetectConfig {
        min_semi_minor_px: request.min_semi_minor_px,
        ..DetectConfig::default()
    };
    let paths: Vec<PathBuf> = names.iter().map(|n| frames.join(n)).collect();
    let total = paths.len();
    let detected = detect_frame_files(&paths, size, &config, &|| progress(total))?;
    let cameras = poses.cameras();
    let targets = match_site_targets(
        &cameras,
        &poses.a1.pairs,
        &detected,
        size,
        poses.a1.reprojection_sigma,
        &MatchConfig::default(),
    );
    let (reconstructed, tracks) = row_targets(
        &targets,
        &cameras,
        &intrinsics,
        poses.rolling.as_ref(),
        size.1,
    );
    log(&format!(
        "{} frames, {} targets matched (Algorithms 1–3) with {}",
        names.len(),
        reconstructed.len(),
        if undistorted {
            "the model's pinhole camera (frames already undistorted)".to_string()
        } else {
            format!("device {device}'s profile")
        }
    ));
    let points: Vec<Point3<f64>> = tls.iter().map(|t| t.position).collect();
    let estimate =
        estimate_scale(&reconstructed, &points, &ScaleConfig::default()).map_err(|source| {
            SiteError::Scale {
                path: tls_path.clone(),
                source,
            }
        })?;
    Ok(SiteScale {
        tracks,
        views: reconstructed.iter().map(|t| t.views).collect(),
        tls_points: points,
        tls_ids: tls.into_iter().map(|t| t.id).collect(),
        estimate,
        device: device.to_string(),
        sfm,
        tls_targets: tls_path,
        undistorted_frames: undistorted,
        model,
        intrinsics,
        poses,
    })
}
