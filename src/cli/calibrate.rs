//! `pipemeasure calibrate --device NAME --frames DIR [--sfm MODEL] [--out PATH] [--report DIR]
//! [--force] [--cross-validate] [--network DIR] [--check-points CSV]`: the calibration loop on a
//! lab video's frames, written as a device profile; the adjusted network in the report (and as a
//! COLMAP model), and its object-space accuracy against check points.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use pipemeasure::calibrate::Calibration;
use pipemeasure::calibrate::check_points::{CheckPointReport, check_points};
use pipemeasure::calibrate::input::{frame_size, listed_frames, model_frames, reconstruct_frames};
use pipemeasure::calibrate::neighbours::detect_neighbours;
use pipemeasure::calibrate::network::ColmapNetwork;
use pipemeasure::calibrate::network::colmap_network;
use pipemeasure::calibrate::pipeline::{
    CalibrateConfig, CalibrationInput, NeighbourDetections, ReadoutStart,
};
use pipemeasure::calibrate::{DeviceCalibration, DeviceConfig, calibrate_device};
use pipemeasure::detect::DetectConfig;
use pipemeasure::io::atomic::{StagedDir, check_writable_dir};
use pipemeasure::io::colmap::{ColmapOptions, ColmapProgress, ModelFormat, Reconstruction};
use pipemeasure::io::tls::TlsTarget;
use pipemeasure::profile::CalibrationSource;
use pipemeasure::profile::{CALIBRATIONS_DIR, Profile, backup_path, validate_device_name};
use pipemeasure::report::calibration::{
    CalibrationReport, intrinsics_table, write_calibration_report,
};
use pipemeasure::sim::truth::simulated_provenance;

use super::matching::detect_named_frames;
use super::{Globals, progress, usage, values};

/// Arguments of `calibrate`.
#[derive(Clone, Debug, clap::Args)]
pub struct Args {
    /// Device name (a name, not a path): the profile is written as `calibrations/NAME.json`
    /// unless `--out` says otherwise.
    #[arg(long)]
    device: String,
    /// Folder of the lab video's frames (image names in the SfM model are relative to it). With
    /// `--video`, where the chosen frames are written (default: `VIDEO_STEM_frames` beside the
    /// video; it must not hold frames already).
    #[arg(long, required_unless_present = "video")]
    frames: Option<PathBuf>,
    /// The lab video itself: decoded with ffmpeg; per second the frame that moves least and is
    /// sharpest is chosen and written with its two neighbours in the video and
    /// `frames.json` (which the rolling-shutter readout estimate uses).
    #[arg(long, conflicts_with = "sfm")]
    video: Option<PathBuf>,
    /// With `--video`: frames chosen per second (1 to 30; each the best of its 1/N s).
    #[arg(long, value_name = "N", requires = "video", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=30))]
    per_second: u32,
    /// With `--video`: plain extraction at this rate instead of the choice (`1fps` or `1`: the
    /// frame nearest every second, the paper's extraction).
    #[arg(long, value_name = "RATE", requires = "video", conflicts_with = "per_second",
          value_parser = values::frame_rate)]
    every_frame_at: Option<f64>,
    /// COLMAP sparse model of the frames (text or binary). Without it, COLMAP is run (CPU
    /// features, sequential matcher, mapper) into `--work`.
    #[arg(long)]
    sfm: Option<PathBuf>,
    /// COLMAP's work folder when `--sfm` is not given (default: `FRAMES/../colmap`).
    #[arg(long)]
    work: Option<PathBuf>,
    /// Without `--sfm`: the longest side (px) COLMAP extracts its features at (larger frames
    /// are downsized for it; the model only starts the calibration). COLMAP's own default is
    /// 3200.
    #[arg(long, value_name = "PX", default_value_t = ColmapOptions::default().max_image_size,
          value_parser = clap::value_parser!(u32).range(256..=16384))]
    colmap_image_size: u32,
    /// Where to write the profile (default `calibrations/DEVICE.json`).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace an existing profile (the old one is kept as a numbered backup, `PATH.1.bak`,
    /// `PATH.2.bak`, …).
    #[arg(long)]
    force: bool,
    /// Write plots (SVG), `report.json` and `report.md` into this folder.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Also calibrate on two disjoint halves of the frames (alternate frames) and report how
    /// much their projections differ over the image.
    #[arg(long)]
    cross_validate: bool,
    /// Smallest semi-minor axis of a target to use (px, at least 1).
    #[arg(long, default_value_t = pipemeasure::detect::MIN_SEMI_MINOR_TO_MEASURE_PX, value_parser = values::semi_minor_px)]
    min_semi_minor: f64,
    /// Cap on matching/adjustment iterations (at least 1). Simulated labs stop in 2–3; real
    /// videos' matches change by a few views at the gate for longer (BoofCV's hexagonal video:
    /// 7 iterations until the camera moved by less than a tenth of its σ).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u16).range(1..))]
    max_iterations: u16,
    /// Write the adjusted network as a COLMAP model (text) into this folder: the profile's
    /// camera, the images at their adjusted poses, the targets as points3D.
    #[arg(long)]
    network: Option<PathBuf>,
    /// Reference coordinates of the targets (`id,x,y,z` in metres, any frame; ids need not
    /// match): the object-space accuracy of the adjusted targets after a 7-parameter
    /// similarity, in the report and on stdout.
    #[arg(long)]
    check_points: Option<PathBuf>,
    /// σ per axis of the check points (m, 0 or more), for the predicted RMS.
    #[arg(long, default_value_t = 0.0, value_parser = values::non_negative)]
    check_point_sigma: f64,
    /// The rolling-shutter model (a motion per frame and the readout time): `auto` lets the
    /// term selection keep it when the frames show it (significant and lowering the BIC),
    /// `off` leaves it out (a global-shutter camera).
    #[arg(long, value_enum, default_value_t = RollingShutterMode::Auto)]
    rolling_shutter: RollingShutterMode,
    /// The readout time (ms), when known (a device's data sheet, an earlier calibration): held
    /// at this value. Without it the readout time is estimated from the frames' neighbours in
    /// the video listed in `FRAMES/frames.json`, or held at 25 ms when there are none (the
    /// camera is then still right: only readout × velocity shows in one frame).
    #[arg(long, value_name = "MS", value_parser = values::readout_ms)]
    readout_time: Option<f64>,
}

impl Args {
    /// The frames folder (given, or where `--video`'s frames were written).
    fn frames(&self) -> &Path {
        self.frames.as_deref().unwrap_or(Path::new("."))
    }
}

/// `--rolling-shutter` (of `calibrate` and of the main command).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum RollingShutterMode {
    /// Calibration: tried by the term selection, kept when significant. Site: modelled when
    /// the readout time is known (the profile's, or `--readout-time`).
    #[default]
    Auto,
    /// Left out.
    Off,
}

/// The SfM model: the given one, or COLMAP's.
fn sfm_model(args: &Args, quiet: bool) -> Result<Reconstruction> {
    if let Some(dir) = &args.sfm {
        return Reconstruction::read(dir).with_context(|| format!("--sfm {}", dir.display()));
    }
    let work = args.work.clone().unwrap_or_else(|| {
        args.frames()
            .parent()
            .unwrap_or_else(|| Path::new("."))
            .join("colmap")
    });
    if !pipemeasure::io::colmap::colmap_available() {
        bail!(
            "no --sfm model given and `colmap` is not on PATH: install COLMAP (Debian/Ubuntu: \
             `apt-get install colmap`) or pass the sparse model of the frames with --sfm DIR"
        );
    }
    if !quiet {
        eprintln!(
            "running COLMAP (features at up to {} px, sequential matching, mapping) into {}",
            args.colmap_image_size,
            work.display()
        );
    }
    // Only the frames (not a video's neighbours): their count is the registration's goal.
    let listed = listed_frames(args.frames())?.map(|l| l.len());
    let bar = progress::bar(0, "COLMAP", quiet);
    let report = |p: ColmapProgress| match p {
        ColmapProgress::Features { done, of } => {
            bar.set_message("COLMAP features");
            bar.set_length(of as u64);
            bar.set_position(done as u64);
        }
        ColmapProgress::Matching { done, of } => {
            bar.set_message("COLMAP matching");
            bar.set_length(of as u64);
            bar.set_position(done as u64);
        }
        ColmapProgress::Registered { images } => {
            bar.set_message("COLMAP images registered");
            if let Some(n) = listed {
                bar.set_length(n as u64);
            }
            bar.set_position(images as u64);
        }
        _ => {}
    };
    let options = ColmapOptions {
        max_image_size: args.colmap_image_size,
        ..ColmapOptions::default()
    };
    let model = reconstruct_frames(args.frames(), &work, &options, &report);
    bar.finish_and_clear();
    Ok(model?)
}

/// The detections in the frames' neighbours in the video, from `FRAMES/frames.json` when
/// there is one (empty otherwise, or with `--rolling-shutter off` or a held readout time,
/// which do not use them).
fn neighbour_detections(
    args: &Args,
    names: &[String],
    size: (u32, u32),
    quiet: bool,
) -> Result<Vec<Vec<NeighbourDetections>>> {
    if args.rolling_shutter == RollingShutterMode::Off || args.readout_time.is_some() {
        return Ok(Vec::new());
    }
    let config = DetectConfig {
        min_semi_minor_px: args.min_semi_minor,
        ..DetectConfig::default()
    };
    let progress = progress::bar(0, "detecting the neighbours", quiet);
    let detected = detect_neighbours(
        args.frames(),
        names,
        size,
        &config,
        &|n| progress.set_length(n as u64),
        &|| progress.inc(1),
    )
    .context("detecting the targets of the frames' neighbours")?;
    progress.finish_and_clear();
    Ok(detected)
}

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

/// What is checked before minutes of calibration: the device name, the frames or video, the
/// check points (read: a bad file fails first), and every destination writable. Returns the
/// check points and the profile's path.
fn preflight(args: &Args) -> Result<(Option<Vec<TlsTarget>>, PathBuf)> {
    validate_device_name(&args.device)
        .map_err(|e| usage(format!("--device: {}", super::hints::said(&e))))?;
    match &args.video {
        Some(video) if !video.is_file() => bail!("--video {}: no such file", video.display()),
        None if !args.frames().is_dir() => {
            bail!("--frames {}: not a folder", args.frames().display())
        }
        _ => {}
    }
    // Read the check points first: a bad file fails before minutes of calibration.
    let check_list = args
        .check_points
        .as_ref()
        .map(|p| pipemeasure::io::tls::read_targets(p))
        .transpose()?;
    if let (Some(c), Some(p)) = (&check_list, &args.check_points)
        && c.len() < 4
    {
        bail!(
            "{}: {} check point(s); a 7-parameter similarity needs at least 4",
            p.display(),
            c.len()
        );
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| Path::new(CALIBRATIONS_DIR).join(format!("{}.json", args.device)));
    if out.exists() && !args.force {
        bail!(
            "{} exists: pass --force to replace it (the old profile is kept as a numbered backup, \
             {}) or --out to write elsewhere",
            out.display(),
            backup_path(&out, 1).display()
        );
    }
    // Every destination before minutes of calibration: the profile's folder is created if
    // missing (calibrations/), the report's and the network's too.
    check_writable_dir(
        out.parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new(".")),
    )?;
    if out.is_dir() {
        bail!(
            "--out {}: is a folder, expected the profile's file name",
            out.display()
        );
    }
    for dir in [&args.report, &args.network].into_iter().flatten() {
        check_writable_dir(dir)?;
    }
    Ok((check_list, out))
}

/// What `calibrate` prints when it is done.
struct Outcome<'a> {
    args: &'a Args,
    device: &'a DeviceCalibration,
    high: &'a [(String, String, f64)],
    check_report: Option<&'a CheckPointReport>,
    colmap: Option<&'a ColmapNetwork>,
    out: &'a Path,
    backup: Option<&'a Path>,
}

/// Prints the calibration's summary: the fit, the intrinsics, the checks, the warnings and
/// where everything was written.
fn print_outcome(o: &Outcome<'_>) -> Result<()> {
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
    for w in &o.device.warnings {
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
    if let Some(b) = o.backup {
        outln!("the profile it replaces kept as {}", b.display());
    }
    if let Some(dir) = &o.args.report {
        outln!("report written to {}", dir.display());
    }
    Ok(())
}

/// `--video`: chooses and writes the frames with their neighbours, and returns the arguments
/// with `--frames` set to their folder.
fn frames_from_video(args: &Args, video: &Path, quiet: bool) -> Result<Args> {
    let dir = args
        .frames
        .clone()
        .unwrap_or_else(|| super::frames::default_dir(video));
    let rule = super::frames::rule(args.per_second, args.every_frame_at);
    super::frames::write_video_frames(video, &dir, rule, true, quiet)
        .with_context(|| "--video".to_string())?;
    Ok(Args {
        frames: Some(dir),
        video: None,
        ..args.clone()
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
    let profile = Profile::from_calibration(
        &args.device,
        cal,
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
