//! The paper's Table III on the simulator: the pipe of interest measured from one site survey
//! reconstructed twice,
//!
//! * **pre-calibration**: the SfM poses adjusted on the feature tracks with the intrinsics held
//!   at the device profile (`pipemeasure calibrate`'s output);
//! * **in situ**: poses and c, k1, k2 adjusted on the same tracks from the SfM model's EXIF-like
//!   initial camera (COLMAP's RADIAL self-calibration; the principal point stays at the image
//!   centre, as COLMAP leaves it by default);
//!
//! then for each, the site's targets matched and corrected (Algorithms 1–3) with that camera,
//! the scale from them against the TLS targets, the dense observations triangulated with that
//! camera and those poses (the dense cloud), and the pipe fitted near its true position. The
//! accuracy is against the simulator's true radius and against the TLS scan's fit (the paper's
//! reference).
//!
//! The site is what `pipemeasure simulate site` writes (rendered frames, the SfM stand-in's
//! sparse model, dense observations, TLS scan and target list), read back from its folder as a
//! user's data would be.
//!
//! The video variant (`experiments --only video`) films each site as a hand-held
//! video (rolling shutter at the preset's readout time, motion blur) and adds a third row:
//! pre-calibration with each row's pose (a motion per frame adjusted with the poses, the
//! readout time given, the targets and the cloud triangulated at their rows' poses, as the main
//! command does with `--readout-time`).

use std::path::Path;

use nalgebra::{Point3, Vector3};
use serde::Serialize;

use crate::adjust::{AdjustConfig, Similarity};
use crate::calibrate::matching::MatchConfig;
use crate::calibrate::pipeline::{adjust_feature_tracks, refresh_pairs};
use crate::calibrate::poses::{consistent_poses, consistent_poses_rolling};
use crate::calibrate::refine::{RefineConfig, algorithm1};
use crate::calibrate::views::FrameCamera;
use crate::camera::rolling::RowTiming;
use crate::camera::{BrownCamera, Intrinsics, Term};
use crate::detect::{DetectConfig, detect_frame_files};
use crate::geometry::conic::Ellipse;
use crate::io::colmap::Reconstruction;
use crate::io::observations::DenseObservations;
use crate::measure::site::row_targets;
use crate::measure::{
    CylinderConfig, Region, ScaleConfig, Scaling, estimate_scale, fit_points, match_site_targets,
    measure_pipe, transformed_points,
};
use crate::sim::dense::fuse_with;
use crate::sim::truth::Truth;

use super::PresetRuns;

/// How the site's camera was obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Method {
    /// Intrinsics fixed to the device profile.
    PreCalibration,
    /// The same with a rolling-shutter motion per frame and each row's pose.
    PreCalibrationRowPoses,
    /// c, k1, k2 self-calibrated on the site.
    InSitu,
}

impl Method {
    /// The name in the tables.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Method::PreCalibration => "pre-calibration",
            Method::PreCalibrationRowPoses => "pre-calibration, rows' poses",
            Method::InSitu => "in situ (radial)",
        }
    }
}

/// One row of the table.
#[derive(Clone, Debug, Serialize)]
pub struct PipeRow {
    /// Method.
    pub method: Method,
    /// The intrinsics used for the site.
    pub intrinsics: Intrinsics,
    /// RMS of the feature adjustment's residuals (px).
    pub feature_rms_px: f64,
    /// Targets matched.
    pub targets: usize,
    /// Targets associated with the TLS list.
    pub associated: usize,
    /// Scale used (similarity) and its σ.
    pub scale: f64,
    /// Scale σ.
    pub scale_std: f64,
    /// The scale's relative error against the SfM stand-in's true scale.
    pub scale_error: f64,
    /// Measured radius (m).
    pub radius_m: f64,
    /// Its σ (fit and scale).
    pub radius_std_m: f64,
    /// RMSE of the fit (m).
    pub rmse_m: f64,
    /// Inliers.
    pub inliers: usize,
    /// Measured minus true radius (m).
    pub accuracy_m: f64,
    /// Measured minus the TLS fit's radius (m): the paper's accuracy.
    pub tls_accuracy_m: f64,
}

impl PipeRow {
    /// The row's measurement as Markdown cells: radius ± σ, accuracy vs truth and vs the TLS
    /// fit, RMSE (mm) and inliers.
    #[must_use]
    pub fn markdown_cells(&self) -> String {
        format!(
            "{:.2} ± {:.2} | {:+.2} | {:+.2} | {:.2} | {}",
            self.radius_m * 1e3,
            self.radius_std_m * 1e3,
            self.accuracy_m * 1e3,
            self.tls_accuracy_m * 1e3,
            self.rmse_m * 1e3,
            self.inliers
        )
    }
}

/// The outcome for one site.
#[derive(Clone, Debug, Serialize)]
pub struct SiteResult {
    /// Device preset.
    pub device: String,
    /// True radius of the pipe of interest (m).
    pub truth_radius_m: f64,
    /// The TLS scan's fit of it (m).
    pub tls_radius_m: f64,
    /// Frames.
    pub frames: usize,
    /// Frame size.
    pub image_size: (u32, u32),
    /// Pre-calibration, then in situ.
    pub rows: Vec<PipeRow>,
}

/// Half-size of the region of interest around the true axis point (m).
const REGION_M: f64 = 0.4;

/// Runs both methods on the simulated site in `site_dir` with the device profile's
/// intrinsics `profile` (at any frame size of the same aspect).
///
/// # Errors
///
/// A message naming the step that failed.
///
/// Kept whole (one function over 150 lines): an experiment script whose steps (the site read,
/// both methods, the row) read top to bottom, each used once.
pub fn run_site(
    site_dir: &Path,
    profile: &BrownCamera,
    log: &dyn Fn(&str),
) -> Result<SiteResult, String> {
    let truth = Truth::read(&site_dir.join("truth.json")).map_err(|e| e.to_string())?;
    let model = Reconstruction::read(&site_dir.join("sparse")).map_err(|e| e.to_string())?;
    let dense = DenseObservations::read(&site_dir.join("dense/observations.bin"))
        .map_err(|e| e.to_string())?;
    let tls = crate::io::tls::read_targets(&site_dir.join("tls_targets.csv"))
        .map_err(|e| e.to_string())?;
    let tls_points: Vec<Point3<f64>> = tls.iter().map(|t| t.position).collect();
    let scan = crate::io::ply::read(&site_dir.join("tls_scan.ply")).map_err(|e| e.to_string())?;
    let size = (truth.camera.width, truth.camera.height);
    let interest = truth
        .pipes
        .iter()
        .find(|p| p.of_interest)
        .ok_or("the truth has no pipe of interest")?;
    let offset = Vector3::from(truth.tls.as_ref().map_or([0.0; 3], |t| t.offset));
    let region = Region {
        centre: Vector3::from(interest.axis_point) + offset,
        radius: REGION_M,
    };
    let config = CylinderConfig {
        radius_min: 0.5 * interest.radius,
        radius_max: 2.0 * interest.radius,
        axis_hint: Some((Vector3::from(interest.axis_direction), 20f64.to_radians())),
        ..CylinderConfig::default()
    };
    let scan_points: Vec<Vector3<f64>> = scan.cloud.points.iter().map(|p| p.coords).collect();
    let tls_fit = fit_points(
        &transformed_points(&scan_points, &Similarity::identity(), Some(&region)),
        &config,
    )
    .map_err(|e| format!("TLS scan: {e}"))?;
    let true_scale = truth
        .sfm
        .as_ref()
        .and_then(|s| s.stand_in.as_ref())
        .map_or(f64::NAN, |s| 1.0 / s.similarity.scale);

    let paths: Vec<_> = model
        .images
        .values()
        .map(|im| site_dir.join("frames").join(&im.name))
        .collect();
    log(&format!("detecting targets in {} frames", paths.len()));
    // The site command's detection: targets too small to measure left out.
    let detect = DetectConfig {
        min_semi_minor_px: crate::detect::MIN_SEMI_MINOR_TO_MEASURE_PX,
        ..DetectConfig::default()
    };
    let detected: Vec<Vec<Ellipse>> =
        detect_frame_files(&paths, size, &detect, &|| {}).map_err(|e| e.to_string())?;

    let profile = profile.scaled(size.0, size.1);
    // A video's readout time, as the device's profile or data sheet gives it.
    let timing = truth.video.as_ref().map(|v| RowTiming {
        readout_s: v.readout_s,
        height_px: f64::from(size.1),
    });
    let methods: &[Method] = if timing.is_some() {
        &[
            Method::PreCalibration,
            Method::PreCalibrationRowPoses,
            Method::InSitu,
        ]
    } else {
        &[Method::PreCalibration, Method::InSitu]
    };
    let mut rows = Vec::new();
    for &method in methods {
        let (initial, free): (Option<&Intrinsics>, &[Term]) = match method {
            Method::PreCalibration | Method::PreCalibrationRowPoses => {
                (Some(&profile.intrinsics), &[])
            }
            Method::InSitu => (None, &[Term::C, Term::K1, Term::K2]),
        };
        let row_timing = timing.filter(|_| method == Method::PreCalibrationRowPoses);
        // Pre-calibration as the main command does it: the poses re-adjusted to the profile
        // (two rounds with re-triangulation); in situ: COLMAP's radial self-calibration.
        let (a1, summary, intrinsics, poses, rolling) = match initial {
            Some(i) => {
                let p = match row_timing {
                    Some(t) => consistent_poses_rolling(
                        &model,
                        i,
                        t,
                        &RefineConfig::default(),
                        &AdjustConfig::default(),
                    ),
                    None => consistent_poses(
                        &model,
                        i,
                        &RefineConfig::default(),
                        &AdjustConfig::default(),
                    ),
                }
                .map_err(|e| format!("{}: {e}", method.name()))?;
                let poses: Vec<_> =
                    p.a1.frames
                        .iter()
                        .map(|f| f.camera.cam_from_world)
                        .collect();
                (p.a1, p.summary, *i, poses, p.rolling)
            }
            None => {
                let a1 = algorithm1(&model, None, &RefineConfig::default())
                    .map_err(|e| e.to_string())?;
                let cameras: Vec<FrameCamera> = a1.frames.iter().map(|f| f.camera).collect();
                let (summary, intrinsics, poses) =
                    adjust_feature_tracks(&model, &a1, &cameras, free, &AdjustConfig::default())
                        .map_err(|e| format!("{}: {e}", method.name()))?;
                (a1, summary, intrinsics, poses, None)
            }
        };
        let cameras: Vec<FrameCamera> = poses
            .iter()
            .map(|&cam_from_world| FrameCamera {
                intrinsics,
                cam_from_world,
            })
            .collect();
        let mut pairs = a1.pairs.clone();
        refresh_pairs(&mut pairs, &cameras);
        let targets = match_site_targets(
            &cameras,
            &pairs,
            &detected,
            size,
            a1.reprojection_sigma,
            &MatchConfig::default(),
        );
        let (reconstructed, _) =
            row_targets(&targets, &cameras, &intrinsics, rolling.as_ref(), size.1);
        let estimate = estimate_scale(&reconstructed, &tls_points, &ScaleConfig::default())
            .map_err(|e| format!("{}: {e}", method.name()))?;
        // The dense cloud through this camera at these poses (frames by name; each
        // observation at its row's pose with a rolling shutter).
        let frame_index: Vec<Option<usize>> = dense
            .frames
            .iter()
            .map(|name| a1.frames.iter().position(|f| &f.name == name))
            .collect();
        let camera = BrownCamera {
            intrinsics,
            ..profile
        };
        let (cloud, _) = fuse_with(&dense, &camera, &|frame, uv| {
            let k = (*frame_index.get(frame as usize)?)?;
            Some(match &rolling {
                Some(r) => r.row_pose(k, &poses[k], uv.y),
                None => poses[k],
            })
        });
        let points: Vec<Vector3<f64>> = cloud.points.iter().map(|p| p.coords).collect();
        let associated = estimate.associated.len();
        let scaling = Scaling::Targets(estimate);
        let m = measure_pipe(&points, &scaling, Some(&region), &config, &[])
            .map_err(|e| format!("{}: {e}", method.name()))?;
        let r = m.fit.cylinder.radius;
        let rms = (2.0 * summary.final_cost / (2.0 * summary.observations_used as f64)).sqrt();
        log(&format!(
            "{}: c {:.2} k1 {:.4} k2 {:.4}, features RMS {rms:.3} px, {} targets ({} associated), scale {:.6} ± {:.6}, radius {:.3} mm (truth {:.3}, TLS {:.3})",
            method.name(),
            intrinsics.c,
            intrinsics.k1,
            intrinsics.k2,
            reconstructed.len(),
            associated,
            m.scale.0,
            m.scale.1,
            r * 1e3,
            interest.radius * 1e3,
            tls_fit.cylinder.radius * 1e3
        ));
        rows.push(PipeRow {
            method,
            intrinsics,
            feature_rms_px: rms,
            targets: reconstructed.len(),
            associated,
            scale: m.scale.0,
            scale_std: m.scale.1,
            scale_error: m.scale.0 / true_scale - 1.0,
            radius_m: r,
            radius_std_m: m.radius_std,
            rmse_m: m.fit.rmse,
            inliers: m.fit.inliers,
            accuracy_m: r - interest.radius,
            tls_accuracy_m: r - tls_fit.cylinder.radius,
        });
    }
    Ok(SiteResult {
        device: truth.camera.device.clone(),
        truth_radius_m: interest.radius,
        tls_radius_m: tls_fit.cylinder.radius,
        frames: model.images.len(),
        image_size: size,
        rows,
    })
}

/// Table III's runs: a simulated site per device preset, measured with both methods.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Table3Options {
    /// The sites: device presets (their profiles from `calibrations/`), frame size, frames of
    /// each site video, seed.
    #[serde(flatten)]
    pub runs: PresetRuns,
    /// Film each site as a hand-held video (rolling shutter, motion blur): the video variant.
    pub video: bool,
}

impl Default for Table3Options {
    fn default() -> Self {
        Table3Options {
            runs: PresetRuns::every_preset(1920, 60),
            video: false,
        }
    }
}

/// Simulates a site per device into `out/site_<device>` (rendered frames, SfM stand-in, dense
/// observations, TLS scan and targets at 1e6 m coordinates) and runs [`run_site`] on it with
/// the device's profile.
///
/// # Errors
///
/// A message naming the device and the step that failed.
pub fn table3(
    options: &Table3Options,
    out: &Path,
    command: &str,
    log: &dyn Fn(&str),
) -> Result<Vec<SiteResult>, String> {
    use crate::sim::simulate::{SimulateOptions, SiteOptions, simulate_site};
    let mut results = Vec::new();
    for device in &options.runs.devices {
        let (_, profile) =
            crate::profile::load_device(device).map_err(|e| format!("{device}: {e}"))?;
        let sim = SimulateOptions {
            video: options.video.then(crate::sim::video::VideoConfig::default),
            ..options.runs.simulate_options(device, command)
        };
        let mut site = SiteOptions::default();
        site.site.frames = options.runs.frames;
        site.tls.offset = [500_000.0, 5_600_000.0, 100.0];
        let dir = out.join(format!("site_{device}"));
        log(&format!(
            "{device}: simulating the site into {}",
            dir.display()
        ));
        simulate_site(&sim, &site, &dir, &|_| {}).map_err(|e| format!("{device}: {e}"))?;
        let result = run_site(&dir, &profile.camera(), &|m| log(&format!("  {m}")))
            .map_err(|e| format!("{device}: {e}"))?;
        results.push(result);
    }
    Ok(results)
}

/// Table III as Markdown, then each site's truth and TLS radius.
#[must_use]
pub fn table3_markdown(results: &[SiteResult]) -> String {
    let mut md = String::from(
        "| device | method | radius (mm) | accuracy vs truth (mm) | accuracy vs TLS fit (mm) | RMSE (mm) | inliers | scale error |\n|---|---|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in results {
        for row in &r.rows {
            md.push_str(&format!(
                "| {} | {} | {} | {:+.2} % |\n",
                r.device,
                row.method.name(),
                row.markdown_cells(),
                100.0 * row.scale_error
            ));
        }
    }
    md.push('\n');
    for r in results {
        md.push_str(&format!(
            "{}: true radius {:.2} mm, TLS fit {:.2} mm, {} frames of {}x{}.\n",
            r.device,
            r.truth_radius_m * 1e3,
            r.tls_radius_m * 1e3,
            r.frames,
            r.image_size.0,
            r.image_size.1
        ));
    }
    md
}
