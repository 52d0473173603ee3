//! `pipemeasure match --frames DIR --sfm MODEL [--json OUT] [--device NAME]
//! [--no-robust-triangulation] [--no-eccentricity]`: Algorithm 1 steps 1–3 on the SfM model,
//! target detection in its frames, Algorithm 2 and Algorithm 3; the tracks as JSON.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use pipemeasure::adjust::AdjustConfig;
use pipemeasure::calibrate::matching::{MatchConfig, Matching};
use pipemeasure::calibrate::poses::consistent_poses;
use pipemeasure::calibrate::refine::{Algorithm1, RefineConfig, algorithm1};
use pipemeasure::calibrate::views::TargetObservation;
use pipemeasure::camera::Intrinsics;
use pipemeasure::detect::{DetectConfig, detect_frame_files};
use pipemeasure::geometry::conic::Ellipse;
use pipemeasure::io::atomic::{check_writable, write_bytes_atomic};
use pipemeasure::io::colmap::Reconstruction;
use pipemeasure::measure::{SiteTargets, match_site_targets};
use serde::Serialize;

use super::progress::bar;
use super::{Globals, NothingFound, values};

/// Arguments of `match`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder of the frames the SfM model was built from (image names are relative to it).
    #[arg(long)]
    frames: PathBuf,
    /// COLMAP sparse model folder (text or binary), e.g. `sparse/0`.
    #[arg(long)]
    sfm: PathBuf,
    /// Write the tracks here as JSON (atomically); without it, print a summary.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Use this device profile's intrinsics instead of the model's camera.
    #[arg(long)]
    device: Option<String>,
    /// Keep every chained view (no LMedS triangulation of the tracks: paper Table II row 1).
    #[arg(long)]
    no_robust_triangulation: bool,
    /// Do not correct the ellipse centres with Algorithm 3.
    #[arg(long)]
    no_eccentricity: bool,
    /// Smallest semi-minor axis of a target to use (px, at least 1).
    #[arg(long, default_value_t = pipemeasure::detect::MIN_SEMI_MINOR_TO_MEASURE_PX, value_parser = values::semi_minor_px)]
    min_semi_minor: f64,
}

#[derive(Serialize)]
struct EllipseOut {
    cx: f64,
    cy: f64,
    a: f64,
    b: f64,
    theta: f64,
}

#[derive(Serialize)]
struct ObservationOut {
    frame: String,
    /// Index of the detection in its frame (as `pipemeasure detect` lists them).
    detection: usize,
    /// The detected ellipse (observed pixels).
    ellipse: EllipseOut,
    /// Algorithm 3's image of the target's centre (observed pixels), if corrected.
    corrected: Option<[f64; 2]>,
    /// Algorithm 3's partner frame.
    partner: Option<String>,
    /// Algorithm 3's roundness of the target in its plane from this view (minor/major axis
    /// ratio; about 1 for a circular target).
    roundness: Option<f64>,
}

#[derive(Serialize)]
struct TargetOut {
    id: usize,
    /// Triangulated centre in the SfM model's frame.
    point: [f64; 3],
    /// RMS reprojection error of the centres (px).
    rms_px: f64,
    observations: Vec<ObservationOut>,
}

#[derive(Serialize)]
struct Algorithm1Out {
    pairs: usize,
    tracks: usize,
    rejected_tracks: usize,
    track_inlier_fraction: f64,
    reprojection_sigma_px: f64,
    /// With `--device`: the σ with the model's poses and the profile, before they were
    /// re-adjusted to it (`reprojection_sigma_px` is after).
    #[serde(skip_serializing_if = "Option::is_none")]
    reprojection_sigma_before_readjustment_px: Option<f64>,
}

#[derive(Serialize)]
struct MatchOut {
    schema: &'static str,
    model: String,
    frames: Vec<String>,
    detections: usize,
    algorithm1: Algorithm1Out,
    candidates: usize,
    pair_matches: usize,
    conflicts: usize,
    /// Tracks dropped as not round in their plane (Algorithm 3's cut of each view's cone).
    not_round: usize,
    targets: Vec<TargetOut>,
}

/// The intrinsics to use: the profile's (scaled to the model's image size) or none (the
/// model's camera).
fn intrinsics_for(
    device: Option<&str>,
    model: &Reconstruction,
) -> Result<Option<(Intrinsics, String)>> {
    let Some(spec) = device else { return Ok(None) };
    let (path, profile) = pipemeasure::profile::load_device(spec)?;
    let Some(cam) = model.cameras.values().next() else {
        bail!("the model has no camera")
    };
    let (w, h) = (
        u32::try_from(cam.width).unwrap_or(0),
        u32::try_from(cam.height).unwrap_or(0),
    );
    let camera = profile.camera();
    let camera = if (camera.width, camera.height) == (w, h) {
        camera
    } else {
        if u64::from(camera.width) * u64::from(h) != u64::from(camera.height) * u64::from(w) {
            bail!(
                "profile {} is for {}x{} frames, the model's are {w}x{h} (another aspect ratio)",
                path.display(),
                camera.width,
                camera.height
            );
        }
        camera.scaled(w, h)
    };
    Ok(Some((camera.intrinsics, path.display().to_string())))
}

/// Detects the targets of the named frames of `dir`, in parallel (one frame in memory per
/// worker): per frame, the detected ellipses in observed pixels.
pub(super) fn detect_named_frames(
    dir: &Path,
    names: &[String],
    size: (u32, u32),
    min_semi_minor: f64,
    quiet: bool,
) -> Result<Vec<Vec<Ellipse>>> {
    let config = DetectConfig {
        min_semi_minor_px: min_semi_minor,
        ..DetectConfig::default()
    };
    let progress = bar(names.len() as u64, "detecting", quiet);
    let paths: Vec<PathBuf> = names.iter().map(|n| dir.join(n)).collect();
    let detected = detect_frame_files(&paths, size, &config, &|| progress.inc(1))
        .context("detecting the targets of the model's frames")?;
    progress.finish_and_clear();
    Ok(detected)
}

/// The image size of the model's (first) camera.
pub(super) fn model_image_size(model: &Reconstruction) -> Result<(u32, u32)> {
    let Some(camera) = model.cameras.values().next() else {
        bail!("the model has no camera")
    };
    Ok((
        u32::try_from(camera.width).unwrap_or(u32::MAX),
        u32::try_from(camera.height).unwrap_or(u32::MAX),
    ))
}

fn output(
    model: &Path,
    a1: &Algorithm1,
    sigma_before: Option<f64>,
    obs: &[Vec<TargetObservation>],
    m: &Matching,
) -> MatchOut {
    let frames: Vec<String> = a1.frames.iter().map(|f| f.name.clone()).collect();
    let targets = m
        .tracks
        .iter()
        .enumerate()
        .map(|(k, t)| TargetOut {
            id: k + 1,
            point: [t.point.x, t.point.y, t.point.z],
            rms_px: t.rms_px,
            observations: t
                .views
                .iter()
                .map(|v| {
                    let o = &obs[v.frame][v.obs];
                    let cam = &a1.frames[v.frame].camera;
                    let e = o.detected;
                    ObservationOut {
                        frame: frames[v.frame].clone(),
                        detection: o.index,
                        ellipse: EllipseOut {
                            cx: e.cx,
                            cy: e.cy,
                            a: e.a,
                            b: e.b,
                            theta: e.theta,
                        },
                        corrected: v
                            .corrected
                            .and_then(|c| cam.distort(&c))
                            .map(|c| [c.x, c.y]),
                        partner: v.partner.map(|p| frames[p].clone()),
                        roundness: v.roundness,
                    }
                })
                .collect(),
        })
        .collect();
    MatchOut {
        schema: "pipemeasure.match/1",
        model: model.display().to_string(),
        detections: obs.iter().map(Vec::len).sum(),
        frames,
        algorithm1: Algorithm1Out {
            pairs: a1.pairs.len(),
            tracks: a1.tracks.len(),
            rejected_tracks: a1.rejected_tracks,
            track_inlier_fraction: a1.track_inlier_fraction(),
            reprojection_sigma_px: a1.reprojection_sigma,
            reprojection_sigma_before_readjustment_px: sigma_before,
        },
        candidates: m.candidates,
        pair_matches: m.pair_matches,
        conflicts: m.conflicts,
        not_round: m.not_round,
        targets,
    }
}

pub fn run(args: &Args, globals: Globals) -> Result<()> {
    if let Some(path) = &args.json {
        check_writable(path)?;
    }
    let model = Reconstruction::read(&args.sfm)?;
    if model.images.is_empty() {
        bail!("the model {} has no registered images", args.sfm.display());
    }
    if !args.frames.is_dir() {
        bail!("--frames {}: not a folder", args.frames.display());
    }
    let intrinsics = intrinsics_for(args.device.as_deref(), &model)?;
    // With a profile, the model's poses (adjusted with the SfM program's own camera) are first
    // re-adjusted to the profile's intrinsics.
    let (a1, sigma_before) = match &intrinsics {
        Some((i, _)) => {
            let p = consistent_poses(
                &model,
                i,
                &RefineConfig::default(),
                &AdjustConfig::default(),
            )
            .with_context(|| format!("Algorithm 1 on {}", args.sfm.display()))?;
            if !globals.quiet {
                eprintln!(
                    "Algorithm 1: reprojection σ {:.2} px with the model's poses and the profile, {:.2} px after re-adjusting the poses to it",
                    p.sigma_before_px, p.sigma_after_px
                );
            }
            (p.a1, Some(p.sigma_before_px))
        }
        None => (
            algorithm1(&model, None, &RefineConfig::default())
                .with_context(|| format!("Algorithm 1 on {}", args.sfm.display()))?,
            None,
        ),
    };
    let names: Vec<String> = a1.frames.iter().map(|f| f.name.clone()).collect();
    let size = model_image_size(&model)?;
    let detected = detect_named_frames(
        &args.frames,
        &names,
        size,
        args.min_semi_minor,
        globals.quiet,
    )?;
    let config = MatchConfig {
        robust_triangulation: !args.no_robust_triangulation,
        correct_before_triangulation: !args.no_eccentricity,
        correct_centres: !args.no_eccentricity,
        ..MatchConfig::default()
    };
    let cameras: Vec<_> = a1.frames.iter().map(|f| f.camera).collect();
    let SiteTargets {
        observations: obs,
        matching: m,
    } = match_site_targets(
        &cameras,
        &a1.pairs,
        &detected,
        size,
        a1.reprojection_sigma,
        &config,
    );
    let out = output(&args.sfm, &a1, sigma_before, &obs, &m);
    if let Some(path) = &args.json {
        write_bytes_atomic(path, serde_json::to_string_pretty(&out)?.as_bytes())?;
    }
    let views: usize = m.tracks.iter().map(|t| t.views.len()).sum();
    let corrected: usize = m
        .tracks
        .iter()
        .flat_map(|t| &t.views)
        .filter(|v| v.corrected.is_some())
        .count();
    if !globals.quiet || args.json.is_none() {
        outln!(
            "{} frames, {} detections; Algorithm 1: {} overlapping pairs, {:.1} % of feature observations inliers, reprojection σ {:.2} px",
            out.frames.len(),
            out.detections,
            a1.pairs.len(),
            100.0 * a1.track_inlier_fraction(),
            a1.reprojection_sigma
        );
        outln!(
            "matched {} targets with {views} views ({corrected} centres corrected by Algorithm 3); {} two-view matches, {} refused as conflicts; {} tracks dropped as not round in their plane",
            m.tracks.len(),
            m.pair_matches,
            m.conflicts,
            m.not_round
        );
        if let Some((_, profile)) = &intrinsics {
            outln!("intrinsics from {profile}");
        }
        if let Some(path) = &args.json {
            outln!("tracks written to {}", path.display());
        }
    }
    if m.tracks.is_empty() {
        return Err(NothingFound("no target was matched in two or more frames".into()).into());
    }
    Ok(())
}
