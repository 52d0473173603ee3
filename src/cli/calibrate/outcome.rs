//! What `pipemeasure calibrate` prints when it is done.

use std::path::Path;

use anyhow::Result;
use pipemeasure::calibrate::DeviceCalibration;
use pipemeasure::calibrate::check_points::CheckPointReport;
use pipemeasure::calibrate::network::ColmapNetwork;
use pipemeasure::report::calibration::intrinsics_table;

use super::Args;

/// What `calibrate` prints when it is done.
pub(super) struct Outcome<'a> {
    pub(super) args: &'a Args,
    pub(super) device: &'a DeviceCalibration,
    pub(super) high: &'a [(String, String, f64)],
    pub(super) check_report: Option<&'a CheckPointReport>,
    pub(super) colmap: Option<&'a ColmapNetwork>,
    pub(super) out: &'a Path,
    pub(super) backup: Option<&'a Path>,
}

/// Prints the calibration's summary: the fit, the intrinsics, the checks, the warnings and
/// where everything was written.
pub(super) fn print_outcome(o: &Outcome<'_>) -> Result<()> {
    let cal = &o.device.calibration;
    outln!(
        "calibrated {} from {} frames: {} targets, {} observations, σ0 {:.4} px, residual RMS {:.4} px",
        o.args.device,
        cal.frame_names.len(),
        cal.points.len(),
        cal.observations.len(),
        cal.sigma0,
        cal.residual_rms_px
    );
    out!("{}", intrinsics_table(cal));
    for (a, b, r) in o.high {
        outln!("correlation {a}/{b} = {r:.3} (above 0.9)");
    }
    outln!(
        "projection uncertainty of a ray: worst {:.4} px, RMS {:.4} px over the frame",
        o.device.projection_uncertainty.max,
        o.device.projection_uncertainty.rms
    );
    if let Some(cv) = &o.device.cross_validation {
        outln!(
            "cross-validation ({} / {} frames): the halves' projections differ by {:.4} px at most, {:.4} px RMS; after the rotation between them ({:.4}°) {:.4} px at most, {:.4} px RMS, {:.2} × the {:.4} px their σ predict",
            cv.frames[0],
            cv.frames[1],
            cv.max_px,
            cv.rms_px,
            cv.rotation_deg,
            cv.rotated_max_px,
            cv.rotated_rms_px,
            cv.ratio,
            cv.predicted_rms_px
        );
    }
    for w in &o.device.calibration.warnings {
        outln!("WARNING: {w}");
    }
    if let Some(c) = o.check_report {
        outln!(
            "check points: {} associated ({} not), RMS {:.3} mm, median {:.3} mm, max {:.3} mm after a similarity{}",
            c.points.len(),
            c.unassociated.len(),
            c.rms_m * 1e3,
            c.median_m * 1e3,
            c.max_m * 1e3,
            match (c.predicted_rms_m, c.normalized_rms) {
                (Some(p), Some(z)) => format!(
                    "; the targets' σ predict {:.3} mm; the residuals are {z:.2} × their own σ",
                    p * 1e3
                ),
                _ => String::new(),
            }
        );
    }
    if let (Some(dir), Some(net)) = (&o.args.network, o.colmap) {
        outln!(
            "adjusted network written to {} as a COLMAP model ({} images, {} targets; camera {}{})",
            dir.display(),
            net.model.images.len(),
            net.model.points3d.len(),
            net.camera_model.name(),
            if net.exact {
                " holding the profile exactly".to_string()
            } else {
                format!(
                    ", up to {:.3} px from the profile: COLMAP has no {}",
                    net.max_error_px,
                    net.missing_terms.join(", ")
                )
            }
        );
    }
    outln!("profile written to {}", o.out.display());
    if o.args.out.is_none() {
        shadow_note(&o.args.device, o.out);
    }
    if let Some(b) = o.backup {
        outln!("the profile it replaces kept as {}", b.display());
    }
    if let Some(dir) = &o.args.report {
        outln!("report written to {}", dir.display());
    }
    Ok(())
}

/// Says so when `--device NAME` from this folder finds another profile before the one just
/// written to the default folder (a `./calibrations/NAME.json` here, or
/// `$PIPEMEASURE_CALIBRATIONS`'s).
fn shadow_note(device: &str, written: &std::path::Path) {
    if let Some(found) = pipemeasure::profile::shadowing(device, written) {
        eprintln!(
            "note: from this folder `--device {device}` finds {} ({}) first; the new profile is \
             found from folders without one",
            found.path.display(),
            found.origin
        );
    }
}
