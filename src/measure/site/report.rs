//! The site's report: what `measure.json` holds (the scale, its targets, every pipe found with
//! its accuracy against the TLS scan, the choice of the pipe of interest) and the message that
//! explains the choice.

use std::path::Path;

use nalgebra::Vector3;
use serde::Serialize;

use super::CloudSource;
use super::scaling::{SiteScale, median_angular_speed_deg_s};
use crate::measure::choice::{ChosenBy, View};
use crate::measure::pipe::{PipeMeasurement, Reference, Scaling};

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
    pub nominal: crate::measure::NominalSize,
    /// Pipe segments the search found, the measured one included.
    pub segments_found: usize,
    /// How the measured segment (the pipe of interest) was chosen, segments named by their
    /// ids (their entries in `pipes`).
    pub pipe_of_interest: crate::measure::Choice,
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
    pub nominal: crate::measure::NominalSize,
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
pub(super) fn pipe_reports(m: &PipeMeasurement, references: &[Option<Reference>]) -> Vec<PipeOut> {
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
pub(super) fn views_of(t: &SiteScale, transform: &crate::adjust::Similarity) -> Vec<View> {
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

pub(super) fn report(
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
        pipe_of_interest: m.choice.renamed(|k| m.segments[k].id),
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
