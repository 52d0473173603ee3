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

mod error;
mod report;
mod retriangulate;
mod scaling;
mod uncertainty;
mod workspace;

pub use error::{SiteError, SiteInput};
pub use report::{AxisOut, PipeOut, ScaleTargetOut, SiteReport, choice_message};
pub use retriangulate::{RetriangulatedCloud, retriangulate_cloud};
pub use scaling::{Ray, SiteScale, row_targets, scale_from_targets};
pub use uncertainty::POSE_SAMPLES;
pub use workspace::{model_image_size, site_intrinsics};

use std::path::PathBuf;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;

use super::cylinder::CylinderConfig;
use super::pipe::{
    PipeMeasurement, Reference, Region, Scaling, measure_pipe, reference_fit, segment_reference,
};
use crate::calibrate::views::FrameCamera;
use crate::io::colmap::{ImageId, Reconstruction};
use report::{pipe_reports, views_of};
use retriangulate::as_given;
use uncertainty::pose_radius_std;

/// What the user gave (paths not given are searched for next to the cloud).
#[derive(Clone, Debug, Default)]
pub struct SiteRequest {
    /// The dense cloud (PLY or E57).
    pub cloud: PathBuf,
    /// Device profile: a name ([`crate::profile::find_device`]) or a path.
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
            return Err(SiteError::BadScale(s));
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
    let mut report = report::report(
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
