//! `pipemeasure calibrate --device NAME --frames DIR [--sfm MODEL] [--out PATH] [--report DIR]
//! [--force] [--cross-validate] [--network DIR] [--check-points CSV]`: the calibration loop on a
//! lab video's frames, written as a device profile; the adjusted network in the report (and as a
//! COLMAP model), and its object-space accuracy against check points.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nalgebra::Vector2;
use pipemeasure::adjust::correlation;
use pipemeasure::calibrate::check_points::{CheckPointReport, check_points};
use pipemeasure::calibrate::checks::{
    DistortionCheck, ImageMap, check_distortion, projection_difference,
    projection_difference_rotated, projection_uncertainty,
};
use pipemeasure::calibrate::neighbours::detect_neighbours;
use pipemeasure::calibrate::network::colmap_network;
use pipemeasure::calibrate::pipeline::{
    CalibrateConfig, Calibration, CalibrationInput, NeighbourDetections, ReadoutStart, calibrate,
};
use pipemeasure::camera::Term;
use pipemeasure::detect::DetectConfig;
use pipemeasure::geometry::conic::Ellipse;
use pipemeasure::geometry::pose::camera_centre;
use pipemeasure::io::atomic::write_bytes_atomic;
use pipemeasure::io::atomic::{StagedDir, check_writable_dir};
use pipemeasure::io::colmap::{
    ColmapOptions, ColmapProgress, ModelFormat, Reconstruction, run_colmap_sfm_with,
};
use pipemeasure::io::sidecar::FramesSidecar;
use pipemeasure::profile::{
    CALIBRATIONS_DIR, Correlation, ImageSize, PROFILE_SCHEMA, Profile, ReadoutTime, StdDev,
    backup_path, validate_device_name,
};
use pipemeasure::report::plots;
use serde::Serialize;

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
    // A video's neighbour frames (in FRAMES/neighbours/, listed in frames.json) are not
    // reconstructed: COLMAP reads the folder recursively, so it gets the frames' list.
    let sidecar = args.frames().join("frames.json");
    let list: Option<Vec<String>> = if sidecar.is_file() {
        Some(
            FramesSidecar::read(&sidecar)?
                .frames
                .into_iter()
                .map(|f| f.name)
                .collect(),
        )
    } else {
        None
    };
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
            if let Some(n) = list.as_ref().map(Vec::len) {
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
    let model = run_colmap_sfm_with(args.frames(), &work, list.as_deref(), &options, &report)
        .with_context(|| "COLMAP sparse reconstruction");
    bar.finish_and_clear();
    model
}

/// The frame size of the model's (single) camera, checked against every image.
fn image_size(model: &Reconstruction) -> Result<(u32, u32)> {
    let mut sizes = model.cameras.values().map(|c| (c.width, c.height));
    let Some(first) = sizes.next() else {
        bail!("the SfM model has no camera")
    };
    if let Some(other) = sizes.find(|s| *s != first) {
        bail!(
            "the SfM model has cameras of different sizes ({}x{} and {}x{}): calibrate one device \
             at one frame size",
            first.0,
            first.1,
            other.0,
            other.1
        );
    }
    Ok((
        u32::try_from(first.0).context("camera width")?,
        u32::try_from(first.1).context("camera height")?,
    ))
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

/// Every model image must be a file in the frames folder.
fn check_frames(model: &Reconstruction, frames: &Path) -> Result<Vec<String>> {
    let names: Vec<String> = model.images.values().map(|i| i.name.clone()).collect();
    let missing: Vec<&String> = names.iter().filter(|n| !frames.join(n).is_file()).collect();
    if !missing.is_empty() {
        bail!(
            "{} of the model's {} images are not in {} (first: {}): is --frames the folder the \
             model was built from?",
            missing.len(),
            names.len(),
            frames.display(),
            missing
                .iter()
                .take(3)
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(names)
}

#[derive(Serialize)]
struct CrossValidation {
    frames: [usize; 2],
    /// The halves' projections apart, as they are (px).
    max_px: f64,
    rms_px: f64,
    map: ImageMap,
    /// After compensating the rotation between the halves' models (mrcal): what the data can
    /// tell apart (px).
    rotated_max_px: f64,
    rotated_rms_px: f64,
    rotation_deg: f64,
    /// The RMS difference the halves' own σ predict, `sqrt(rms σ_a² + rms σ_b²)` (px).
    predicted_rms_px: f64,
    /// Observed over predicted; above 1 the σ are too small for these frames.
    ratio: f64,
    /// The factor the profile's σ (and covariance, squared) were multiplied by: the ratio when
    /// above 1, else 1.
    sigma_scaled_by: f64,
}

#[derive(Serialize)]
struct ReportJson<'a> {
    schema: &'static str,
    device: &'a str,
    profile: &'a Profile,
    selection: &'a [pipemeasure::calibrate::selection::SelectionStep],
    iterations: &'a [pipemeasure::calibrate::pipeline::LoopRecord],
    converged: bool,
    stop_reason: &'a str,
    /// The selection's alternation between two term sets and how the loop settled it.
    term_alternation: Option<&'a pipemeasure::calibrate::pipeline::TermAlternation>,
    /// Frames (by name) in the final adjustment; the others saw too few targets.
    adjusted_frames: Vec<&'a str>,
    redundancy: usize,
    feature_adjustment: Option<pipemeasure::adjust::AdjustSummary>,
    adjustment: pipemeasure::adjust::AdjustSummary,
    distortion_check: &'a DistortionCheck,
    projection_uncertainty: &'a ImageMap,
    cross_validation: Option<&'a CrossValidation>,
    high_correlations: Vec<(String, String, f64)>,
    warnings: &'a [String],
    observations: &'a [pipemeasure::calibrate::pipeline::CalibrationObservation],
    /// The adjusted targets and frames with their σ.
    network: &'a pipemeasure::calibrate::network::Network,
    /// The check points' comparison, when given.
    check_points: Option<&'a CheckPointReport>,
    /// The jackknife over the frames that checked (and widened) the covariance, when it ran.
    frame_jackknife: Option<&'a pipemeasure::calibrate::pipeline::JackknifeCheck>,
}

fn profile_of(args: &Args, cal: &Calibration, size: (u32, u32), model: &str) -> Profile {
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
    provenance.insert(
        "command".into(),
        serde_json::json!(std::env::args().collect::<Vec<_>>().join(" ")),
    );
    provenance.insert(
        "frames".into(),
        serde_json::json!(args.frames().display().to_string()),
    );
    provenance.insert("sfm".into(), serde_json::json!(model));
    provenance.insert("iterations".into(), serde_json::json!(cal.iterations.len()));
    provenance.insert("converged".into(), serde_json::json!(cal.converged()));
    if let Some(j) = &cal.frame_jackknife {
        // The σ above are the adjustment's times √variance_inflation (the frames' scatter).
        provenance.insert("frame_jackknife".into(), serde_json::json!(j));
    }
    // Frames from `pipemeasure simulate lab` carry their truth next to them: say so.
    let truth_path = args.frames().parent().map(|d| d.join("truth.json"));
    if let Some(truth) = truth_path
        .filter(|p| p.is_file())
        .and_then(|p| pipemeasure::sim::truth::Truth::read(&p).ok())
    {
        provenance.insert(
            "simulated".into(),
            serde_json::json!({
                "scene": truth.scene,
                "device_preset": truth.camera.device,
                "seed": truth.seed,
                "simulate_command": truth.command,
                "note": "calibrated from simulated frames, not a real phone: calibrate your own phone and replace this profile",
            }),
        );
    }
    Profile {
        schema: PROFILE_SCHEMA.into(),
        device: args.device.clone(),
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

fn high_correlations(profile: &Profile) -> Vec<(String, String, f64)> {
    let n = profile.correlation.names.len();
    let mut out = Vec::new();
    for i in 0..n {
        for j in 0..i {
            let r = profile.correlation.matrix[i][j];
            if r.abs() > 0.9 {
                out.push((
                    profile.correlation.names[j].name().to_string(),
                    profile.correlation.names[i].name().to_string(),
                    r,
                ));
            }
        }
    }
    out
}

fn calibrate_model(
    model: &Reconstruction,
    (detections, neighbours): (&[Vec<Ellipse>], &[Vec<NeighbourDetections>]),
    size: (u32, u32),
    config: &CalibrateConfig,
    log: &dyn Fn(&str),
) -> Result<Calibration> {
    let input = CalibrationInput {
        model,
        detections,
        image_size: size,
        neighbours,
    };
    Ok(calibrate(&input, config, log)?)
}

fn intrinsics_table(cal: &Calibration) -> String {
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

fn write_report(
    dir: &Path,
    cal: &Calibration,
    size: (u32, u32),
    report: &ReportJson<'_>,
) -> Result<()> {
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
fn check_points_markdown(c: &CheckPointReport) -> String {
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
    validate_device_name(&args.device).map_err(|e| usage(format!("--device: {e}")))?;
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
    let names = check_frames(&model, args.frames())?;
    let size = image_size(&model)?;
    let detections = detect_named_frames(
        args.frames(),
        &names,
        size,
        args.min_semi_minor,
        globals.quiet,
    )?;
    let neighbours = neighbour_detections(args, &names, size, globals.quiet)?;
    let config = CalibrateConfig {
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
    };
    let quiet = globals.quiet;
    let log = move |m: &str| {
        if !quiet {
            eprintln!("{m}");
        }
    };
    let cal = calibrate_model(&model, (&detections, &neighbours), size, &config, &log)?;
    let check = check_distortion(&cal.intrinsics, size);
    let mut warnings = cal.warnings.clone();
    if !check.ok {
        warnings.push(format!(
            "the distortion is not monotonic and invertible over the whole frame: it fails at {} \
             of the checked pixels, from {:.0} px from the principal point (the frame reaches \
             {:.0} px); do not use the profile near the image border",
            check.failing_pixels,
            check.first_failure_radius_px.unwrap_or(f64::NAN),
            check.frame_radius_px
        ));
    }
    let cross = if args.cross_validate {
        let halves: Vec<Vec<bool>> = (0..2)
            .map(|h| (0..names.len()).map(|k| k % 2 == h).collect())
            .collect();
        let mut models = Vec::new();
        for (h, keep) in halves.iter().enumerate() {
            let sub = model.with_images(keep);
            let det: Vec<Vec<Ellipse>> = detections
                .iter()
                .zip(keep)
                .filter(|(_, k)| **k)
                .map(|(d, _)| d.clone())
                .collect();
            let nb: Vec<Vec<NeighbourDetections>> = neighbours
                .iter()
                .zip(keep)
                .filter(|(_, k)| **k)
                .map(|(d, _)| d.clone())
                .collect();
            log(&format!(
                "cross-validation: half {} ({} frames)",
                h + 1,
                det.len()
            ));
            models.push(
                calibrate_model(&sub, (&det, &nb), size, &config, &log)
                    .with_context(|| format!("cross-validation half {}", h + 1))?,
            );
        }
        let map = projection_difference(&models[0].intrinsics, &models[1].intrinsics, size);
        let rotated =
            projection_difference_rotated(&models[0].intrinsics, &models[1].intrinsics, size);
        let sigma_rms =
            |m: &Calibration| projection_uncertainty(&m.intrinsics, &m.covariance, size).rms;
        let predicted = sigma_rms(&models[0]).hypot(sigma_rms(&models[1]));
        let ratio = rotated.map.rms / predicted.max(f64::MIN_POSITIVE);
        Some(CrossValidation {
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
    } else {
        None
    };
    // Where the halves disagree by more than their σ say, the σ are too small for these frames
    // (correlated detection errors, unmodelled effects): the reported σ follow the data.
    let mut cal = cal;
    if let Some(cv) = &cross
        && cv.sigma_scaled_by > 1.0
    {
        let k = cv.sigma_scaled_by;
        for s in &mut cal.std_dev {
            *s *= k;
        }
        cal.covariance *= k * k;
        warnings.push(format!(
            "cross-validation: the halves' projections differ by {:.3} px RMS after the rotation between them, {k:.2} times what their σ predict ({:.3} px); the profile's σ are multiplied by {k:.2}",
            cv.rotated_rms_px, cv.predicted_rms_px
        ));
    }
    let uncertainty = projection_uncertainty(&cal.intrinsics, &cal.covariance, size);
    let model_name = args.sfm.as_ref().map_or_else(
        || "colmap (run by pipemeasure)".to_string(),
        |p| p.display().to_string(),
    );
    let profile = profile_of(args, &cal, size, &model_name);
    let high = high_correlations(&profile);
    let network = pipemeasure::calibrate::network::network(&cal);
    let check_report = match (&check_list, &args.check_points) {
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
    };
    let colmap = match &args.network {
        Some(_) => Some(
            colmap_network(&cal, &profile.camera())
                .context("exporting the adjusted network as a COLMAP model")?,
        ),
        None => None,
    };
    // Every output is written beside its destination first; only when all are complete are
    // they moved into place, the profile last (a failure before leaves nothing new behind).
    let report_dir = args.report.as_deref().map(StagedDir::new).transpose()?;
    if let (Some(staged), Some(dir)) = (&report_dir, &args.report) {
        let stop_reason = cal.stop_reason();
        let report = ReportJson {
            schema: "pipemeasure.calibration-report/1",
            device: &args.device,
            profile: &profile,
            selection: &cal.selection,
            iterations: &cal.iterations,
            converged: cal.converged(),
            stop_reason: &stop_reason,
            term_alternation: cal.term_alternation.as_ref(),
            adjusted_frames: cal
                .adjusted_frames
                .iter()
                .map(|&k| cal.frame_names[k].as_str())
                .collect(),
            redundancy: cal.redundancy,
            feature_adjustment: cal.feature_adjustment,
            adjustment: cal.summary,
            distortion_check: &check,
            projection_uncertainty: &uncertainty,
            cross_validation: cross.as_ref(),
            high_correlations: high.clone(),
            warnings: &warnings,
            observations: &cal.observations,
            network: &network,
            check_points: check_report.as_ref(),
            frame_jackknife: cal.frame_jackknife.as_ref(),
        };
        write_report(staged.path(), &cal, size, &report)
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
    outln!(
        "calibrated {} from {} frames: {} targets, {} observations, σ0 {:.4} px, residual RMS {:.4} px",
        args.device,
        cal.frame_names.len(),
        cal.points.len(),
        cal.observations.len(),
        cal.sigma0,
        cal.residual_rms_px
    );
    out!("{}", intrinsics_table(&cal));
    for (a, b, r) in &high {
        outln!("correlation {a}/{b} = {r:.3} (above 0.9)");
    }
    outln!(
        "projection uncertainty of a ray: worst {:.4} px, RMS {:.4} px over the frame",
        uncertainty.max,
        uncertainty.rms
    );
    if let Some(cv) = &cross {
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
    for w in &warnings {
        outln!("WARNING: {w}");
    }
    if let Some(c) = &check_report {
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
    if let (Some(dir), Some(net)) = (&args.network, &colmap) {
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
    outln!("profile written to {}", out.display());
    if let Some(b) = backup {
        outln!("the profile it replaces kept as {}", b.display());
    }
    if let Some(dir) = &args.report {
        outln!("report written to {}", dir.display());
    }
    Ok(())
}
