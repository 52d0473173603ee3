//! The calibration report (`calibrate --report DIR`): what the calibration found, for people
//! (`report.md`, the plots) and for programs (`report.json`, schema
//! `pipemeasure.calibration-report/1`).

use std::path::Path;

use nalgebra::Vector2;
use serde::Serialize;

use super::ReportError;
use super::plots;
use crate::calibrate::check_points::CheckPointReport;
use crate::calibrate::checks::{DistortionCheck, ImageMap};
use crate::calibrate::{Calibration, CrossValidation, DeviceCalibration};
use crate::camera::Term;
use crate::geometry::pose::camera_centre;
use crate::io::atomic::write_bytes_atomic;
use crate::profile::Profile;

/// The report's schema tag.
pub const CALIBRATION_REPORT_SCHEMA: &str = "pipemeasure.calibration-report/1";

/// `report.json`: the profile and how the calibration got there.
#[derive(Serialize)]
pub struct CalibrationReport<'a> {
    /// The report's schema tag.
    pub schema: &'static str,
    /// The device's name.
    pub device: &'a str,
    /// The profile written.
    pub profile: &'a Profile,
    /// The term selection's steps.
    pub selection: &'a [crate::calibrate::selection::SelectionStep],
    /// The loop's iterations.
    pub iterations: &'a [crate::calibrate::pipeline::LoopRecord],
    /// Whether the loop converged.
    pub converged: bool,
    /// Why the loop stopped.
    pub stop_reason: String,
    /// The selection's alternation between two term sets and how the loop settled it.
    pub term_alternation: Option<&'a crate::calibrate::pipeline::TermAlternation>,
    /// Frames (by name) in the final adjustment; the others saw too few targets.
    pub adjusted_frames: Vec<&'a str>,
    /// Redundancy of the final adjustment.
    pub redundancy: usize,
    /// Algorithm 1 step 4's solver summary.
    pub feature_adjustment: Option<crate::adjust::AdjustSummary>,
    /// The final adjustment's solver summary.
    pub adjustment: crate::adjust::AdjustSummary,
    /// Whether the distortion is invertible over the frame.
    pub distortion_check: &'a DistortionCheck,
    /// The ray projection σ over the frame (px).
    pub projection_uncertainty: &'a ImageMap,
    /// The halves compared, when asked.
    pub cross_validation: Option<&'a CrossValidation>,
    /// Pairs of estimated terms correlated above [`crate::profile::HIGH_CORRELATION`].
    pub high_correlations: Vec<(String, String, f64)>,
    /// Warnings for the user.
    pub warnings: &'a [String],
    /// The final adjustment's observations with residuals.
    pub observations: &'a [crate::calibrate::pipeline::CalibrationObservation],
    /// The adjusted targets and frames with their σ.
    pub network: &'a crate::calibrate::network::Network,
    /// The check points' comparison, when given.
    pub check_points: Option<&'a CheckPointReport>,
    /// The jackknife over the frames that checked (and widened) the covariance, when it ran.
    pub frame_jackknife: Option<&'a crate::calibrate::pipeline::JackknifeCheck>,
}

impl<'a> CalibrationReport<'a> {
    /// The report of the device `device`'s calibration `dc`, written as `profile`, with its
    /// adjusted `network` and the comparison against check points when there was one.
    #[must_use]
    pub fn new(
        device: &'a str,
        profile: &'a Profile,
        dc: &'a DeviceCalibration,
        network: &'a crate::calibrate::network::Network,
        check_points: Option<&'a CheckPointReport>,
    ) -> Self {
        let cal = &dc.calibration;
        CalibrationReport {
            schema: CALIBRATION_REPORT_SCHEMA,
            device,
            profile,
            selection: &cal.selection,
            iterations: &cal.iterations,
            converged: cal.converged(),
            stop_reason: cal.stop_reason(),
            term_alternation: cal.term_alternation.as_ref(),
            adjusted_frames: cal
                .adjusted_frames
                .iter()
                .map(|&k| cal.frame_names[k].as_str())
                .collect(),
            redundancy: cal.redundancy,
            feature_adjustment: cal.feature_adjustment,
            adjustment: cal.summary,
            distortion_check: &dc.distortion_check,
            projection_uncertainty: &dc.projection_uncertainty,
            cross_validation: dc.cross_validation.as_ref(),
            high_correlations: profile.high_correlations(),
            warnings: &dc.calibration.warnings,
            observations: &cal.observations,
            network,
            check_points,
            frame_jackknife: cal.frame_jackknife.as_ref(),
        }
    }
}

/// The intrinsics as a Markdown table: each term's value and σ, or `fixed`.
#[must_use]
pub fn intrinsics_table(cal: &Calibration) -> String {
    let mut s = String::from("| term | value | σ |\n| --- | ---: | ---: |\n");
    for t in Term::ALL {
        let v = cal.intrinsics.get(t);
        let sd = cal.std_dev[t.index()];
        if cal.terms.contains(&t) {
            s += &format!("| {} | {v:.6e} | {sd:.2e} |\n", t.name());
        } else {
            s += &format!("| {} | {v} | fixed |\n", t.name());
        }
    }
    s
}

/// Writes the calibration report into `dir`: `report.json` (the [`CalibrationReport`]),
/// `report.md` (for people), and the plots: radial residuals before and after the chosen
/// terms, the residual vectors, the camera network, the projection σ over the frame and the
/// cross-validation's difference map.
///
/// # Errors
/// [`ReportError`] when a plot cannot be drawn or a file cannot be written.
pub fn write_calibration_report(
    dir: &Path,
    cal: &Calibration,
    size: (u32, u32),
    report: &CalibrationReport<'_>,
) -> Result<(), ReportError> {
    // Radial residuals before (c, u0, v0 only) and after (the chosen model).
    let (u0, v0) = (cal.intrinsics.u0, cal.intrinsics.v0);
    let after: Vec<(f64, f64)> = cal
        .observations
        .iter()
        .map(|o| {
            let d = Vector2::new(o.uv[0] - u0, o.uv[1] - v0);
            let r = d.norm().max(1e-12);
            (r, (o.residual[0] * d.x + o.residual[1] * d.y) / r)
        })
        .collect();
    let chosen = format!(
        "chosen model ({})",
        cal.terms
            .iter()
            .map(|t| t.name())
            .collect::<Vec<_>>()
            .join(", ")
    );
    plots::radial_residuals(
        &dir.join("radial_residuals.svg"),
        &[("c, u0, v0 only", &cal.radial_base), (&chosen, &after)],
    )?;
    let vectors: Vec<(Vector2<f64>, Vector2<f64>)> = cal
        .observations
        .iter()
        .map(|o| {
            (
                Vector2::new(o.uv[0], o.uv[1]),
                Vector2::new(o.residual[0], o.residual[1]),
            )
        })
        .collect();
    let rms = cal.residual_rms_px.max(1e-6);
    let scale = (0.02 * f64::from(size.0) / (3.0 * rms)).round().max(1.0);
    plots::residual_vectors(&dir.join("residual_vectors.svg"), size, &vectors, scale)?;
    let centres: Vec<_> = cal.cam_from_world.iter().map(camera_centre).collect();
    let dirs: Vec<_> = cal
        .cam_from_world
        .iter()
        .map(|p| p.rotation.inverse() * nalgebra::Vector3::z())
        .collect();
    plots::camera_network(
        &dir.join("camera_network.svg"),
        &centres,
        &dirs,
        &cal.points,
    )?;
    plots::image_map(
        &dir.join("projection_uncertainty.svg"),
        size,
        &report.projection_uncertainty.values,
        "projection σ of a ray",
        "px",
    )?;
    if let Some(cv) = report.cross_validation {
        plots::image_map(
            &dir.join("cross_validation.svg"),
            size,
            &cv.map.values,
            "difference of the two halves' projections",
            "px",
        )?;
    }
    let json = serde_json::to_string_pretty(report)?;
    write_bytes_atomic(&dir.join("report.json"), json.as_bytes())?;
    let mut md = format!(
        "# Calibration of {}\n\n{} frames, {} targets, {} observations; σ0 {:.4} px, residual RMS {:.4} px, redundancy {}.\n\n",
        report.device,
        cal.frame_names.len(),
        cal.points.len(),
        cal.observations.len(),
        cal.sigma0,
        cal.residual_rms_px,
        cal.redundancy
    );
    md += &format!(
        "The loop ran {} iteration(s) and stopped because {}{}.\n\n",
        cal.iterations.len(),
        cal.stop_reason(),
        if cal.converged() {
            ""
        } else {
            " (not converged)"
        }
    );
    if let Some(a) = &cal.term_alternation {
        md += &format!(
            "At iteration {} the term selection alternated between {} (BIC {:.1}) and {} (BIC {:.1}); {} was kept (lower BIC) for the rest of the loop. The two cameras differ by {:.4} px at most over the frame ({:.2} × the projection σ).\n\n",
            a.iteration,
            a.sets[0],
            a.bic[0],
            a.sets[1],
            a.bic[1],
            a.kept,
            a.camera_difference_px,
            a.camera_difference_ratio
        );
    }
    if cal.adjusted_frames.len() < cal.frame_names.len() {
        md += &format!(
            "{} of the {} frames saw too few matched targets to enter the adjustment.\n\n",
            cal.frame_names.len() - cal.adjusted_frames.len(),
            cal.frame_names.len()
        );
    }
    md += &intrinsics_table(cal);
    md += "\nCorrelations above 0.9 (flagged):\n\n";
    let high = &report.high_correlations;
    if high.is_empty() {
        md += "none\n";
    }
    for (a, b, r) in high {
        md += &format!("- **{a} / {b}: {r:.3}**\n");
    }
    md += "\nTerm selection:\n\n";
    for s in report.selection {
        md += &format!(
            "- {}: {} ({})\n",
            s.candidate
                .iter()
                .map(|t| t.name())
                .collect::<Vec<_>>()
                .join("+"),
            if s.accepted { "kept" } else { "refused" },
            s.reason
        );
    }
    if let Some(c) = report.check_points {
        md += &check_points_markdown(c);
    }
    for w in report.warnings {
        md += &format!("\n**warning:** {w}\n");
    }
    write_bytes_atomic(&dir.join("report.md"), md.as_bytes())?;
    Ok(())
}

/// The check points' section of `report.md`.
#[must_use]
pub fn check_points_markdown(c: &CheckPointReport) -> String {
    let mut md = format!(
        "\nCheck points: {} associated, {} not; after a 7-parameter similarity (scale {:.6} m per SfM unit) RMS {:.3} mm, median {:.3} mm, max {:.3} mm{}.\n\n",
        c.points.len(),
        c.unassociated.len(),
        c.scale,
        c.rms_m * 1e3,
        c.median_m * 1e3,
        c.max_m * 1e3,
        match (c.predicted_rms_m, c.normalized_rms) {
            (Some(p), Some(z)) => format!(
                " (the targets' σ predict {:.3} mm; the residuals are {z:.2} times their own σ)",
                p * 1e3
            ),
            _ => String::new(),
        }
    );
    md += "| id | target | dx (mm) | dy (mm) | dz (mm) | distance (mm) |\n|---|---|---|---|---|---|\n";
    for p in &c.points {
        md += &format!(
            "| {} | {} | {:+.3} | {:+.3} | {:+.3} | {:.3} |\n",
            p.id,
            p.target,
            p.residual_m[0] * 1e3,
            p.residual_m[1] * 1e3,
            p.residual_m[2] * 1e3,
            p.distance_m * 1e3
        );
    }
    if !c.unassociated.is_empty() {
        md += &format!("\nNot associated: {}\n", c.unassociated.join(", "));
    }
    md
}
