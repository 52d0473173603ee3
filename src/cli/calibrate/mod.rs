//! `pipemeasure calibrate --device NAME --frames DIR [--sfm MODEL] [--out PATH] [--report DIR]
//! [--force] [--cross-validate] [--network DIR] [--check-points CSV]`: the calibration loop on a
//! lab video's frames, written as a device profile; the adjusted network in the report (and as a
//! COLMAP model), and its object-space accuracy against check points.

use anyhow::{Context, Result};
use pipemeasure::calibrate::Calibration;
use pipemeasure::calibrate::check_points::{CheckPointReport, check_points};
use pipemeasure::calibrate::input::{frame_size, model_frames};
use pipemeasure::calibrate::network::colmap_network;
use pipemeasure::calibrate::pipeline::{CalibrateConfig, CalibrationInput, ReadoutStart};
use pipemeasure::calibrate::{DeviceConfig, calibrate_device};
use pipemeasure::io::atomic::StagedDir;
use pipemeasure::io::colmap::ModelFormat;
use pipemeasure::io::tls::TlsTarget;
use pipemeasure::profile::{CalibrationSource, Profile};
use pipemeasure::report::calibration::{CalibrationReport, write_calibration_report};
use pipemeasure::sim::truth::simulated_provenance;

mod args;
mod inputs;
mod outcome;

pub(crate) use args::{Args, RollingShutterMode};
use inputs::{frames_from_video, neighbour_detections, preflight, sfm_model};
use outcome::{Outcome, print_outcome};

use super::Globals;
use super::matching::detect_named_frames;

/// The loop's configuration from the options: the iteration cap and the rolling shutter
/// (off, or tried with a nominal or the given readout time).
fn calibrate_config(args: &Args) -> CalibrateConfig {
    CalibrateConfig {
        max_iterations: usize::from(args.max_iterations),
        rolling_shutter: match (args.rolling_shutter, args.readout_time) {
            (RollingShutterMode::Off, _) => None,
            (RollingShutterMode::Auto, None) => Some(ReadoutStart::default()),
            (RollingShutterMode::Auto, Some(ms)) => Some(ReadoutStart {
                readout_s: ms * 1e-3,
                hold: true,
            }),
        },
        ..CalibrateConfig::default()
    }
}

/// The adjusted targets against the check points, when given (`--check-points`).
fn check_point_report(
    args: &Args,
    check_list: Option<&[TlsTarget]>,
    cal: &Calibration,
) -> Result<Option<CheckPointReport>> {
    Ok(match (check_list, &args.check_points) {
        (Some(points), Some(path)) => {
            let list: Vec<(String, nalgebra::Point3<f64>)> =
                points.iter().map(|t| (t.id.clone(), t.position)).collect();
            Some(
                check_points(
                    &cal.points,
                    cal.point_covariance.as_deref(),
                    &list,
                    args.check_point_sigma,
                )
                .with_context(|| format!("check points {}", path.display()))?,
            )
        }
        _ => None,
    })
}

pub fn run(args: &Args, globals: Globals) -> Result<()> {
    let (check_list, out) = preflight(args)?;
    // The video's frames once every destination is known to be writable.
    let from_video;
    let args = match &args.video {
        Some(video) => {
            from_video = frames_from_video(args, video, globals.quiet)?;
            &from_video
        }
        None => args,
    };
    let model = sfm_model(args, globals.quiet)?;
    let names = model_frames(&model, args.frames())?;
    let size = frame_size(&model)?;
    let detections = detect_named_frames(
        args.frames(),
        &names,
        size,
        args.min_semi_minor,
        globals.quiet,
    )?;
    let neighbours = neighbour_detections(args, &names, size, globals.quiet)?;
    let config = calibrate_config(args);
    let quiet = globals.quiet;
    let log = move |m: &str| {
        if !quiet {
            eprintln!("{m}");
        }
    };
    let input = CalibrationInput {
        model: &model,
        detections: &detections,
        image_size: size,
        neighbours: &neighbours,
    };
    let device = calibrate_device(
        &input,
        &DeviceConfig {
            calibrate: config,
            cross_validate: args.cross_validate,
        },
        &log,
    )?;
    let cal = &device.calibration;
    let model_name = args.sfm.as_ref().map_or_else(
        || "colmap (run by pipemeasure)".to_string(),
        |p| p.display().to_string(),
    );
    let profile = Profile::from_device_calibration(
        &args.device,
        &device,
        size,
        &CalibrationSource {
            command: std::env::args().collect::<Vec<_>>().join(" "),
            frames: args.frames().to_path_buf(),
            sfm: model_name,
            simulated: simulated_provenance(args.frames()),
        },
    );
    let high = profile.high_correlations();
    let network = pipemeasure::calibrate::network::network(cal);
    let check_report = check_point_report(args, check_list.as_deref(), cal)?;
    let colmap = match &args.network {
        Some(_) => Some(
            colmap_network(cal, &profile.camera())
                .context("exporting the adjusted network as a COLMAP model")?,
        ),
        None => None,
    };
    // Every output is written beside its destination first; only when all are complete are
    // they moved into place, the profile last (a failure before leaves nothing new behind).
    let report_dir = args.report.as_deref().map(StagedDir::new).transpose()?;
    if let (Some(staged), Some(dir)) = (&report_dir, &args.report) {
        let report = CalibrationReport::new(
            &args.device,
            &profile,
            &device,
            &network,
            check_report.as_ref(),
        );
        write_calibration_report(staged.path(), cal, size, &report)
            .with_context(|| format!("writing the report {}", dir.display()))?;
    }
    let network_dir = match (&args.network, &colmap) {
        (Some(dir), Some(net)) => {
            let staged = StagedDir::new(dir)?;
            net.model
                .write(staged.path(), ModelFormat::Text)
                .with_context(|| format!("writing the network {}", dir.display()))?;
            Some(staged)
        }
        _ => None,
    };
    let staged_profile = profile
        .stage(&out, args.force)
        .with_context(|| format!("writing the profile {}", out.display()))?;
    for staged in [report_dir, network_dir].into_iter().flatten() {
        staged.commit()?;
    }
    let backup = staged_profile
        .commit()
        .with_context(|| format!("writing the profile {}", out.display()))?;
    print_outcome(&Outcome {
        args,
        device: &device,
        high: &high,
        check_report: check_report.as_ref(),
        colmap: colmap.as_ref(),
        out: &out,
        backup: backup.as_deref(),
    })
}
