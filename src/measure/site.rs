//! The site's chain, paper "Summary of Methods" on site: the workspace found, the device
//! profile's intrinsics, the SfM model's poses re-adjusted to them (Algorithm 1 with the
//! intrinsics fixed, [`crate::calibrate::poses`]), the targets detected, matched and corrected
//! (Algorithms 2–3), the scale (or the similarity) from them against the TLS targets, the dense
//! cloud re-triangulated through the profile and the re-adjusted poses (when COLMAP's
//! `fused.ply.vis` says which images saw each point), the pipe fitted, and the report.
//!
//! Defaults follow COLMAP's workspace (for `WS/dense/0/fused.ply`: the model in
//! `dense/0/sparse`, the frames in `dense/0/images`, `WS/tls_targets.csv`) and the simulator's
//! (`OUT/dense/fused.ply`, `OUT/sparse`, `OUT/frames`, `OUT/tls_targets.csv`): each is searched
//! for in the cloud's folder and up to two folders above it, nearest first.

use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, Point3, Vector2, Vector3, Vector6};
use rayon::prelude::*;
use serde::Serialize;

use super::choice::{ChosenBy, View};
use super::cylinder::{CylinderConfig, CylinderError};
use super::pipe::{
    PipeMeasurement, Reference, Region, Scaling, measure_pipe, reference_fit, segment_reference,
};
use super::scale::ReconstructedTarget;
use super::scale::{ScaleConfig, ScaleError, ScaleEstimate, estimate_scale};
use super::targets::{SiteTargets, match_site_targets};
use crate::adjust::AdjustConfig;
use crate::calibrate::matching::MatchConfig;
use crate::calibrate::pipeline::CalibrateError;
use crate::calibrate::poses::{
    ConsistentPoses, RollingPoses, consistent_poses, consistent_poses_rolling, pose_covariance,
};
use crate::calibrate::refine::RefineConfig;
use crate::calibrate::views::FrameCamera;
use crate::camera::convert::{ColmapModel, brown_from_colmap};
use crate::camera::rolling::RowTiming;
use crate::camera::{BrownCamera, Intrinsics};
use crate::detect::{DetectConfig, DetectFilesError, detect_frame_files};
use crate::geometry::triangulation::{Observation, triangulate};
use crate::io::ReadError;
use crate::io::colmap::{ImageId, Reconstruction};
use crate::io::tls::read_targets;
use crate::profile::{ProfileError, load_device};
use crate::robust::standard_normal as gaussian;

/// Why the site could not be measured.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SiteError {
    /// An input is missing or does not fit the others (the message says which and why).
    #[error("{0}")]
    Input(String),
    /// A file could not be read.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The device profile.
    #[error(transparent)]
    Profile(#[from] ProfileError),
    /// The poses could not be re-adjusted to the profile.
    #[error("Algorithm 1 on {}: {source}", path.display())]
    Poses {
        /// The model.
        path: PathBuf,
        /// Why.
        #[source]
        source: CalibrateError,
    },
    /// Detection in the frames.
    #[error("detecting the targets of the model's frames: {0}")]
    Detect(#[from] DetectFilesError),
    /// The scale.
    #[error("scale from {}: {source}", path.display())]
    Scale {
        /// The TLS target list.
        path: PathBuf,
        /// Why.
        #[source]
        source: ScaleError,
    },
    /// The pipe network.
    #[error("the pipe network of {}: {source}", path.display())]
    Network {
        /// The cloud.
        path: PathBuf,
        /// Why.
        #[source]
        source: super::network::NetworkError,
    },
    /// The pipe fit.
    #[error("fitting the pipe in {}: {source}", path.display())]
    Fit {
        /// The cloud (or scan).
        path: PathBuf,
        /// Why.
        #[source]
        source: CylinderError,
    },
}

/// What the user gave (paths not given are searched for next to the cloud).
#[derive(Clone, Debug, Default)]
pub struct SiteRequest {
    /// The dense cloud (PLY or E57).
    pub cloud: PathBuf,
    /// Device profile (a name in `calibrations/` or a path).
    pub device: Option<String>,
    /// The SfM model.
    pub sfm: Option<PathBuf>,
    /// The frames.
    pub frames: Option<PathBuf>,
    /// The TLS target list.
    pub tls_targets: Option<PathBuf>,
    /// Only these TLS targets.
    pub tls_ids: Vec<String>,
    /// The TLS scan, fitted as the reference.
    pub tls_scan: Option<PathBuf>,
    /// A given scale instead of the targets'.
    pub scale: Option<f64>,
    /// Smallest semi-minor axis of a target to use (px).
    pub min_semi_minor_px: f64,
    /// The region of interest in the measured frame.
    pub region: Option<Region>,
    /// The cylinder search.
    pub cylinder: CylinderConfig,
    /// The rolling shutter's readout time (s), when given: overrides the profile's.
    pub readout_time_s: Option<f64>,
    /// Leave the rolling shutter out even when the profile has a readout time.
    pub global_shutter: bool,
}

/// The first existing `name` in the cloud's folder, its parent and grandparent.
fn search_up(cloud: &Path, names: &[&str], ok: impl Fn(&Path) -> bool) -> Option<PathBuf> {
    let dir = match cloud.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    dir.ancestors()
        .take(3)
        .flat_map(|d| names.iter().map(move |n| d.join(n)))
        .find(|p| ok(p))
}

fn is_model(dir: &Path) -> bool {
    ["cameras.txt", "cameras.bin"]
        .iter()
        .any(|f| dir.join(f).is_file())
}

/// A path given, or searched for, or a clear error naming where we looked.
fn resolve(
    given: Option<&PathBuf>,
    cloud: &Path,
    names: &[&str],
    ok: impl Fn(&Path) -> bool,
    what: &str,
    flag: &str,
) -> Result<PathBuf, SiteError> {
    if let Some(p) = given {
        if !p.exists() {
            return Err(SiteError::Input(format!(
                "{flag} {}: not found",
                p.display()
            )));
        }
        return Ok(p.clone());
    }
    search_up(cloud, names, ok).ok_or_else(|| {
        SiteError::Input(format!(
            "no {what} found next to {} or up to two folders above it (looked for {}); give it with {flag}",
            cloud.display(),
            names.join(", ")
        ))
    })
}

/// The image size of the model's (first) camera.
///
/// # Errors
///
/// [`SiteError::Input`] for a model without a camera.
pub fn model_image_size(model: &Reconstruction) -> Result<(u32, u32), SiteError> {
    let Some(camera) = model.cameras.values().next() else {
        return Err(SiteError::Input("the model has no camera".into()));
    };
    Ok((
        u32::try_from(camera.width).unwrap_or(u32::MAX),
        u32::try_from(camera.height).unwrap_or(u32::MAX),
    ))
}

/// The intrinsics to observe the targets with: the profile's for frames as recorded, the
/// model's pinhole camera for frames already undistorted (checked against the profile); with
/// whether the frames are undistorted.
///
/// # Errors
///
/// [`SiteError::Input`] when the profile is for another aspect ratio, or the model's pinhole
/// camera is not the profile's.
pub fn site_intrinsics(
    device: &str,
    profile_path: &Path,
    profile_cam: &BrownCamera,
    model: &Reconstruction,
) -> Result<(Intrinsics, bool), SiteError> {
    let Some(cam) = model.cameras.values().next() else {
        return Err(SiteError::Input("the model has no camera".into()));
    };
    let (w, h) = model_image_size(model)?;
    if u64::from(profile_cam.width) * u64::from(h) != u64::from(profile_cam.height) * u64::from(w) {
        return Err(SiteError::Input(format!(
            "device {device} ({}) is for {}x{} frames but the model's camera is {w}x{h}: another aspect ratio, so these frames are not from this device",
            profile_path.display(),
            profile_cam.width,
            profile_cam.height
        )));
    }
    let scaled = profile_cam.scaled(w, h);
    let model_cam = brown_from_colmap(cam)
        .map_err(|e| SiteError::Input(format!("the model's camera: {e}")))?
        .camera;
    // COLMAP's undistorter (and `pipemeasure undistort`) write pinhole cameras; a model with a
    // distortion model (even one estimated as zero, or never refined) has the frames as recorded.
    let pinhole = matches!(cam.model, ColmapModel::Pinhole | ColmapModel::SimplePinhole);
    if !pinhole || model_cam.intrinsics.has_distortion() {
        return Ok((scaled.intrinsics, false));
    }
    let rel = (model_cam.intrinsics.c / scaled.intrinsics.c - 1.0).abs();
    if rel > 0.05 {
        return Err(SiteError::Input(format!(
            "the model's pinhole camera has a principal distance of {:.1} px, device {device} {:.1} px at {w}x{h} ({:.0} % apart): these frames were not undistorted with this device's profile",
            model_cam.intrinsics.c,
            scaled.intrinsics.c,
            100.0 * rel
        )));
    }
    Ok((model_cam.intrinsics, true))
}

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
fn ray_pose(
    rolling: Option<&RollingPoses>,
    ray: &Ray,
    pose: &crate::geometry::Rigid3,
) -> crate::geometry::Rigid3 {
    rolling.map_or(*pose, |r| r.row_pose(ray.frame, pose, ray.row_px))
}

/// A target triangulated from its views' undistorted centres through `intrinsics` and the
/// frames' `poses` (each view at its row's pose under a rolling shutter).
fn triangulate_target(
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
fn median_angular_speed_deg_s(motions: &[crate::camera::rolling::Motion]) -> f64 {
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
        return Err(SiteError::Input(
            "--device NAME is needed to scale the cloud from the targets (or give --scale)".into(),
        ));
    };
    let sfm = resolve(
        request.sfm.as_ref(),
        cloud,
        &["sparse", "sparse/0"],
        is_model,
        "SfM model",
        "--sfm",
    )?;
    let frames = resolve(
        request.frames.as_ref(),
        cloud,
        &["images", "frames"],
        Path::is_dir,
        "frames folder",
        "--frames",
    )?;
    let tls_path = resolve(
        request.tls_targets.as_ref(),
        cloud,
        &["tls_targets.csv"],
        Path::is_file,
        "TLS target list",
        "--tls-targets",
    )?;
    let mut tls = read_targets(&tls_path)?;
    if !request.tls_ids.is_empty() {
        for id in &request.tls_ids {
            if !tls.iter().any(|t| &t.id == id) {
                return Err(SiteError::Input(format!(
                    "--tls-ids: target `{id}` is not in {} (its ids: {})",
                    tls_path.display(),
                    tls.iter()
                        .map(|t| t.id.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
        }
        tls.retain(|t| request.tls_ids.contains(&t.id));
    }
    if tls.len() < 2 {
        return Err(SiteError::Input(format!(
            "{}: {} TLS target(s); the scale needs at least two",
            tls_path.display(),
            tls.len()
        )));
    }
    let model = Reconstruction::read(&sfm)?;
    if model.images.is_empty() {
        return Err(SiteError::Input(format!(
            "the model {} has no registered images",
            sfm.display()
        )));
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

/// The dense cloud in the frame of the re-adjusted poses: each point projected through the
/// model's own camera at the model's poses into the images `visibility` names (positions in
/// `image_order`, the model's images file), and triangulated again from those pixels through
/// `cameras` (the profile's intrinsics at the re-adjusted poses). The cloud COLMAP fused with
/// its own camera carries that camera's errors; this is the same cloud as the profile sees it.
/// Points with fewer than two usable views are dropped; returned with how many, and per kept
/// point its views (index into `cameras`, ideal image coordinates under the new intrinsics,
/// the row). With `rolling`, each view is triangulated at its row's pose (the row where the
/// model's camera sees the point).
///
/// # Errors
///
/// [`SiteError::Input`] for an image index or id the model does not have.
pub fn retriangulate_cloud(
    points: &[Vector3<f64>],
    visibility: &[Vec<u32>],
    model: &Reconstruction,
    image_order: &[ImageId],
    cameras: &[(ImageId, FrameCamera)],
    rolling: Option<&RollingPoses>,
) -> Result<RetriangulatedCloud, SiteError> {
    // Per position in the images file: the model's camera and pose, and the new camera.
    let mut views = Vec::with_capacity(image_order.len());
    for id in image_order {
        let image = model.images.get(id).ok_or_else(|| {
            SiteError::Input(format!(
                "the images file names image {} twice or not at all",
                id.0
            ))
        })?;
        let cam = model
            .cameras
            .get(&image.camera_id)
            .ok_or_else(|| SiteError::Input(format!("image {} has no camera", id.0)))?;
        let original = brown_from_colmap(cam)
            .map_err(|e| SiteError::Input(format!("the model's camera: {e}")))?
            .camera
            .intrinsics;
        let new = cameras.iter().position(|(i, _)| i == id);
        views.push((original, image.cam_from_world(), new));
    }
    let n_views = views.len();
    if let Some(bad) = visibility
        .iter()
        .flatten()
        .find(|&&k| k as usize >= n_views)
    {
        return Err(SiteError::Input(format!(
            "fused.ply.vis names image {bad} but the model has {n_views} images"
        )));
    }
    let out: Vec<Option<(Vector3<f64>, Vec<Ray>)>> = points
        .par_iter()
        .zip(visibility)
        .map(|(x, vis)| {
            let rays: Vec<Ray> = vis
                .iter()
                .filter_map(|&k| {
                    let (original, pose, new) = views.get(k as usize)?;
                    let frame = (*new)?;
                    let uv = original.project(&(pose * Point3::from(*x)).coords)?;
                    let xy = cameras[frame].1.intrinsics.ideal_from_pixel(&uv).ok()?;
                    Some(Ray {
                        frame,
                        xy,
                        row_px: uv.y,
                    })
                })
                .collect();
            let p = triangulate_rays(&rays, &|j| cameras[j].1.cam_from_world, rolling)?;
            Some((p, rays))
        })
        .collect();
    let dropped = out.iter().filter(|p| p.is_none()).count();
    let (points, rays) = out.into_iter().flatten().unzip();
    Ok(RetriangulatedCloud {
        points,
        rays,
        dropped,
    })
}

/// The cloud re-triangulated by [`retriangulate_cloud`].
#[derive(Clone, Debug, Default)]
pub struct RetriangulatedCloud {
    /// The points.
    pub points: Vec<Vector3<f64>>,
    /// Per point its views (ideal image coordinates).
    pub rays: Vec<Vec<Ray>>,
    /// Points dropped for fewer than two usable views.
    pub dropped: usize,
}

/// A point triangulated from ideal image coordinates in the frames' cameras `pose(frame)`
/// (each ray at its row's pose with `rolling`); `None` for fewer than two views or a
/// degenerate configuration.
fn triangulate_rays(
    rays: &[Ray],
    pose: &dyn Fn(usize) -> crate::geometry::Rigid3,
    rolling: Option<&RollingPoses>,
) -> Option<Vector3<f64>> {
    if rays.len() < 2 {
        return None;
    }
    let obs: Vec<Observation> = rays
        .iter()
        .map(|ray| Observation::normalized(&ray_pose(rolling, ray, &pose(ray.frame)), ray.xy))
        .collect();
    triangulate(&obs).map(|p| p.coords)
}

/// The site measured: the pipe and, when a scan is given, its reference.
#[derive(Clone, Debug)]
pub struct SiteMeasurement {
    /// The pipe.
    pub pipe: PipeMeasurement,
    /// The scale used.
    pub scaling: Scaling,
    /// The targets' scale, when it came from them.
    pub targets: Option<SiteScale>,
    /// The TLS scan's fit of the same pipe.
    pub reference: Option<Reference>,
    /// How the cloud was used.
    pub cloud_source: CloudSource,
    /// The report.
    pub report: SiteReport,
}

/// Where the fitted points came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CloudSource {
    /// The cloud as given (a metric cloud, a given scale, or no `fused.ply.vis`).
    AsGiven,
    /// Re-triangulated through the profile at the re-adjusted poses.
    Retriangulated,
}

/// A site's cloud with its scale: the points (re-triangulated through the profile at the
/// re-adjusted poses when the cloud's `.vis` is there), still in the cloud's own frame; the
/// scale (given or from the targets) whose [`Scaling::transform`] takes them to metres (and
/// into the TLS frame).
#[derive(Clone, Debug)]
pub struct ScaledCloud {
    /// The scale used.
    pub scaling: Scaling,
    /// The targets' scale, when it came from them.
    pub targets: Option<SiteScale>,
    /// The points (cloud frame).
    pub points: RetriangulatedCloud,
    /// How the cloud was used.
    pub cloud_source: CloudSource,
}

/// The scale of the site's cloud `points` (from `request.scale`, else from the targets) and the
/// points to measure: the first steps of [`measure_site`], shared with the pipe network of a
/// site's cloud.
///
/// # Errors
///
/// [`SiteError`] naming the input and step that failed.
pub fn scaled_cloud(
    request: &SiteRequest,
    points: &[Vector3<f64>],
    log: &dyn Fn(&str),
    progress: &(dyn Fn(usize) + Sync),
) -> Result<ScaledCloud, SiteError> {
    let (scaling, targets) = match request.scale {
        Some(s) if s.is_finite() && s > 0.0 => (Scaling::Given(s), None),
        Some(s) => {
            return Err(SiteError::Input(format!(
                "--scale {s}: must be a positive number"
            )));
        }
        None => {
            let t = scale_from_targets(request, log, progress)?;
            (Scaling::Targets(t.estimate.clone()), Some(t))
        }
    };
    let vis_path = {
        let mut p = request.cloud.as_os_str().to_owned();
        p.push(".vis");
        PathBuf::from(p)
    };
    let (points, cloud_source) = match &targets {
        Some(t) if vis_path.is_file() => {
            let visibility = crate::io::vis::read(&vis_path, points.len())?;
            let order = Reconstruction::image_file_order(&t.sfm)?;
            let cameras: Vec<(ImageId, FrameCamera)> = t
                .poses
                .a1
                .frames
                .iter()
                .map(|f| (f.image_id, f.camera))
                .collect();
            let rolling = t.poses.rolling.as_ref();
            let cloud =
                retriangulate_cloud(points, &visibility, &t.model, &order, &cameras, rolling)?;
            log(&format!(
                "cloud re-triangulated through the profile at the re-adjusted poses{} ({} points, {} without two usable views dropped; visibility from {})",
                if rolling.is_some() {
                    ", each view at its row's pose"
                } else {
                    ""
                },
                cloud.points.len(),
                cloud.dropped,
                vis_path.display()
            ));
            (cloud, CloudSource::Retriangulated)
        }
        Some(_) => {
            log(&format!(
                "no {}: the cloud is used as fused, with the SfM program's camera and poses (it may carry that camera's errors)",
                vis_path.display()
            ));
            (as_given(points), CloudSource::AsGiven)
        }
        None => (as_given(points), CloudSource::AsGiven),
    };
    Ok(ScaledCloud {
        scaling,
        targets,
        points,
        cloud_source,
    })
}

/// The pipe network of a site's cloud ([`site_network`]).
#[derive(Clone, Debug)]
pub struct SiteNetwork {
    /// The cloud's scale and the points before it.
    pub scaled: ScaledCloud,
    /// The points searched: in metres, in the TLS frame when the targets gave a similarity.
    pub points: Vec<Vector3<f64>>,
    /// The network (its `inlier_indices` index [`SiteNetwork::points`]).
    pub network: super::network::Network,
}

/// The pipe network of a site's photogrammetric cloud `points`: the cloud scaled as for the
/// main command ([`scaled_cloud`]: from the targets against the TLS list, re-triangulated at the
/// re-adjusted poses), brought into metres (and the TLS frame) and searched whole
/// ([`super::network::extract_network`]).
///
/// # Errors
///
/// [`SiteError`] naming the input and step that failed.
pub fn site_network(
    request: &SiteRequest,
    points: &[Vector3<f64>],
    config: &super::network::NetworkConfig,
    log: &dyn Fn(&str),
    progress: &(dyn Fn(usize) + Sync),
) -> Result<SiteNetwork, SiteError> {
    let scaled = scaled_cloud(request, points, log, progress)?;
    let metric =
        super::pipe::transformed_points(&scaled.points.points, &scaled.scaling.transform(), None);
    let network =
        super::network::extract_network(&metric, config).map_err(|source| SiteError::Network {
            path: request.cloud.clone(),
            source,
        })?;
    Ok(SiteNetwork {
        scaled,
        points: metric,
        network,
    })
}

/// Measures the site: `points` is the cloud of `request.cloud`, `scan` the TLS scan's points
/// (when given).
///
/// # Errors
///
/// [`SiteError`] naming the input and step that failed.
pub fn measure_site(
    request: &SiteRequest,
    points: &[Vector3<f64>],
    scan: Option<&[Vector3<f64>]>,
    log: &dyn Fn(&str),
    progress: &(dyn Fn(usize) + Sync),
) -> Result<SiteMeasurement, SiteError> {
    let ScaledCloud {
        scaling,
        targets,
        points,
        cloud_source,
    } = scaled_cloud(request, points, log, progress)?;
    let views = targets
        .as_ref()
        .map(|t| views_of(t, &scaling.transform()))
        .unwrap_or_default();
    let mut pipe = measure_pipe(
        &points.points,
        &scaling,
        request.region.as_ref(),
        &request.cylinder,
        &views,
    )
    .map_err(|source| SiteError::Fit {
        path: request.cloud.clone(),
        source,
    })?;
    log(&choice_message(&pipe));
    // What the poses' uncertainty does to the radius (the targets and the cloud move with them).
    let pose_radius_std_m = match (&targets, cloud_source) {
        (Some(t), CloudSource::Retriangulated) => {
            let s = pose_radius_std(t, &points, &pipe, request);
            if let Some(s) = s {
                log(&format!(
                    "the poses' uncertainty contributes ±{:.3} mm to the radius ({POSE_SAMPLES} samples of the poses' covariance)",
                    s * 1e3
                ));
                pipe.radius_std = pipe.radius_std.hypot(s);
            }
            s
        }
        _ => None,
    };
    let reference = match (&request.tls_scan, scan) {
        (Some(path), Some(scan)) => Some(
            reference_fit(scan, &pipe, scaling.in_tls_frame(), &request.cylinder).map_err(
                |source| SiteError::Fit {
                    path: path.clone(),
                    source,
                },
            )?,
        ),
        _ => None,
    };
    // Every other segment's reference where the scan is in the measured frame (with only a
    // scale, nothing but the radius says which scan cylinder is which pipe).
    let references: Vec<Option<Reference>> = match (scan, scaling.in_tls_frame()) {
        (Some(scan), true) => pipe
            .segments
            .par_iter()
            .enumerate()
            .map(|(k, g)| {
                if k == pipe.choice.segment {
                    return reference.clone();
                }
                segment_reference(scan, g, &pipe.points, &request.cylinder).ok()
            })
            .collect(),
        _ => (0..pipe.segments.len())
            .map(|k| {
                if k == pipe.choice.segment {
                    reference.clone()
                } else {
                    None
                }
            })
            .collect(),
    };
    let mut report = report(
        &request.cloud,
        &pipe,
        &scaling,
        targets.as_ref(),
        reference.as_ref(),
        cloud_source,
    );
    report.pipes = pipe_reports(&pipe, &references);
    report.pose_radius_std_m = pose_radius_std_m;
    if let Some(p) = report
        .pipes
        .iter_mut()
        .find(|p| p.id == pipe.segments[pipe.choice.segment].id)
    {
        p.radius_std_m = pipe.radius_std;
        p.pose_radius_std_m = pose_radius_std_m;
    }
    Ok(SiteMeasurement {
        pipe,
        scaling,
        targets,
        reference,
        cloud_source,
        report,
    })
}

/// A target used for the scale.
#[derive(Clone, Debug, Serialize)]
pub struct ScaleTargetOut {
    /// Its TLS id.
    pub tls_id: String,
    /// Its views.
    pub views: usize,
    /// Distance to the TLS target after the similarity (m), if there is one.
    pub residual_m: Option<f64>,
}

/// The pipe's axis.
#[derive(Clone, Debug, Serialize)]
pub struct AxisOut {
    /// A point of the axis.
    pub point: [f64; 3],
    /// Unit direction.
    pub direction: [f64; 3],
}

/// The main command's report (`measurement.json`, schema `pipemeasure.measurement/1`).
#[derive(Clone, Debug, Serialize)]
pub struct SiteReport {
    /// Schema name.
    pub schema: &'static str,
    /// The cloud.
    pub cloud: String,
    /// How the cloud was used: `as_given` or `retriangulated`.
    pub cloud_source: CloudSource,
    /// The device.
    pub device: Option<String>,
    /// The model.
    pub sfm: Option<String>,
    /// The TLS list.
    pub tls_targets: Option<String>,
    /// Whether the frames were undistorted.
    pub frames_undistorted: Option<bool>,
    /// Algorithm 1's reprojection σ with the model's poses and the profile (px).
    pub reprojection_sigma_before_px: Option<f64>,
    /// The same after the poses were re-adjusted to the profile (px).
    pub reprojection_sigma_after_px: Option<f64>,
    /// The rolling shutter's readout time (s) the poses were adjusted with, when modelled.
    pub readout_time_s: Option<f64>,
    /// The re-adjustment's reprojection σ with a motion per frame (px), when modelled.
    pub reprojection_sigma_rolling_px: Option<f64>,
    /// The frames' median angular speed during the readout (°/s), when modelled.
    pub median_angular_speed_deg_s: Option<f64>,
    /// Radius (m).
    pub radius_m: f64,
    /// Combined σ: the fit's, the scale's and the poses' (when the cloud was re-triangulated).
    pub radius_std_m: f64,
    /// The poses' part of it (Monte Carlo over their covariance), when known.
    pub pose_radius_std_m: Option<f64>,
    /// The fit's σ.
    pub fit_radius_std_m: f64,
    /// RMSE of the inliers (m).
    pub rmse_m: f64,
    /// Inliers.
    pub inliers: usize,
    /// Axis.
    pub axis: AxisOut,
    /// The measured segment's axis endpoints (where the pipe ends, turns or leaves the region
    /// of interest).
    pub segment_start: [f64; 3],
    /// See `segment_start`.
    pub segment_end: [f64; 3],
    /// The segment's length (m).
    pub length_m: f64,
    /// The standard size closest to the measured outside diameter (steel tables).
    pub nominal: super::NominalSize,
    /// Pipe segments the search found, the measured one included.
    pub segments_found: usize,
    /// How the measured segment (the pipe of interest) was chosen.
    pub pipe_of_interest: ChoiceOut,
    /// Every pipe segment found, the pipe of interest among them.
    pub pipes: Vec<PipeOut>,
    /// `tls` when the cloud was moved into the TLS frame by the targets' similarity, `scaled`
    /// when only scaled.
    pub frame: &'static str,
    /// Scale.
    pub scale: f64,
    /// Its σ.
    pub scale_std: f64,
    /// `given`, `two targets` (paper) or `similarity`.
    pub scale_method: &'static str,
    /// The targets of the scale.
    pub scale_targets: Vec<ScaleTargetOut>,
    /// The paper's two-target scale.
    pub two_target_scale: Option<f64>,
    /// Its two TLS ids.
    pub two_target_ids: Option<[String; 2]>,
    /// The similarity's scale.
    pub similarity_scale: Option<f64>,
    /// Its σ.
    pub similarity_scale_std: Option<f64>,
    /// RMS of the similarity's residuals (m).
    pub similarity_rms_m: Option<f64>,
    /// Whether the two-target association was assumed.
    pub association_assumed: Option<bool>,
    /// The reference radius (m).
    pub reference_radius_m: Option<f64>,
    /// Its σ.
    pub reference_radius_std_m: Option<f64>,
    /// Its RMSE.
    pub reference_rmse_m: Option<f64>,
    /// Its inliers.
    pub reference_inliers: Option<usize>,
    /// Radius minus the reference radius (m).
    pub accuracy_m: Option<f64>,
}

/// How the pipe of interest was chosen, in the report.
#[derive(Clone, Debug, Serialize)]
pub struct ChoiceOut {
    /// The chosen segment's id (its entry in `pipes`).
    pub segment: usize,
    /// `near`, `frames` (with the votes) or `most-inliers` (with the reason).
    #[serde(flatten)]
    pub by: ChosenBy,
    /// Distance from the `--near` point to its axis (m).
    pub distance_m: Option<f64>,
    /// The next candidate's id and its distance from the `--near` point (m), its votes or its
    /// inliers.
    pub runner_up: Option<(usize, f64)>,
    /// Whether other segments are as good a choice.
    pub ambiguous: bool,
    /// Those segments' ids.
    pub alternatives: Vec<usize>,
}

/// One pipe segment of the measured cloud, in the report.
#[derive(Clone, Debug, Serialize)]
pub struct PipeOut {
    /// Its id.
    pub id: usize,
    /// Whether it is the pipe of interest.
    pub of_interest: bool,
    /// Radius (m).
    pub radius_m: f64,
    /// σ: the fit's and the scale's (and for the pipe of interest the poses').
    pub radius_std_m: f64,
    /// The poses' part of it, when computed (the pipe of interest).
    pub pose_radius_std_m: Option<f64>,
    /// The closest standard size.
    pub nominal: super::NominalSize,
    /// Axis start (m, measured frame).
    pub start: [f64; 3],
    /// Axis end.
    pub end: [f64; 3],
    /// Length (m).
    pub length_m: f64,
    /// Inliers.
    pub inliers: usize,
    /// RMS of the inliers' residuals (m).
    pub rmse_m: f64,
    /// Arc of the circumference its inliers fill (degrees).
    pub coverage_deg: f64,
    /// The TLS scan's fit of the same pipe (m), when the scan was given and is in the same
    /// frame.
    pub reference_radius_m: Option<f64>,
    /// Radius minus the reference radius (m).
    pub accuracy_m: Option<f64>,
}

/// The report's entry for every segment of `m`, with its reference when there is one.
fn pipe_reports(m: &PipeMeasurement, references: &[Option<Reference>]) -> Vec<PipeOut> {
    let (s, s_std) = m.scale;
    m.segments
        .iter()
        .enumerate()
        .map(|(k, g)| {
            let r = g.radius_m;
            let reference = references.get(k).and_then(Option::as_ref);
            PipeOut {
                id: g.id,
                of_interest: k == m.choice.segment,
                radius_m: r,
                radius_std_m: g.radius_std_m.hypot(r * s_std / s),
                pose_radius_std_m: None,
                nominal: g.nominal.clone(),
                start: g.start,
                end: g.end,
                length_m: g.length_m,
                inliers: g.inliers,
                rmse_m: g.rmse_m,
                coverage_deg: g.coverage_deg,
                reference_radius_m: reference.map(|x| x.fit.cylinder.radius),
                accuracy_m: reference.map(|x| r - x.fit.cylinder.radius),
            }
        })
        .collect()
}

/// The choice in the report: indices turned into segment ids.
fn choice_out(m: &PipeMeasurement) -> ChoiceOut {
    let c = &m.choice;
    let id = |k: usize| m.segments[k].id;
    ChoiceOut {
        segment: id(c.segment),
        by: c.by.clone(),
        distance_m: c.distance_m,
        runner_up: c.runner_up.map(|(k, d)| (id(k), d)),
        ambiguous: c.ambiguous,
        alternatives: c.alternatives.iter().map(|&k| id(k)).collect(),
    }
}

/// What the log says of the choice of the pipe of interest.
#[must_use]
pub fn choice_message(m: &PipeMeasurement) -> String {
    let c = &m.choice;
    let seg = |k: usize| {
        let g = &m.segments[k];
        format!("segment {} (r {:.2} mm)", g.id, g.radius_m * 1e3)
    };
    let how = match &c.by {
        ChosenBy::Near => format!(
            "the one whose axis passes nearest --near ({:.0} mm)",
            c.distance_m.unwrap_or(f64::NAN) * 1e3
        ),
        ChosenBy::Frames { votes, frames } => {
            format!("the one the optical axes of {votes} of the {frames} frames meet first")
        }
        ChosenBy::MostInliers { reason } => {
            format!("the best-supported one (most inliers): {reason}")
        }
    };
    let next = match (c.ambiguous, c.runner_up, &c.by) {
        (true, _, _) => format!(
            "; ambiguous: {} as good a choice; give --near X,Y,Z to choose",
            c.alternatives
                .iter()
                .map(|&k| seg(k))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        (false, Some((k, d)), ChosenBy::Near) => {
            format!("; next: {} at {:.0} mm", seg(k), d * 1e3)
        }
        (false, Some((k, v)), ChosenBy::Frames { .. }) => {
            format!("; next: {} with {v} frames", seg(k))
        }
        _ => String::new(),
    };
    format!(
        "pipe of interest: {} of {} found, {how}{next}",
        seg(c.segment),
        m.segments.len()
    )
}

/// The frames' optical axes in the measured frame: the re-adjusted poses' camera centres and
/// +Z axes, through the cloud's transform.
fn views_of(t: &SiteScale, transform: &crate::adjust::Similarity) -> Vec<View> {
    t.poses
        .a1
        .frames
        .iter()
        .map(|f| {
            let pose = &f.camera.cam_from_world;
            let centre = crate::geometry::pose::camera_centre(pose);
            let axis = pose.rotation.inverse() * Vector3::z();
            View {
                centre: transform.apply(&centre.coords),
                direction: (transform.rotation * axis).normalize(),
            }
        })
        .collect()
}

fn report(
    cloud: &Path,
    m: &PipeMeasurement,
    scaling: &Scaling,
    targets: Option<&SiteScale>,
    reference: Option<&Reference>,
    cloud_source: CloudSource,
) -> SiteReport {
    let c = &m.fit.cylinder;
    let est = targets.map(|t| &t.estimate);
    let rolling = targets.and_then(|t| t.poses.rolling.as_ref());
    let scale_targets = targets
        .map(|t| {
            t.estimate
                .associated
                .iter()
                .enumerate()
                .map(|(k, &(r, i))| ScaleTargetOut {
                    tls_id: t.tls_ids[i].clone(),
                    views: t.views[r],
                    residual_m: t
                        .estimate
                        .similarity
                        .as_ref()
                        .and_then(|s| s.residuals_m.get(k).copied()),
                })
                .collect()
        })
        .unwrap_or_default();
    SiteReport {
        schema: "pipemeasure.measurement/1",
        cloud: cloud.display().to_string(),
        cloud_source,
        device: targets.map(|t| t.device.clone()),
        sfm: targets.map(|t| t.sfm.display().to_string()),
        tls_targets: targets.map(|t| t.tls_targets.display().to_string()),
        frames_undistorted: targets.map(|t| t.undistorted_frames),
        reprojection_sigma_before_px: targets.map(|t| t.poses.sigma_before_px),
        reprojection_sigma_after_px: targets.map(|t| t.poses.sigma_after_px),
        readout_time_s: rolling.map(|r| r.timing.readout_s),
        reprojection_sigma_rolling_px: rolling.map(|r| r.sigma_px),
        median_angular_speed_deg_s: rolling.map(|r| median_angular_speed_deg_s(&r.motions)),
        radius_m: c.radius,
        radius_std_m: m.radius_std,
        pose_radius_std_m: None,
        fit_radius_std_m: m.fit.radius_std,
        rmse_m: m.fit.rmse,
        inliers: m.fit.inliers,
        axis: AxisOut {
            point: c.point.into(),
            direction: c.direction.into(),
        },
        segment_start: m.segment.start,
        segment_end: m.segment.end,
        length_m: m.segment.length_m,
        nominal: m.segment.nominal.clone(),
        segments_found: m.segments_found,
        pipe_of_interest: choice_out(m),
        pipes: Vec::new(),
        frame: if scaling.in_tls_frame() {
            "tls"
        } else {
            "scaled"
        },
        scale: m.scale.0,
        scale_std: m.scale.1,
        scale_method: match (scaling, est.and_then(|e| e.similarity.as_ref())) {
            (Scaling::Given(_), _) => "given",
            (_, Some(_)) => "similarity",
            _ => "two targets",
        },
        scale_targets,
        two_target_scale: est.map(|e| e.two_target.scale),
        two_target_ids: targets.map(|t| t.estimate.two_target.tls.map(|i| t.tls_ids[i].clone())),
        similarity_scale: est.and_then(|e| e.similarity.as_ref().map(|s| s.scale)),
        similarity_scale_std: est.and_then(|e| e.similarity.as_ref().map(|s| s.scale_std)),
        similarity_rms_m: est.and_then(|e| e.similarity.as_ref().map(|s| s.rms_m)),
        association_assumed: est.map(|e| e.assumed),
        reference_radius_m: reference.map(|r| r.fit.cylinder.radius),
        reference_radius_std_m: reference.map(|r| r.fit.radius_std),
        reference_rmse_m: reference.map(|r| r.fit.rmse),
        reference_inliers: reference.map(|r| r.fit.inliers),
        accuracy_m: reference.map(|r| r.accuracy),
    }
}

/// The cloud as given, with no views.
fn as_given(points: &[Vector3<f64>]) -> RetriangulatedCloud {
    RetriangulatedCloud {
        points: points.to_vec(),
        rays: Vec::new(),
        dropped: 0,
    }
}

/// Samples of the poses' covariance drawn for the radius's pose σ ([`measure_site`]).
pub const POSE_SAMPLES: usize = 32;

/// The radius's σ from the poses' uncertainty, by Monte Carlo: `POSE_SAMPLES` draws of all the
/// poses from their joint covariance; per draw the
/// targets and the pipe's points (those within 3 RMSE of the fitted cylinder) triangulated
/// again, the scale or similarity re-estimated on the same association, and the cylinder
/// fitted again. Seeded: the same input gives the same σ. `None` without a covariance
/// ([`pose_covariance`]).
fn pose_radius_std(
    t: &SiteScale,
    cloud: &RetriangulatedCloud,
    pipe: &PipeMeasurement,
    request: &SiteRequest,
) -> Option<f64> {
    use rand::SeedableRng;
    let cov = pose_covariance(&t.model, &t.poses)?;
    let draw = covariance_sampler(&cov)?;
    let nominal = Scaling::Targets(t.estimate.clone()).transform();
    let c = &pipe.fit.cylinder;
    let band = 3.0 * pipe.fit.rmse.max(1e-6);
    let near: Vec<usize> = (0..cloud.points.len())
        .filter(|&k| {
            let p = nominal.apply(&cloud.points[k]);
            request.region.as_ref().is_none_or(|r| r.contains(&p)) && c.residual(&p).abs() < band
        })
        .collect();
    if near.len() < 50 {
        return None;
    }
    let frames = &t.poses.a1.frames;
    let block = cov.nrows() / frames.len().max(1);
    let tls = &t.tls_points;
    let radii: Vec<f64> = (0..POSE_SAMPLES)
        .into_par_iter()
        .filter_map(|s| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5EED_0000 + s as u64);
            let delta = draw(&mut rng);
            let poses: Vec<crate::geometry::Rigid3> = frames
                .iter()
                .enumerate()
                .map(|(j, f)| {
                    let d = Vector6::from_fn(|r, _| delta[block * j + r]);
                    crate::geometry::pose::retract(&f.camera.cam_from_world, &d)
                })
                .collect();
            // With rolling-shutter motions the covariance has their steps after each pose's.
            let sampled = t.poses.rolling.as_ref().map(|r| RollingPoses {
                motions: r
                    .motions
                    .iter()
                    .enumerate()
                    .map(|(j, m)| match block {
                        12 => crate::camera::rolling::Motion {
                            angular: m.angular + Vector3::from_fn(|r, _| delta[block * j + 6 + r]),
                            linear: m.linear + Vector3::from_fn(|r, _| delta[block * j + 9 + r]),
                            ..*m
                        },
                        _ => *m,
                    })
                    .collect(),
                ..r.clone()
            });
            let rolling = sampled.as_ref();
            let targets: Vec<Option<Point3<f64>>> = t
                .tracks
                .iter()
                .map(|views| triangulate_target(views, &t.intrinsics, &|f| poses[f], rolling))
                .collect();
            let transform = resampled_transform(&t.estimate, &targets, tls)?;
            let points: Vec<Vector3<f64>> = near
                .iter()
                .filter_map(|&k| {
                    triangulate_rays(&cloud.rays[k], &|j| poses[j], rolling)
                        .map(|p| transform.apply(&p))
                })
                .collect();
            super::pipe::fit_points(&points, &request.cylinder)
                .ok()
                .map(|f| f.cylinder.radius)
        })
        .collect();
    if radii.len() < POSE_SAMPLES / 2 {
        return None;
    }
    let mean = radii.iter().sum::<f64>() / radii.len() as f64;
    let var = radii.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (radii.len() - 1) as f64;
    Some(var.sqrt())
}

/// A sampler of `N(0, cov)`: `V·√Λ·z` from the symmetric eigen-decomposition (the
/// free network's covariance is singular along its datum; negative round-off clamped).
#[allow(clippy::type_complexity)]
fn covariance_sampler(
    cov: &DMatrix<f64>,
) -> Option<impl Fn(&mut rand_chacha::ChaCha8Rng) -> nalgebra::DVector<f64>> {
    let n = cov.nrows();
    if n == 0 || cov.ncols() != n || cov.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let eigen = nalgebra::SymmetricEigen::new(cov.clone());
    let scale: Vec<f64> = eigen
        .eigenvalues
        .iter()
        .map(|l| l.max(0.0).sqrt())
        .collect();
    let vectors = eigen.eigenvectors;
    Some(move |rng: &mut rand_chacha::ChaCha8Rng| {
        let z = nalgebra::DVector::from_fn(n, |k, _| scale[k] * gaussian(rng));
        &vectors * z
    })
}

/// The scale (or similarity) of `estimate` re-estimated on the same association from moved
/// targets.
fn resampled_transform(
    estimate: &ScaleEstimate,
    targets: &[Option<Point3<f64>>],
    tls: &[Point3<f64>],
) -> Option<crate::adjust::Similarity> {
    match &estimate.similarity {
        Some(_) => {
            let origin = tls.first()?.coords;
            let (from, to): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = estimate
                .associated
                .iter()
                .filter_map(|&(r, k)| {
                    Some((
                        targets.get(r)?.as_ref()?.coords,
                        tls.get(k)?.coords - origin,
                    ))
                })
                .unzip();
            let mut sim = crate::adjust::similarity_from_points(&from, &to)?;
            sim.translation += origin;
            Some(sim)
        }
        None => {
            let [a, b] = estimate.two_target.reconstructed;
            let d = (targets.get(a)?.as_ref()? - targets.get(b)?.as_ref()?).norm();
            (d > 0.0).then(|| crate::adjust::Similarity {
                scale: estimate.two_target.tls_distance / d,
                ..crate::adjust::Similarity::identity()
            })
        }
    }
}
