//! The profile of a finished calibration: its terms, σ, correlations, statistics and provenance.

use std::collections::BTreeMap;

use super::{Correlation, ImageSize, PROFILE_SCHEMA, Profile, ReadoutTime, StdDev};
use crate::adjust::correlation;
use crate::calibrate::Calibration;
use crate::camera::Term;

/// Where a calibration came from, recorded in its profile's provenance.
#[derive(Clone, Debug, Default)]
pub struct CalibrationSource {
    /// The command line that made it.
    pub command: String,
    /// The frames' folder.
    pub frames: std::path::PathBuf,
    /// The SfM model (its path, or how it was made).
    pub sfm: String,
    /// A note when the frames are simulated ([`crate::sim::truth::simulated_provenance`]).
    pub simulated: Option<serde_json::Value>,
}

/// The provenance key of the jackknife over the frames ([`Profile::jackknife`]).
const JACKKNIFE_KEY: &str = "frame_jackknife";
/// The provenance key of the highest order of the frames' motions ([`Profile::motion_order`]).
const MOTION_ORDER_KEY: &str = "motion_order";
/// The provenance key of the cross-validation of two halves ([`Profile::cross_validation`]).
const CROSS_VALIDATION_KEY: &str = "cross_validation";

/// The jackknife over the frames as a profile records it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordedJackknife {
    /// Groups of frames left out in turn.
    pub groups: f64,
    /// The factor the covariance was multiplied by (the frames' scatter over the
    /// adjustment's prediction).
    pub variance_inflation: f64,
}

/// The cross-validation of two halves as a profile records it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordedCrossValidation {
    /// RMS distance between the halves' projections, after the rotation between them (px).
    pub rms_px: f64,
    /// That against what the halves' σ predict.
    pub ratio: f64,
}

/// Correlations of two estimated terms above this magnitude are flagged: the two trade
/// against each other and the frames do not tell them apart well (a common rule of thumb in
/// self-calibration; the paper's term selection tests significance, not correlation).
pub const HIGH_CORRELATION: f64 = 0.9;

impl Profile {
    /// The profile of a finished calibration: its estimated terms with their σ and
    /// correlations, the fit's statistics, the readout time when it is the device's (estimated
    /// or given; a nominal one held for frames without neighbours is left out), and the
    /// provenance (`source`; the loop's iterations, convergence and jackknife check).
    #[must_use]
    pub fn from_calibration(
        device: &str,
        cal: &Calibration,
        size: (u32, u32),
        source: &CalibrationSource,
    ) -> Profile {
        let mut std_dev = StdDev::default();
        for t in Term::ALL {
            std_dev.set(t, cal.std_dev[t.index()]);
        }
        let idx: Vec<usize> = cal.terms.iter().map(|t| t.index()).collect();
        let all = correlation(&cal.covariance);
        let matrix = idx
            .iter()
            .map(|&i| idx.iter().map(|&j| all[(i, j)]).collect())
            .collect();
        let mut provenance = BTreeMap::new();
        provenance.insert(
            "tool".into(),
            serde_json::json!(format!("pipemeasure {}", env!("CARGO_PKG_VERSION"))),
        );
        provenance.insert("source".into(), serde_json::json!("calibrate"));
        provenance.insert("command".into(), serde_json::json!(source.command));
        provenance.insert(
            "frames".into(),
            serde_json::json!(source.frames.display().to_string()),
        );
        provenance.insert("sfm".into(), serde_json::json!(source.sfm));
        provenance.insert("iterations".into(), serde_json::json!(cal.iterations.len()));
        provenance.insert("converged".into(), serde_json::json!(cal.converged()));
        if let Some(j) = &cal.frame_jackknife {
            // The σ above are the adjustment's times √variance_inflation (the frames' scatter).
            provenance.insert(JACKKNIFE_KEY.into(), serde_json::json!(j));
        }
        if let Some(r) = cal.rolling_shutter.as_ref().filter(|r| r.determined) {
            // The highest order any frame's motion was adjusted to (fourth over a frame's
            // video neighbours when the selection kept the snaps, first without neighbours).
            let order = r
                .motions
                .iter()
                .map(|m| m.order().number())
                .max()
                .unwrap_or(1);
            provenance.insert(MOTION_ORDER_KEY.into(), serde_json::json!(order));
        }
        if let Some(note) = &source.simulated {
            provenance.insert("simulated".into(), note.clone());
        }
        Profile {
            schema: PROFILE_SCHEMA.into(),
            device: device.to_string(),
            image: ImageSize {
                width: size.0,
                height: size.1,
            },
            model: "brown".into(),
            terms: cal.terms.clone(),
            intrinsics: cal.intrinsics,
            std_dev,
            correlation: Correlation {
                names: cal.terms.clone(),
                matrix,
            },
            residual_rms_px: Some(cal.residual_rms_px),
            sigma0: Some(cal.sigma0),
            images: cal.frame_names.len(),
            targets: cal.points.len(),
            observations: cal.observations.len(),
            // A readout time held at the nominal value (frames without neighbours) is no property
            // of the device: left out, so a measurement does not take it for one.
            rolling_shutter: cal
                .rolling_shutter
                .as_ref()
                .filter(|r| r.determined)
                .map(|r| ReadoutTime {
                    readout_s: r.readout_s,
                    readout_std_s: r.readout_std_s,
                    estimated: r.estimated,
                }),
            provenance,
        }
    }

    /// The profile of a device's calibration ([`crate::calibrate::calibrate_device`]): as
    /// [`Profile::from_calibration`], with the cross-validation recorded when it ran.
    #[must_use]
    pub fn from_device_calibration(
        device: &str,
        dc: &crate::calibrate::DeviceCalibration,
        size: (u32, u32),
        source: &CalibrationSource,
    ) -> Profile {
        let mut profile = Profile::from_calibration(device, &dc.calibration, size, source);
        if let Some(cv) = &dc.cross_validation {
            profile.record_cross_validation(cv);
        }
        profile
    }

    /// Records the cross-validation of the calibration (`calibrate --cross-validate`) in the
    /// provenance: the halves' frames, how far their projections differ (RMS and worst, px,
    /// after the rotation between them) and that against what their σ predict.
    pub fn record_cross_validation(&mut self, cv: &crate::calibrate::CrossValidation) {
        self.provenance.insert(
            CROSS_VALIDATION_KEY.into(),
            serde_json::json!({
                "frames": cv.frames,
                "rms_px": cv.rotated_rms_px,
                "max_px": cv.rotated_max_px,
                "predicted_rms_px": cv.predicted_rms_px,
                "ratio": cv.ratio,
            }),
        );
    }

    /// Pairs of estimated terms whose correlation exceeds [`HIGH_CORRELATION`] in magnitude:
    /// `(first, second, r)` in the order of [`Profile::correlation`].
    #[must_use]
    pub fn high_correlations(&self) -> Vec<(String, String, f64)> {
        let n = self.correlation.names.len();
        let mut out = Vec::new();
        for i in 0..n {
            for j in 0..i {
                let r = self.correlation.matrix[i][j];
                if r.abs() > HIGH_CORRELATION {
                    out.push((
                        self.correlation.names[j].name().to_string(),
                        self.correlation.names[i].name().to_string(),
                        r,
                    ));
                }
            }
        }
        out
    }

    /// The highest order of the frames' motions the calibration adjusted, when it kept a
    /// rolling shutter.
    #[must_use]
    pub fn motion_order(&self) -> Option<u64> {
        self.provenance
            .get(MOTION_ORDER_KEY)
            .and_then(serde_json::Value::as_u64)
    }

    /// The jackknife over the frames, when the calibration ran it.
    #[must_use]
    pub fn jackknife(&self) -> Option<RecordedJackknife> {
        let j = self.provenance.get(JACKKNIFE_KEY)?;
        Some(RecordedJackknife {
            groups: number(j, "groups")?,
            variance_inflation: number(j, "variance_inflation")?,
        })
    }

    /// The cross-validation of two halves, when the calibration ran it.
    #[must_use]
    pub fn cross_validation(&self) -> Option<RecordedCrossValidation> {
        let c = self.provenance.get(CROSS_VALIDATION_KEY)?;
        Some(RecordedCrossValidation {
            rms_px: number(c, "rms_px")?,
            ratio: number(c, "ratio")?,
        })
    }
}

/// The number at `key` of a JSON object.
fn number(v: &serde_json::Value, key: &str) -> Option<f64> {
    v.get(key).and_then(serde_json::Value::as_f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::CrossValidation;
    use crate::calibrate::checks::ImageMap;
    use crate::calibrate::pipeline::JackknifeCheck;

    /// What a calibration writes into the provenance (the jackknife's record, the
    /// cross-validation's, the motion order) is what `profile show` reads back, through the
    /// JSON file.
    #[test]
    fn the_recorded_checks_read_back_after_a_round_trip() {
        let cam = crate::camera::BrownCamera {
            width: 640,
            height: 480,
            intrinsics: crate::camera::Intrinsics::pinhole(500.0, 320.0, 240.0),
        };
        let mut p = Profile::uncalibrated("t", &cam, BTreeMap::new());
        assert_eq!(
            (p.jackknife(), p.cross_validation(), p.motion_order()),
            (None, None, None)
        );
        let j = JackknifeCheck {
            groups: 10,
            variance_inflation: 1.44,
            readout_std_s: 0.0,
        };
        p.provenance
            .insert(JACKKNIFE_KEY.into(), serde_json::json!(j));
        p.provenance
            .insert(MOTION_ORDER_KEY.into(), serde_json::json!(4));
        let map = ImageMap {
            cols: 1,
            rows: 1,
            values: vec![vec![0.0]],
            max: 0.0,
            rms: 0.0,
        };
        p.record_cross_validation(&CrossValidation {
            frames: [12, 13],
            max_px: 0.9,
            rms_px: 0.4,
            map,
            rotated_max_px: 0.2,
            rotated_rms_px: 0.08,
            rotation_deg: 0.01,
            predicted_rms_px: 0.05,
            ratio: 1.6,
            sigma_scaled_by: 1.6,
        });
        let back = Profile::from_json(&p.to_json(), std::path::Path::new("t.json")).unwrap();
        assert_eq!(
            back.jackknife(),
            Some(RecordedJackknife {
                groups: 10.0,
                variance_inflation: 1.44
            })
        );
        // The rotation-compensated difference is what the data can tell apart.
        assert_eq!(
            back.cross_validation(),
            Some(RecordedCrossValidation {
                rms_px: 0.08,
                ratio: 1.6
            })
        );
        assert_eq!(back.motion_order(), Some(4));
    }
}
