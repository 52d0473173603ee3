//! The main job, `pipemeasure --device NAME CLOUD [--sfm DIR] [--frames DIR] [--tls-targets CSV]
//! [--tls-scan PLY|E57] [--json OUT] [--ply-out PLY] [--scale S]`: the site's targets matched
//! and corrected (Algorithms 1–3) with the device profile, the scale from them against the TLS
//! targets, the pipe fitted in the scaled cloud, and the same pipe in the TLS scan as the
//! reference.
//!
//! Defaults follow COLMAP's workspace (for `WS/dense/0/fused.ply`: the model in
//! `dense/0/sparse`, the frames in `dense/0/images`, `WS/tls_targets.csv`) and the simulator's
//! (`OUT/dense/fused.ply`, `OUT/sparse`, `OUT/frames`, `OUT/tls_targets.csv`): each is searched
//! for in the cloud's folder and up to two folders above it, nearest first.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nalgebra::Point3;
use pipemeasure::calibrate::matching::MatchConfig;
use pipemeasure::calibrate::refine::{RefineConfig, algorithm1};
use pipemeasure::camera::Intrinsics;
use pipemeasure::camera::convert::{ColmapModel, brown_from_colmap};
use pipemeasure::io::atomic::write_bytes_atomic;
use pipemeasure::io::colmap::Reconstruction;
use pipemeasure::io::ply::PointCloud;
use pipemeasure::io::tls::read_targets;
use pipemeasure::measure::{
    PipeMeasurement, Reference, ScaleConfig, ScaleEstimate, Scaling, estimate_scale,
    match_site_targets, measure_pipe, reference_fit,
};
use pipemeasure::profile::load_device;
use serde::Serialize;

use super::Globals;
use super::fit_cylinder::{SearchArgs, read_points};
use super::matching::{detect_named_frames, model_image_size};

/// Arguments of the main command (given without a subcommand).
#[derive(Debug, Default, clap::Args)]
pub struct Args {
    /// The dense cloud of the site (PLY, or E57), e.g. COLMAP's `dense/0/fused.ply`.
    pub cloud: Option<PathBuf>,
    /// Device profile (a name in `calibrations/`, or a path to a profile JSON).
    #[arg(long)]
    device: Option<String>,
    /// The site's SfM model (COLMAP text or binary); default: `sparse` next to the cloud or up
    /// to two folders above it.
    #[arg(long)]
    sfm: Option<PathBuf>,
    /// The site's frames the model was built from; default: `images` or `frames` next to the
    /// cloud or up to two folders above it.
    #[arg(long)]
    frames: Option<PathBuf>,
    /// TLS target coordinates `id,x,y,z` (m); default: `tls_targets.csv` next to the cloud or up
    /// to two folders above it.
    #[arg(long)]
    tls_targets: Option<PathBuf>,
    /// Use only these TLS targets (comma-separated ids), e.g. the two the paper's scale uses.
    #[arg(long, value_delimiter = ',')]
    tls_ids: Vec<String>,
    /// The TLS scan (PLY or E57): the same pipe is fitted there as the reference.
    #[arg(long)]
    tls_scan: Option<PathBuf>,
    /// The cloud's scale (metres per cloud unit), instead of the targets (1 for a metric cloud).
    #[arg(long)]
    scale: Option<f64>,
    /// Write the report as JSON (atomically).
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the pipe's inliers, coloured by residual (blue inside, red outside), as PLY.
    #[arg(long)]
    ply_out: Option<PathBuf>,
    #[command(flatten)]
    search: SearchArgs,
    /// Smallest semi-minor axis of a target to use (px).
    #[arg(long, default_value_t = 4.0)]
    min_semi_minor: f64,
}

impl Args {
    /// The main command's options given on the command line (they make no sense with a
    /// subcommand).
    pub fn given(&self) -> Vec<&'static str> {
        [
            ("--device", self.device.is_some()),
            ("--sfm", self.sfm.is_some()),
            ("--frames", self.frames.is_some()),
            ("--tls-targets", self.tls_targets.is_some()),
            ("--tls-ids", !self.tls_ids.is_empty()),
            ("--tls-scan", self.tls_scan.is_some()),
            ("--scale", self.scale.is_some()),
            ("--json", self.json.is_some()),
            ("--ply-out", self.ply_out.is_some()),
            ("--near", self.search.near.is_some()),
            ("--within", self.search.within.is_some()),
            ("--axis-hint", self.search.axis_hint.is_some()),
        ]
        .into_iter()
        .filter_map(|(name, given)| given.then_some(name))
        .collect()
    }
}

/// The first existing `name` in `dir`, its parent and grandparent.
fn search_up(cloud: &Path, names: &[&str], ok: impl Fn(&Path) -> bool) -> Option<PathBuf> {
    let dir = match cloud.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    dir.ancestors()
        .take(3)
        .flat_map(|d| names.iter().map(move |n| d.join(n)))
        .find(|p| ok(p))
}

fn is_model(dir: &Path) -> bool {
    ["cameras.txt", "cameras.bin"]
        .iter()
        .any(|f| dir.join(f).is_file())
}

/// A path given, or searched for, or a clear error naming where we looked.
fn resolve(
    given: Option<&PathBuf>,
    cloud: &Path,
    names: &[&str],
    ok: impl Fn(&Path) -> bool,
    what: &str,
    flag: &str,
) -> Result<PathBuf> {
    if let Some(p) = given {
        if !p.exists() {
            bail!("{flag} {}: not found", p.display());
        }
        return Ok(p.clone());
    }
    search_up(cloud, names, ok).with_context(|| {
        format!(
            "no {what} found next to {} or up to two folders above it (looked for {}); give it with {flag}",
            cloud.display(),
            names.join(", ")
        )
    })
}

/// The targets' scale, with what was used.
struct TargetScale {
    estimate: ScaleEstimate,
    tls_ids: Vec<String>,
    views: Vec<usize>,
    device: String,
    sfm: PathBuf,
    tls_targets: PathBuf,
    undistorted_frames: bool,
}

/// The intrinsics to observe the targets with: the profile's for frames as recorded, the model's
/// pinhole camera for frames already undistorted (checked against the profile).
fn site_intrinsics(device: &str, model: &Reconstruction) -> Result<(Intrinsics, bool)> {
    let (path, profile) = load_device(device)?;
    let Some(cam) = model.cameras.values().next() else {
        bail!("the model has no camera")
    };
    let (w, h) = model_image_size(model)?;
    let profile_cam = profile.camera();
    if u64::from(profile_cam.width) * u64::from(h) != u64::from(profile_cam.height) * u64::from(w) {
        bail!(
            "device {device} ({}) is for {}x{} frames but the model's camera is {w}x{h}: another aspect ratio, so these frames are not from this device",
            path.display(),
            profile_cam.width,
            profile_cam.height
        );
    }
    let scaled = profile_cam.scaled(w, h);
    let model_cam = brown_from_colmap(cam)
        .with_context(|| "the model's camera")?
        .camera;
    // COLMAP's undistorter (and `pipemeasure undistort`) write pinhole cameras; a model with a
    // distortion model (even one estimated as zero, or never refined) has the frames as recorded.
    let pinhole = matches!(cam.model, ColmapModel::Pinhole | ColmapModel::SimplePinhole);
    if !pinhole || model_cam.intrinsics.has_distortion() {
        return Ok((scaled.intrinsics, false));
    }
    // Undistorted frames: a pinhole of about the profile's principal distance.
    let rel = (model_cam.intrinsics.c / scaled.intrinsics.c - 1.0).abs();
    if rel > 0.05 {
        bail!(
            "the model's pinhole camera has a principal distance of {:.1} px, device {device} {:.1} px at {w}x{h} ({:.0} % apart): these frames were not undistorted with this device's profile",
            model_cam.intrinsics.c,
            scaled.intrinsics.c,
            100.0 * rel
        );
    }
    Ok((model_cam.intrinsics, true))
}

/// Checks that the first frame has the model's size.
fn check_frame_size(frames: &Path, name: &str, size: (u32, u32)) -> Result<()> {
    let path = frames.join(name);
    let (w, h) = image::image_dimensions(&path)
        .with_context(|| format!("frame {} of the model", path.display()))?;
    if (w, h) != size {
        bail!(
            "frame {} is {w}x{h} but the model's camera is {}x{}: the frames and the model do not belong together",
            path.display(),
            size.0,
            size.1
        );
    }
    Ok(())
}

fn scale_from_targets(
    args: &Args,
    cloud: &Path,
    globals: Globals,
    log: &dyn Fn(&str),
) -> Result<TargetScale> {
    let Some(device) = args.device.as_deref() else {
        bail!("--device NAME is needed to scale the cloud from the targets (or give --scale)");
    };
    let sfm = resolve(
        args.sfm.as_ref(),
        cloud,
        &["sparse", "sparse/0"],
        is_model,
        "SfM model",
        "--sfm",
    )?;
    let frames = resolve(
        args.frames.as_ref(),
        cloud,
        &["images", "frames"],
        Path::is_dir,
        "frames folder",
        "--frames",
    )?;
    let tls_path = resolve(
        args.tls_targets.as_ref(),
        cloud,
        &["tls_targets.csv"],
        Path::is_file,
        "TLS target list",
        "--tls-targets",
    )?;
    let mut tls = read_targets(&tls_path)?;
    if !args.tls_ids.is_empty() {
        for id in &args.tls_ids {
            if !tls.iter().any(|t| &t.id == id) {
                bail!(
                    "--tls-ids: target `{id}` is not in {} (its ids: {})",
                    tls_path.display(),
                    tls.iter()
                        .map(|t| t.id.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                );
            }
        }
        tls.retain(|t| args.tls_ids.contains(&t.id));
    }
    if tls.len() < 2 {
        bail!(
            "{}: {} TLS target(s); the scale needs at least two",
            tls_path.display(),
            tls.len()
        );
    }
    let model = Reconstruction::read(&sfm)?;
    if model.images.is_empty() {
        bail!("the model {} has no registered images", sfm.display());
    }
    let (intrinsics, undistorted) = site_intrinsics(device, &model)?;
    let size = model_image_size(&model)?;
    let a1 = algorithm1(&model, Some(&intrinsics), &RefineConfig::default())
        .with_context(|| format!("Algorithm 1 on {}", sfm.display()))?;
    check_frame_size(&frames, &a1.frames[0].name, size)?;
    let names: Vec<String> = a1.frames.iter().map(|f| f.name.clone()).collect();
    let detected = detect_named_frames(&frames, &names, args.min_semi_minor, globals.quiet)?;
    let cameras: Vec<_> = a1.frames.iter().map(|f| f.camera).collect();
    let targets = match_site_targets(
        &cameras,
        &a1.pairs,
        &detected,
        size,
        a1.reprojection_sigma,
        &MatchConfig::default(),
    );
    let reconstructed = targets.reconstructed();
    log(&format!(
        "{} frames, {} targets matched (Algorithms 1–3) with {}",
        names.len(),
        reconstructed.len(),
        if undistorted {
            "the model's pinhole camera (frames already undistorted)".to_string()
        } else {
            format!("device {device}'s profile")
        }
    ));
    let points: Vec<Point3<f64>> = tls.iter().map(|t| t.position).collect();
    let estimate = estimate_scale(&reconstructed, &points, &ScaleConfig::default())
        .with_context(|| format!("scale from {}", tls_path.display()))?;
    Ok(TargetScale {
        views: reconstructed.iter().map(|t| t.views).collect(),
        tls_ids: tls.into_iter().map(|t| t.id).collect(),
        estimate,
        device: device.to_string(),
        sfm,
        tls_targets: tls_path,
        undistorted_frames: undistorted,
    })
}

#[derive(Serialize)]
struct ScaleTargetOut {
    tls_id: String,
    views: usize,
    /// Distance to the TLS target after the similarity (m), if there is one.
    residual_m: Option<f64>,
}

#[derive(Serialize)]
struct AxisOut {
    point: [f64; 3],
    direction: [f64; 3],
}

#[derive(Serialize)]
struct ReportOut {
    schema: &'static str,
    cloud: String,
    device: Option<String>,
    sfm: Option<String>,
    tls_targets: Option<String>,
    frames_undistorted: Option<bool>,
    radius_m: f64,
    /// Combined σ: the fit's and the scale's.
    radius_std_m: f64,
    fit_radius_std_m: f64,
    rmse_m: f64,
    inliers: usize,
    axis: AxisOut,
    /// `tls` when the cloud was moved into the TLS frame by the targets' similarity, `scaled`
    /// when only scaled.
    frame: &'static str,
    scale: f64,
    scale_std: f64,
    /// `given`, `two targets` (paper) or `similarity`.
    scale_method: &'static str,
    scale_targets: Vec<ScaleTargetOut>,
    two_target_scale: Option<f64>,
    two_target_ids: Option<[String; 2]>,
    similarity_scale: Option<f64>,
    similarity_scale_std: Option<f64>,
    similarity_rms_m: Option<f64>,
    association_assumed: Option<bool>,
    reference_radius_m: Option<f64>,
    reference_radius_std_m: Option<f64>,
    reference_rmse_m: Option<f64>,
    reference_inliers: Option<usize>,
    accuracy_m: Option<f64>,
}

fn report(
    cloud: &Path,
    m: &PipeMeasurement,
    scaling: &Scaling,
    targets: Option<&TargetScale>,
    reference: Option<&Reference>,
) -> ReportOut {
    let c = &m.fit.cylinder;
    let est = targets.map(|t| &t.estimate);
    let scale_targets = targets
        .map(|t| {
            t.estimate
                .associated
                .iter()
                .enumerate()
                .map(|(k, &(r, i))| ScaleTargetOut {
                    tls_id: t.tls_ids[i].clone(),
                    views: t.views[r],
                    residual_m: t
                        .estimate
                        .similarity
                        .as_ref()
                        .and_then(|s| s.residuals_m.get(k).copied()),
                })
                .collect()
        })
        .unwrap_or_default();
    ReportOut {
        schema: "pipemeasure.measurement/1",
        cloud: cloud.display().to_string(),
        device: targets.map(|t| t.device.clone()),
        sfm: targets.map(|t| t.sfm.display().to_string()),
        tls_targets: targets.map(|t| t.tls_targets.display().to_string()),
        frames_undistorted: targets.map(|t| t.undistorted_frames),
        radius_m: c.radius,
        radius_std_m: m.radius_std,
        fit_radius_std_m: m.fit.radius_std,
        rmse_m: m.fit.rmse,
        inliers: m.fit.inliers,
        axis: AxisOut {
            point: c.point.into(),
            direction: c.direction.into(),
        },
        frame: if scaling.in_tls_frame() {
            "tls"
        } else {
            "scaled"
        },
        scale: m.scale.0,
        scale_std: m.scale.1,
        scale_method: match (scaling, est.and_then(|e| e.similarity.as_ref())) {
            (Scaling::Given(_), _) => "given",
            (_, Some(_)) => "similarity",
            _ => "two targets",
        },
        scale_targets,
        two_target_scale: est.map(|e| e.two_target.scale),
        two_target_ids: targets.map(|t| t.estimate.two_target.tls.map(|i| t.tls_ids[i].clone())),
        similarity_scale: est.and_then(|e| e.similarity.as_ref().map(|s| s.scale)),
        similarity_scale_std: est.and_then(|e| e.similarity.as_ref().map(|s| s.scale_std)),
        similarity_rms_m: est.and_then(|e| e.similarity.as_ref().map(|s| s.rms_m)),
        association_assumed: est.map(|e| e.assumed),
        reference_radius_m: reference.map(|r| r.fit.cylinder.radius),
        reference_radius_std_m: reference.map(|r| r.fit.radius_std),
        reference_rmse_m: reference.map(|r| r.fit.rmse),
        reference_inliers: reference.map(|r| r.fit.inliers),
        accuracy_m: reference.map(|r| r.accuracy),
    }
}

/// The inliers coloured by residual: blue (−3 RMSE, inside) – white – red (+3 RMSE, outside).
fn coloured_inliers(m: &PipeMeasurement) -> PointCloud {
    let scale = 3.0 * m.fit.rmse.max(f64::MIN_POSITIVE);
    let (points, colors) = m
        .fit
        .inlier_indices
        .iter()
        .map(|&i| {
            let p = m.points[i];
            let t = (m.fit.cylinder.residual(&p) / scale).clamp(-1.0, 1.0);
            let fade = |x: f64| (255.0 * (1.0 - x.abs())).round() as u8;
            let color = if t >= 0.0 {
                [255, fade(t), fade(t)]
            } else {
                [fade(t), fade(t), 255]
            };
            (Point3::from(p), color)
        })
        .unzip();
    PointCloud {
        colors: Some(colors),
        ..PointCloud::from_points(points)
    }
}

/// Runs the main command.
pub fn run(args: &Args, cloud: &Path, globals: Globals) -> Result<()> {
    let log = |s: &str| {
        if !globals.quiet {
            eprintln!("{s}");
        }
    };
    let region = args.search.region()?;
    let points = read_points(cloud)?;
    let (scaling, targets) = match args.scale {
        Some(s) if s.is_finite() && s > 0.0 => (Scaling::Given(s), None),
        Some(s) => bail!("--scale {s}: must be a positive number"),
        None => {
            let t = scale_from_targets(args, cloud, globals, &log)?;
            (Scaling::Targets(t.estimate.clone()), Some(t))
        }
    };
    let config = args.search.config()?;
    let m = measure_pipe(&points, &scaling, region.as_ref(), &config)
        .with_context(|| format!("fitting the pipe in {}", cloud.display()))?;
    let reference = match &args.tls_scan {
        Some(path) => {
            let scan = read_points(path)?;
            Some(
                reference_fit(&scan, &m, scaling.in_tls_frame(), &config)
                    .with_context(|| format!("fitting the same pipe in {}", path.display()))?,
            )
        }
        None => None,
    };
    let out = report(cloud, &m, &scaling, targets.as_ref(), reference.as_ref());
    if let Some(path) = &args.ply_out {
        pipemeasure::io::ply::write_binary(path, &coloured_inliers(&m))?;
    }
    if let Some(path) = &args.json {
        write_bytes_atomic(path, serde_json::to_string_pretty(&out)?.as_bytes())?;
    }
    print_summary(&out, args)?;
    Ok(())
}

fn print_summary(out: &ReportOut, args: &Args) -> Result<()> {
    outln!(
        "pipe radius {:.2} ± {:.2} mm (fit ± {:.2} mm, scale included), RMSE {:.2} mm, {} inliers",
        out.radius_m * 1e3,
        out.radius_std_m * 1e3,
        out.fit_radius_std_m * 1e3,
        out.rmse_m * 1e3,
        out.inliers
    );
    let ids = |v: &[ScaleTargetOut]| {
        v.iter()
            .map(|t| format!("{} ({} views)", t.tls_id, t.views))
            .collect::<Vec<_>>()
            .join(", ")
    };
    match out.scale_method {
        "given" => outln!("scale {} (given)", out.scale),
        method => {
            outln!(
                "scale {:.6} ± {:.6} ({method}) from {} targets: {}",
                out.scale,
                out.scale_std,
                out.scale_targets.len(),
                ids(&out.scale_targets)
            );
            if let (Some(s2), Some([a, b])) = (out.two_target_scale, &out.two_target_ids) {
                outln!(
                    "paper's two-target scale {s2:.6} ({a}–{b}, the two with the most views){}",
                    if out.association_assumed == Some(true) {
                        "; with only two TLS targets they are assumed to be the two targets seen in the most views"
                    } else {
                        ""
                    }
                );
            }
        }
    }
    let (p, d) = (out.axis.point, out.axis.direction);
    outln!(
        "axis through ({:.4}, {:.4}, {:.4}) along ({:.4}, {:.4}, {:.4}), {} frame",
        p[0],
        p[1],
        p[2],
        d[0],
        d[1],
        d[2],
        if out.frame == "tls" {
            "TLS"
        } else {
            "scaled cloud's"
        }
    );
    if let (Some(r), Some(a)) = (out.reference_radius_m, out.accuracy_m) {
        outln!(
            "TLS reference radius {:.2} ± {:.2} mm ({} inliers): accuracy {:+.2} mm",
            r * 1e3,
            out.reference_radius_std_m.unwrap_or(f64::NAN) * 1e3,
            out.reference_inliers.unwrap_or(0),
            a * 1e3
        );
    }
    if let Some(p) = &args.json {
        outln!("report written to {}", p.display());
    }
    if let Some(p) = &args.ply_out {
        outln!("inliers coloured by residual written to {}", p.display());
    }
    Ok(())
}
