//! `pipemeasure fit-cylinder CLOUD.ply [--json] [--radius-min M --radius-max M] [--all]
//! [--near X,Y,Z --within M] [--axis-hint X,Y,Z]`: the robust cylinder fit alone.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use nalgebra::Vector3;
use pipemeasure::measure::{Cloud, CylinderConfig, CylinderFit, fit_all_cylinders, fit_cylinder};
use serde::Serialize;

use super::Globals;

/// Arguments of `fit-cylinder`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The point cloud (PLY, or E57 by its extension).
    cloud: PathBuf,
    /// Print JSON: `{"radius_m","radius_std_m","rmse_m","inliers","axis":{"point","direction"}}`
    /// (with `--all`, one such object per line).
    #[arg(long)]
    json: bool,
    /// Smallest radius to accept (m).
    #[arg(long, default_value_t = 0.005)]
    radius_min: f64,
    /// Largest radius to accept (m).
    #[arg(long, default_value_t = 1.0)]
    radius_max: f64,
    /// Report every cylinder found (fitted and removed in turn), best supported first.
    #[arg(long)]
    all: bool,
    /// Keep only points near this point (`X,Y,Z`, cloud units), with `--within`.
    #[arg(long, value_parser = parse_vec3)]
    near: Option<Vector3<f64>>,
    /// Radius of the region of interest around `--near` (m).
    #[arg(long)]
    within: Option<f64>,
    /// Only axes within 20° of this direction (`X,Y,Z`).
    #[arg(long, value_parser = parse_vec3)]
    axis_hint: Option<Vector3<f64>>,
    /// Seed of the sampling.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

pub(super) fn parse_vec3(s: &str) -> Result<Vector3<f64>, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("`{s}`: expected X,Y,Z"))?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Vector3::new(*x, *y, *z)),
        _ => Err(format!("`{s}`: expected three finite numbers X,Y,Z")),
    }
}

#[derive(Serialize)]
struct Axis {
    point: [f64; 3],
    direction: [f64; 3],
}

#[derive(Serialize)]
struct FitOut {
    radius_m: f64,
    radius_std_m: f64,
    rmse_m: f64,
    inliers: usize,
    axis: Axis,
}

fn out_of(f: &CylinderFit) -> FitOut {
    let (p, d) = (f.cylinder.point, f.cylinder.direction);
    FitOut {
        radius_m: f.cylinder.radius,
        radius_std_m: f.radius_std,
        rmse_m: f.rmse,
        inliers: f.inliers,
        axis: Axis {
            point: [p.x, p.y, p.z],
            direction: [d.x, d.y, d.z],
        },
    }
}

pub fn run(args: &Args, _globals: Globals) -> Result<()> {
    if args.near.is_some() != args.within.is_some() {
        bail!("--near and --within go together");
    }
    let read = pipemeasure::io::e57::read_cloud(&args.cloud)?;
    let mut points: Vec<Vector3<f64>> = read.cloud.points.iter().map(|p| p.coords).collect();
    if points.is_empty() {
        bail!(
            "{}: no finite points ({} vertices, {} not finite)",
            args.cloud.display(),
            read.vertices_in_file,
            read.skipped_non_finite
        );
    }
    if let (Some(c), Some(r)) = (args.near, args.within) {
        points.retain(|p| (p - c).norm() <= r);
    }
    let cloud = Cloud::new(&points).with_context(|| format!("{}", args.cloud.display()))?;
    let config = CylinderConfig {
        radius_min: args.radius_min,
        radius_max: args.radius_max,
        axis_hint: args.axis_hint.map(|h| (h.normalize(), 20f64.to_radians())),
        seed: args.seed,
        ..CylinderConfig::default()
    };
    config.validate()?;
    let fits = if args.all {
        let all = fit_all_cylinders(&cloud, &config, 16);
        if all.is_empty() {
            // Report why, with the not-found exit code.
            fit_cylinder(&cloud, &config)?;
        }
        all
    } else {
        vec![fit_cylinder(&cloud, &config)?]
    };
    for f in &fits {
        if args.json {
            outln!("{}", serde_json::to_string(&out_of(f))?);
        } else {
            let (p, d) = (f.cylinder.point, f.cylinder.direction);
            outln!(
                "radius {:.2} ± {:.2} mm, RMSE {:.2} mm, {} inliers; axis through ({:.4}, {:.4}, {:.4}) along ({:.4}, {:.4}, {:.4})",
                f.cylinder.radius * 1e3,
                f.radius_std * 1e3,
                f.rmse * 1e3,
                f.inliers,
                p.x,
                p.y,
                p.z,
                d.x,
                d.y,
                d.z
            );
        }
    }
    Ok(())
}
