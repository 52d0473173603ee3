//! The main job, `pipemeasure --device NAME CLOUD [--sfm DIR] [--frames DIR] [--tls-targets CSV]
//! [--tls-scan PLY|E57] [--json OUT] [--ply-out PLY] [--scale S]`: the site's targets matched
//! and corrected (Algorithms 1–3) with the device profile, the scale from them against the TLS
//! targets, the pipe fitted in the scaled cloud, and the same pipe in the TLS scan as the
//! reference. The chain is the library's [`pipemeasure::measure::site`]; this parses, calls,
//! writes and prints.

use std::path::{Path, PathBuf};

use anyhow::Result;
use nalgebra::Point3;
use std::io::Write as _;

use pipemeasure::io::atomic::{StagedFile, check_writable};
use pipemeasure::io::ply::{PointCloud, stage_binary};
use pipemeasure::measure::site::{ScaleTargetOut, SiteReport, SiteRequest, measure_site};
use pipemeasure::measure::{ChosenBy, PipeMeasurement};

use super::calibrate::RollingShutterMode;
use super::fit_cylinder::{SearchArgs, read_points};
use super::progress::bar;
use super::{Globals, values};

/// Arguments of the main command (given without a subcommand).
#[derive(Debug, Default, clap::Args)]
pub struct Args {
    /// The dense cloud of the site (PLY, or E57), e.g. COLMAP's `dense/0/fused.ply`.
    pub cloud: Option<PathBuf>,
    /// Device profile: a name (looked up in $PIPEMEASURE_CALIBRATIONS, ./calibrations/, the
    /// user's data folder, then the presets built in) or a path to a profile JSON.
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
    /// The cloud's scale (metres per cloud unit, positive), instead of the targets (1 for a
    /// metric cloud).
    #[arg(long, value_parser = values::positive)]
    scale: Option<f64>,
    /// Write the report as JSON (atomically).
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the pipe's inliers, coloured by residual (blue inside, red outside), as PLY.
    #[arg(long)]
    ply_out: Option<PathBuf>,
    #[command(flatten)]
    search: SearchArgs,
    /// Smallest semi-minor axis of a target to use (px, at least 1).
    #[arg(long, default_value_t = pipemeasure::detect::MIN_SEMI_MINOR_TO_MEASURE_PX, value_parser = values::semi_minor_px)]
    min_semi_minor: f64,
    /// The rolling shutter of video frames: `auto` models it when the readout time is known
    /// (the profile's, from a calibration that kept it, or `--readout-time`): each frame's
    /// motion is adjusted with its pose, and the targets and the cloud are triangulated with
    /// each row's pose; `off` leaves it out (frames taken still).
    #[arg(long, value_enum, default_value_t = RollingShutterMode::Auto)]
    rolling_shutter: RollingShutterMode,
    /// The device's readout time (ms), instead of the profile's.
    #[arg(long, value_name = "MS", value_parser = values::readout_ms)]
    readout_time: Option<f64>,
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
            ("--readout-time", self.readout_time.is_some()),
            (
                "--rolling-shutter",
                self.rolling_shutter != RollingShutterMode::Auto,
            ),
        ]
        .into_iter()
        .filter_map(|(name, given)| given.then_some(name))
        .collect()
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

/// Runs the main command: parses, calls [`measure_site`], writes and prints.
pub fn run(args: &Args, cloud: &Path, globals: Globals) -> Result<()> {
    let log = |message: &str| globals.log(message);
    // The destinations first: minutes of work are not lost to a missing folder.
    for path in [&args.json, &args.ply_out].into_iter().flatten() {
        check_writable(path)?;
    }
    let request = SiteRequest {
        cloud: cloud.to_path_buf(),
        device: args.device.clone(),
        sfm: args.sfm.clone(),
        frames: args.frames.clone(),
        tls_targets: args.tls_targets.clone(),
        tls_ids: args.tls_ids.clone(),
        tls_scan: args.tls_scan.clone(),
        scale: args.scale,
        min_semi_minor_px: args.min_semi_minor,
        region: args.search.region()?,
        cylinder: args.search.pipe_config()?,
        readout_time_s: args.readout_time.map(|ms| ms * 1e-3),
        global_shutter: args.rolling_shutter == RollingShutterMode::Off,
    };
    let points = read_points(cloud, None)?;
    let scan = args
        .tls_scan
        .as_deref()
        .map(|p| read_points(p, None))
        .transpose()?;
    let progress = bar(0, "detecting", globals.quiet);
    let m = measure_site(&request, &points, scan.as_deref(), &log, &|total| {
        progress.set_length(total as u64);
        progress.inc(1);
    })?;
    progress.finish_and_clear();
    // Both outputs written, then both moved into place: all or nothing.
    let ply = args
        .ply_out
        .as_ref()
        .map(|path| stage_binary(path, &coloured_inliers(&m.pipe)))
        .transpose()?;
    let json = args
        .json
        .as_ref()
        .map(|path| {
            let text = serde_json::to_string_pretty(&m.report)?;
            Ok::<_, anyhow::Error>(StagedFile::write(path, |w| w.write_all(text.as_bytes()))?)
        })
        .transpose()?;
    for staged in [ply, json].into_iter().flatten() {
        staged.commit()?;
    }
    print_summary(&m.report, args)?;
    Ok(())
}

/// Every pipe segment found, the pipe of interest marked, and how it was chosen.
fn print_pipes(out: &SiteReport) -> Result<()> {
    let c = &out.pipe_of_interest;
    let how = match &c.by {
        ChosenBy::Near => "nearest --near".to_string(),
        ChosenBy::Frames { votes, frames } => {
            format!("the frames ({votes} of {frames} optical axes meet it first)")
        }
        ChosenBy::MostInliers { reason } => format!("most inliers ({reason})"),
    };
    outln!(
        "{} pipe segment{} found; pipe of interest * chosen by {how}{}",
        out.pipes.len(),
        if out.pipes.len() == 1 { "" } else { "s" },
        if c.ambiguous {
            format!(
                "; AMBIGUOUS: segment{} {} as good a choice (give --near X,Y,Z)",
                if c.alternatives.len() == 1 { "" } else { "s" },
                c.alternatives
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        } else {
            String::new()
        }
    );
    outln!(
        "{:>4}  {:>6} {:>5}  {:>18}  {:>7}  {:>8}  {:>6}  {:>9}  {:>9}",
        "id",
        "NPS",
        "DN",
        "radius mm",
        "len m",
        "inliers",
        "RMSE",
        "TLS mm",
        "accuracy"
    );
    for p in &out.pipes {
        outln!(
            "{:>3}{}  {:>6} {:>5}  {:>8.2} ± {:>7.2}  {:>7.3}  {:>8}  {:>6.2}  {:>9}  {:>9}",
            p.id,
            if p.of_interest { "*" } else { " " },
            p.nominal.nps.unwrap_or("-"),
            p.nominal.dn,
            p.radius_m * 1e3,
            p.radius_std_m * 1e3,
            p.length_m,
            p.inliers,
            p.rmse_m * 1e3,
            p.reference_radius_m
                .map_or("-".to_string(), |r| format!("{:.2}", r * 1e3)),
            p.accuracy_m
                .map_or("-".to_string(), |a| format!("{:+.2}", a * 1e3)),
        );
    }
    Ok(())
}

fn print_summary(out: &SiteReport, args: &Args) -> Result<()> {
    outln!(
        "pipe radius {:.2} ± {:.2} mm (fit ± {:.2} mm, {}), RMSE {:.2} mm, {} inliers",
        out.radius_m * 1e3,
        out.radius_std_m * 1e3,
        out.fit_radius_std_m * 1e3,
        out.pose_radius_std_m
            .map_or("scale included".to_string(), |p| format!(
                "poses ± {:.2} mm, scale included",
                p * 1e3
            )),
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
    let (a, b, n) = (out.segment_start, out.segment_end, &out.nominal);
    outln!(
        "segment from ({:.4}, {:.4}, {:.4}) to ({:.4}, {:.4}, {:.4}), {:.3} m; nominal {} (OD {:.2} mm, measured {:+.2} mm); {} pipe segment{} found",
        a[0],
        a[1],
        a[2],
        b[0],
        b[1],
        b[2],
        out.length_m,
        n.nps.map_or(format!("DN {}", n.dn), |nps| format!(
            "NPS {nps} / DN {}",
            n.dn
        )),
        n.outside_diameter_mm,
        n.difference_mm,
        out.segments_found,
        if out.segments_found == 1 { "" } else { "s" }
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
    print_pipes(out)?;
    if let Some(p) = &args.json {
        outln!("report written to {}", p.display());
    }
    if let Some(p) = &args.ply_out {
        outln!("inliers coloured by residual written to {}", p.display());
    }
    Ok(())
}
