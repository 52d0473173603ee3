//! The video calibration table: the calibration lab of each device preset filmed as a
//! hand-held video (rolling shutter at the preset's readout time, motion blur, tremor; each
//! extracted frame's neighbours at ±1/fps), calibrated twice from the same rendered frames and
//! the same SfM stand-in's model,
//!
//! * **rolling shutter**: the selection free to keep a motion per frame, the readout time
//!   estimated from the neighbours (what `pipemeasure calibrate` does on such a folder);
//! * **global shutter**: the same frames with the rolling-shutter model left out
//!   (`--rolling-shutter off`),
//!
//! each scored against the simulator's true camera over the whole frame (as it is and after
//! the best rotation between the two cameras), against the projection σ the calibration
//! reports, and for the readout time against its true value.
//!
//! The lab is what `pipemeasure simulate lab --video --neighbours` writes, read back from its
//! folder as a user's data would be; the targets are found by our detector in the rendered
//! frames.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::calibrate::checks::{
    projection_difference, projection_difference_rotated, projection_uncertainty,
};
use crate::calibrate::neighbours::detect_neighbours;
use crate::calibrate::pipeline::{CalibrateConfig, Calibration, CalibrationInput, ReadoutStart};
use crate::calibrate::{DeviceConfig, calibrate_device};
use crate::detect::{DetectConfig, detect_frame_files};
use crate::io::colmap::Reconstruction;
use crate::sim::truth::Truth;

use super::PresetRuns;

/// The camera model a video lab was calibrated with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum ShutterModel {
    /// A motion per frame and the readout time (estimated from the neighbours), when the
    /// selection keeps them.
    RollingShutter,
    /// The rolling-shutter model left out.
    GlobalShutter,
}

impl ShutterModel {
    /// The table's name for it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            ShutterModel::RollingShutter => "rolling shutter",
            ShutterModel::GlobalShutter => "global shutter",
        }
    }
}

/// One calibration of a video lab, scored against the truth.
#[derive(Clone, Debug, Serialize)]
pub struct VideoLabRow {
    /// The model asked for.
    pub model: ShutterModel,
    /// The selected terms (the rolling-shutter motions as `motion` when kept).
    pub terms: Vec<String>,
    /// A-posteriori σ0 (px).
    pub sigma0_px: f64,
    /// Targets in the final adjustment.
    pub targets: usize,
    /// The camera against the truth over the frame: largest difference (px).
    pub camera_max_px: f64,
    /// Its RMS over the frame (px).
    pub camera_rms_px: f64,
    /// The largest difference after the best rotation between the two cameras (px).
    pub rotated_max_px: f64,
    /// The largest ratio of the difference to the reported projection σ over the frame.
    pub error_over_sigma_max: f64,
    /// The readout time (s) and its σ, when the rolling shutter was kept.
    pub readout_s: Option<(f64, f64)>,
    /// Whether the loop converged.
    pub converged: bool,
    /// Seconds for detection of the neighbours and the calibration.
    pub seconds: f64,
}

/// A preset's video lab and its two calibrations.
#[derive(Clone, Debug, Serialize)]
pub struct VideoLabResult {
    /// Device preset.
    pub device: String,
    /// Frame size.
    pub image_size: (u32, u32),
    /// Registered frames of the model.
    pub frames: usize,
    /// The true readout time (s).
    pub true_readout_s: f64,
    /// Rolling shutter first, then global shutter.
    pub rows: Vec<VideoLabRow>,
}

/// The calibration table's labs: 90 frames of 1920×1080 of each device preset's lab.
#[must_use]
pub fn video_lab_runs() -> PresetRuns {
    PresetRuns::every_preset(1920, 90)
}

/// Calibrates the video lab in `lab_dir` (`simulate lab --video --neighbours`'s folder) with
/// both models and scores each against its truth.
///
/// # Errors
///
/// A message naming the file or the step that failed.
pub fn run_video_lab(lab_dir: &Path, log: &dyn Fn(&str)) -> Result<VideoLabResult, String> {
    let truth = Truth::read(&lab_dir.join("truth.json")).map_err(|e| e.to_string())?;
    let true_readout_s = truth
        .video
        .as_ref()
        .map(|v| v.readout_s)
        .ok_or_else(|| format!("{}: not a video lab (no video truth)", lab_dir.display()))?;
    let model = Reconstruction::read(&lab_dir.join("sparse")).map_err(|e| e.to_string())?;
    let size = (truth.camera.width, truth.camera.height);
    let frames_dir = lab_dir.join("frames");
    let names: Vec<String> = model.images.values().map(|i| i.name.clone()).collect();
    let paths: Vec<PathBuf> = names.iter().map(|n| frames_dir.join(n)).collect();
    let detect = DetectConfig {
        min_semi_minor_px: crate::detect::MIN_SEMI_MINOR_TO_MEASURE_PX,
        ..DetectConfig::default()
    };
    log(&format!("detecting targets in {} frames", paths.len()));
    let detections =
        detect_frame_files(&paths, size, &detect, &|| {}).map_err(|e| e.to_string())?;
    let mut rows = Vec::new();
    for model_kind in [ShutterModel::RollingShutter, ShutterModel::GlobalShutter] {
        let start = std::time::Instant::now();
        let rolling = model_kind == ShutterModel::RollingShutter;
        let neighbours = if rolling {
            detect_neighbours(&frames_dir, &names, size, &detect, &|_| {}, &|| {})
                .map_err(|e| e.to_string())?
        } else {
            Vec::new()
        };
        log(&format!(
            "calibrating with the {} model ({} frames with neighbours)",
            model_kind.name(),
            neighbours.iter().filter(|n| !n.is_empty()).count()
        ));
        let config = CalibrateConfig {
            rolling_shutter: rolling.then(ReadoutStart::default),
            ..CalibrateConfig::default()
        };
        let input = CalibrationInput {
            model: &model,
            detections: &detections,
            image_size: size,
            neighbours: &neighbours,
        };
        let config = DeviceConfig {
            calibrate: config,
            cross_validate: false,
        };
        let cal = calibrate_device(&input, &config, &|m| log(&format!("  {m}")))
            .map_err(|e| e.to_string())?
            .calibration;
        rows.push(score(
            model_kind,
            &cal,
            &truth,
            start.elapsed().as_secs_f64(),
        ));
    }
    Ok(VideoLabResult {
        device: truth.camera.device.clone(),
        image_size: size,
        frames: model.images.len(),
        true_readout_s,
        rows,
    })
}

/// A calibration against the truth's camera over the frame.
fn score(model: ShutterModel, cal: &Calibration, truth: &Truth, seconds: f64) -> VideoLabRow {
    let size = (truth.camera.width, truth.camera.height);
    let tru = &truth.camera.intrinsics;
    let diff = projection_difference(&cal.intrinsics, tru, size);
    let rotated = projection_difference_rotated(&cal.intrinsics, tru, size);
    let sigma = projection_uncertainty(&cal.intrinsics, &cal.covariance, size);
    let error_over_sigma_max = diff.max_ratio_to(&sigma);
    let mut terms: Vec<String> = cal.terms.iter().map(|t| t.name().to_string()).collect();
    if cal.rolling_shutter.is_some() {
        terms.push("motion".into());
    }
    VideoLabRow {
        model,
        terms,
        sigma0_px: cal.sigma0,
        targets: cal.points.len(),
        camera_max_px: diff.max,
        camera_rms_px: diff.rms,
        rotated_max_px: rotated.map.max,
        error_over_sigma_max,
        readout_s: cal
            .rolling_shutter
            .as_ref()
            .map(|r| (r.readout_s, r.readout_std_s)),
        converged: cal.converged(),
        seconds,
    }
}

/// Simulates a video lab per device into `out/lab_<device>` (`simulate lab --video
/// --neighbours` with the options' size, frames and seed) and runs [`run_video_lab`] on it.
///
/// # Errors
///
/// A message naming the device and the step that failed.
pub fn video_labs(
    options: &PresetRuns,
    out: &Path,
    command: &str,
    log: &dyn Fn(&str),
) -> Result<Vec<VideoLabResult>, String> {
    use crate::sim::lab::LabConfig;
    use crate::sim::simulate::{SimulateOptions, simulate_lab};
    use crate::sim::video::VideoConfig;
    let mut results = Vec::new();
    for device in &options.devices {
        let sim = SimulateOptions {
            video: Some(VideoConfig {
                neighbours: true,
                ..VideoConfig::default()
            }),
            ..options.simulate_options(device, command)
        };
        let lab = LabConfig {
            frames: options.frames,
            ..LabConfig::default()
        };
        let dir = out.join(format!("lab_{device}"));
        log(&format!(
            "{device}: simulating the lab video into {}",
            dir.display()
        ));
        simulate_lab(&sim, &lab, &dir, &|_| {}).map_err(|e| format!("{device}: {e}"))?;
        let result = run_video_lab(&dir, &|m| log(&format!("  {m}")))
            .map_err(|e| format!("{device}: {e}"))?;
        results.push(result);
    }
    Ok(results)
}

/// The calibration table as Markdown.
#[must_use]
pub fn video_labs_markdown(results: &[VideoLabResult]) -> String {
    let mut md = String::from(
        "| device | model | selected | σ0 (px) | camera vs truth, max (RMS) px | after rotation, max px | error / reported σ, max | readout (ms) | true readout (ms) |\n|---|---|---|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in results {
        for row in &r.rows {
            let readout = row.readout_s.map_or("—".into(), |(t, s)| {
                format!(
                    "{:.2} ± {:.2} ({:+.1} %)",
                    1e3 * t,
                    1e3 * s,
                    100.0 * (t - r.true_readout_s) / r.true_readout_s
                )
            });
            md.push_str(&format!(
                "| {} | {} | {} | {:.4} | {:.3} ({:.3}) | {:.3} | {:.2} | {} | {:.0} |\n",
                r.device,
                row.model.name(),
                row.terms.join(" "),
                row.sigma0_px,
                row.camera_max_px,
                row.camera_rms_px,
                row.rotated_max_px,
                row.error_over_sigma_max,
                readout,
                1e3 * r.true_readout_s
            ));
        }
    }
    md.push('\n');
    for r in results {
        md.push_str(&format!(
            "{}: {} frames of {}x{}; calibration {:.0} s (rolling shutter, neighbours' detection included) and {:.0} s (global shutter).\n",
            r.device,
            r.frames,
            r.image_size.0,
            r.image_size.1,
            r.rows.first().map_or(0.0, |x| x.seconds),
            r.rows.get(1).map_or(0.0, |x| x.seconds)
        ));
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(model: ShutterModel, readout: Option<(f64, f64)>) -> VideoLabRow {
        VideoLabRow {
            model,
            terms: vec!["c".into(), "k1".into()],
            sigma0_px: 0.0123,
            targets: 100,
            camera_max_px: 0.0749,
            camera_rms_px: 0.032,
            rotated_max_px: 0.072,
            error_over_sigma_max: 0.71,
            readout_s: readout,
            converged: true,
            seconds: 18.0,
        }
    }

    /// The readout's relative error is against the true readout time, the global-shutter row
    /// has none.
    #[test]
    fn the_table_gives_the_readout_error_against_the_truth() {
        let r = VideoLabResult {
            device: "p30".into(),
            image_size: (960, 540),
            frames: 40,
            true_readout_s: 0.020,
            rows: vec![
                row(ShutterModel::RollingShutter, Some((0.019352, 0.000186))),
                row(ShutterModel::GlobalShutter, None),
            ],
        };
        let md = video_labs_markdown(&[r]);
        assert!(
            md.contains("| p30 | rolling shutter | c k1 | 0.0123 | 0.075 (0.032) | 0.072 | 0.71 | 19.35 ± 0.19 (-3.2 %) | 20 |"),
            "{md}"
        );
        assert!(
            md.contains(
                "| p30 | global shutter | c k1 | 0.0123 | 0.075 (0.032) | 0.072 | 0.71 | — | 20 |"
            ),
            "{md}"
        );
    }
}
