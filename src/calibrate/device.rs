//! Calibrating a device: the front door of the calibration, what `pipemeasure calibrate` runs
//! after it has the frames, their detections and the SfM model. The loop
//! ([`super::pipeline::calibrate`]), then the checks a profile needs before it is trusted:
//! whether the distortion stays invertible over the frame ([`check_distortion`]), the ray
//! projection uncertainty over the frame, and, when asked, the cross-validation of two halves
//! of the frames (odd and even), whose projections should agree within their own σ; where they
//! disagree by more, the σ are too small for these frames (correlated detection errors,
//! unmodelled effects) and the reported σ are widened to follow the data.

use serde::Serialize;

use super::checks::{
    DistortionCheck, ImageMap, check_distortion, projection_difference,
    projection_difference_rotated, projection_uncertainty,
};
use super::neighbours::NeighbourDetections;
use super::pipeline::{CalibrateConfig, CalibrateError, Calibration, CalibrationInput, calibrate};
use crate::geometry::conic::Ellipse;

/// How to calibrate a device.
#[derive(Clone, Debug, Default)]
pub struct DeviceConfig {
    /// The calibration loop.
    pub calibrate: CalibrateConfig,
    /// Cross-validate the two halves of the frames (odd and even).
    pub cross_validate: bool,
}

/// The two halves' cameras compared (mrcal's cross-validation: the difference of their
/// projections over the frame against what their σ predict).
#[derive(Clone, Debug, Serialize)]
pub struct CrossValidation {
    /// Frames in each half.
    pub frames: [usize; 2],
    /// The halves' projections apart, as they are (px).
    pub max_px: f64,
    /// Their RMS over the frame (px).
    pub rms_px: f64,
    /// The difference over the frame.
    pub map: ImageMap,
    /// After compensating the rotation between the halves' models (mrcal): what the data can
    /// tell apart (px).
    pub rotated_max_px: f64,
    /// Its RMS over the frame (px).
    pub rotated_rms_px: f64,
    /// The rotation compensated (degrees).
    pub rotation_deg: f64,
    /// The RMS difference the halves' own σ predict, `sqrt(rms σ_a² + rms σ_b²)` (px).
    pub predicted_rms_px: f64,
    /// Observed over predicted; above 1 the σ are too small for these frames.
    pub ratio: f64,
    /// The factor the profile's σ (and covariance, squared) were multiplied by: the ratio when
    /// above 1, else 1.
    pub sigma_scaled_by: f64,
}

/// A device's calibration with its checks.
#[derive(Clone, Debug)]
pub struct DeviceCalibration {
    /// The calibration; its σ and covariance widened by the cross-validation when the halves
    /// disagree by more than their σ say.
    pub calibration: Calibration,
    /// Whether the distortion stays monotonic and invertible over the frame.
    pub distortion_check: DistortionCheck,
    /// The ray projection uncertainty over the frame (px), from the final covariance.
    pub projection_uncertainty: ImageMap,
    /// The halves compared, when asked.
    pub cross_validation: Option<CrossValidation>,
}

/// Calibrates a device from an SfM model and the detections in its frames, and checks the
/// result (module docs).
///
/// # Errors
/// [`CalibrateError`] from the loop on all frames, or on a half
/// ([`CalibrateError::CrossValidation`]).
pub fn calibrate_device(
    input: &CalibrationInput<'_>,
    config: &DeviceConfig,
    log: &dyn Fn(&str),
) -> Result<DeviceCalibration, CalibrateError> {
    let size = input.image_size;
    let mut cal = calibrate(input, &config.calibrate, log)?;
    let distortion_check = check_distortion(&cal.intrinsics, size);
    // The checks' warnings follow the loop's in `cal.warnings`.
    if !distortion_check.ok {
        cal.warnings.push(format!(
            "the distortion is not monotonic and invertible over the whole frame: it fails at {} \
             of the checked pixels, from {:.0} px from the principal point (the frame reaches \
             {:.0} px); do not use the profile near the image border",
            distortion_check.failing_pixels,
            distortion_check.first_failure_radius_px.unwrap_or(f64::NAN),
            distortion_check.frame_radius_px
        ));
    }
    let cross_validation = if config.cross_validate {
        Some(cross_validate(input, &config.calibrate, log)?)
    } else {
        None
    };
    if let Some(cv) = &cross_validation
        && cv.sigma_scaled_by > 1.0
    {
        let k = cv.sigma_scaled_by;
        for s in &mut cal.std_dev {
            *s *= k;
        }
        cal.covariance *= k * k;
        cal.warnings.push(format!(
            "cross-validation: the halves' projections differ by {:.3} px RMS after the rotation between them, {k:.2} times what their σ predict ({:.3} px); the profile's σ are multiplied by {k:.2}",
            cv.rotated_rms_px, cv.predicted_rms_px
        ));
    }
    let projection_uncertainty = projection_uncertainty(&cal.intrinsics, &cal.covariance, size);
    Ok(DeviceCalibration {
        calibration: cal,
        distortion_check,
        projection_uncertainty,
        cross_validation,
    })
}

/// The loop on the odd and the even frames, and their cameras compared.
fn cross_validate(
    input: &CalibrationInput<'_>,
    config: &CalibrateConfig,
    log: &dyn Fn(&str),
) -> Result<CrossValidation, CalibrateError> {
    let size = input.image_size;
    let n = input.detections.len();
    let mut models = Vec::new();
    for h in 0..2 {
        let keep: Vec<bool> = (0..n).map(|k| k % 2 == h).collect();
        let sub = input.model.with_images(&keep);
        let det: Vec<Vec<Ellipse>> = kept(input.detections, &keep);
        let nb: Vec<Vec<NeighbourDetections>> = kept(input.neighbours, &keep);
        log(&format!(
            "cross-validation: half {} ({} frames)",
            h + 1,
            det.len()
        ));
        let half = CalibrationInput {
            model: &sub,
            detections: &det,
            image_size: size,
            neighbours: &nb,
        };
        models.push(calibrate(&half, config, log).map_err(|e| {
            CalibrateError::CrossValidation {
                half: h + 1,
                source: Box::new(e),
            }
        })?);
    }
    let map = projection_difference(&models[0].intrinsics, &models[1].intrinsics, size);
    let rotated = projection_difference_rotated(&models[0].intrinsics, &models[1].intrinsics, size);
    let sigma_rms =
        |m: &Calibration| projection_uncertainty(&m.intrinsics, &m.covariance, size).rms;
    let predicted = sigma_rms(&models[0]).hypot(sigma_rms(&models[1]));
    let ratio = rotated.map.rms / predicted.max(f64::MIN_POSITIVE);
    Ok(CrossValidation {
        frames: [models[0].frame_names.len(), models[1].frame_names.len()],
        max_px: map.max,
        rms_px: map.rms,
        map,
        rotated_max_px: rotated.map.max,
        rotated_rms_px: rotated.map.rms,
        rotation_deg: rotated.rotation_deg,
        predicted_rms_px: predicted,
        ratio,
        sigma_scaled_by: ratio.max(1.0),
    })
}

/// The items whose `keep` is true, in order (`items` may be shorter: frames without
/// neighbours have an empty list).
fn kept<T: Clone>(items: &[T], keep: &[bool]) -> Vec<T> {
    items
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(d, _)| d.clone())
        .collect()
}
