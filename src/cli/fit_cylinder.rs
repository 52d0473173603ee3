//! `pipemeasure fit-cylinder CLOUD.ply [--json] [--radius-min M --radius-max M] [--all]
//! [--near X,Y,Z --within M] [--axis-hint X,Y,Z]`: the robust cylinder fit alone.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nalgebra::Vector3;
use pipemeasure::io::e57::stream_cloud;
use pipemeasure::measure::network::Network;
use pipemeasure::measure::scan::{ScanConfig, extract_network_from};
use pipemeasure::measure::{
    Cloud, CylinderConfig, CylinderFit, NetworkConfig, Region, extract_network, fit_cylinder,
};
use serde::Serialize;

use super::{Globals, usage, values};

/// Arguments of `fit-cylinder`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The point cloud (PLY, or E57 by its extension).
    cloud: PathBuf,
    /// Print JSON: `{"radius_m","radius_std_m","rmse_m","inliers","axis":{"point","direction"}}`
    /// (with `--all`, one such object per line).
    #[arg(long)]
    json: bool,
    /// Report every pipe, once, as straight segments (the engine of `pipemeasure pipes`),
    /// best supported first.
    #[arg(long)]
    all: bool,
    #[command(flatten)]
    search: SearchArgs,
}

/// The cylinder search's options, shared by `fit-cylinder` and the main command.
#[derive(Debug, Default, clap::Args)]
pub struct SearchArgs {
    /// Smallest radius to accept (m): by default 0.005 for `fit-cylinder`, 0.015 for the main
    /// command (the pipe engine's range, as `pipes`).
    #[arg(long, value_parser = values::non_negative)]
    radius_min: Option<f64>,
    /// Largest radius to accept (m), above `--radius-min`: by default 1 for `fit-cylinder`,
    /// 0.35 for the main command (wider curved surfaces, housings and tanks, are not pipes).
    #[arg(long, value_parser = values::positive)]
    radius_max: Option<f64>,
    /// Keep only points near this point (`X,Y,Z`), with `--within`. For the main command in the
    /// measured frame: TLS coordinates when the targets give a similarity.
    #[arg(long, value_parser = values::point)]
    pub near: Option<Vector3<f64>>,
    /// Radius of the region of interest around `--near` (m).
    #[arg(long, value_parser = values::positive)]
    pub within: Option<f64>,
    /// Only axes within 20° of this direction (`X,Y,Z`, not all zero).
    #[arg(long, value_parser = values::direction)]
    pub axis_hint: Option<Vector3<f64>>,
    /// Seed of the cylinder sampling.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

impl SearchArgs {
    /// The region of interest, if `--near` and `--within` are given (one without the other is
    /// an error).
    pub fn region(&self) -> Result<Option<Region>> {
        match (self.near, self.within) {
            (Some(centre), Some(radius)) => Ok(Some(Region { centre, radius })),
            (None, None) => Ok(None),
            _ => Err(usage("--near and --within go together")),
        }
    }

    /// The fitting configuration of `fit-cylinder` (radii 0.005–1 m by default), checked.
    pub fn config(&self) -> Result<CylinderConfig> {
        self.config_within(0.005, 1.0)
    }

    /// The main command's configuration: by default the pipe engine's radius range
    /// ([`NetworkConfig::default`], as `pipes`), checked.
    pub fn pipe_config(&self) -> Result<CylinderConfig> {
        let engine = NetworkConfig::default().cylinder;
        self.config_within(engine.radius_min, engine.radius_max)
    }

    /// The configuration with the radius range's defaults `min`–`max`, checked: every value
    /// comes from an option, so what the library refuses is a usage error.
    fn config_within(&self, min: f64, max: f64) -> Result<CylinderConfig> {
        checked(CylinderConfig {
            radius_min: self.radius_min.unwrap_or(min),
            radius_max: self.radius_max.unwrap_or(max),
            axis_hint: self.axis_hint.map(|h| (h, 20f64.to_radians())),
            seed: self.seed,
            ..CylinderConfig::default()
        })
    }
}

/// A cylinder configuration made from options, checked: `--radius-min` below `--radius-max`,
/// and what the library refuses is a usage error.
pub(super) fn checked(config: CylinderConfig) -> Result<CylinderConfig> {
    if config.radius_min >= config.radius_max {
        return Err(usage(format!(
            "--radius-min {} must be below --radius-max {}",
            config.radius_min, config.radius_max
        )));
    }
    config.validate().map_err(|e| usage(e.to_string()))?;
    Ok(config)
}

/// The finite points of a PLY or E57 cloud, only those within `region` if given: the file is
/// streamed, so only they are held. No finite point in the file, or none in the region, is an
/// error naming the file.
pub(super) fn read_points(path: &Path, region: Option<&Region>) -> Result<Vec<Vector3<f64>>> {
    let mut points = Vec::new();
    let read = stream_cloud(path, 1 << 20, &mut |chunk| {
        points.extend(
            chunk
                .iter()
                .map(|p| p.coords)
                .filter(|p| region.is_none_or(|r| r.contains(p))),
        );
    })?;
    read.require_finite(path)?;
    if let (Some(region), true) = (region, points.is_empty()) {
        let c = region.centre;
        bail!(
            "{}: no point within {} m of ({}, {}, {}) ({} finite points in the file)",
            path.display(),
            region.radius,
            c.x,
            c.y,
            c.z,
            read.vertices_in_file - read.skipped_non_finite
        );
    }
    Ok(points)
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
    let region = args.search.region()?;
    let config = args.search.config()?;
    if args.all && region.is_none() {
        // A scan of any size: streamed, decimated beyond the budget, re-fitted on every point.
        let scan = extract_network_from(
            &args.cloud,
            &ScanConfig {
                network: NetworkConfig {
                    cylinder: config,
                    ..Default::default()
                },
                ..Default::default()
            },
            &mut |_, _| {},
        )?;
        return print_all(args, &scan.network);
    }
    let points = read_points(&args.cloud, region.as_ref())?;
    if args.all {
        let network = extract_network(
            &points,
            &NetworkConfig {
                cylinder: config,
                ..Default::default()
            },
        )
        .with_context(|| format!("{}", args.cloud.display()))?;
        return print_all(args, &network);
    }
    let cloud = Cloud::new(&points).with_context(|| format!("{}", args.cloud.display()))?;
    let fits = vec![fit_cylinder(&cloud, &config)?];
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

#[derive(Serialize)]
struct SegmentOut<'a> {
    #[serde(flatten)]
    fit: FitOut,
    start: [f64; 3],
    end: [f64; 3],
    length_m: f64,
    nominal: &'a pipemeasure::measure::NominalSize,
}

/// `--all`: the pipe network's engine ([`pipemeasure::measure::extract_network`]): every pipe
/// once, as straight segments, walls and boxes refused (`pipemeasure pipes` says why).
fn print_all(args: &Args, network: &Network) -> Result<()> {
    if network.segments.is_empty() {
        return Err(
            anyhow::Error::new(pipemeasure::measure::CylinderError::NotFound {
                best: network.refused.iter().map(|r| r.inliers).max().unwrap_or(0),
                required: 1,
            })
            .context(format!(
                "{}: no pipe ({} candidates refused; `pipemeasure pipes` lists why)",
                args.cloud.display(),
                network.refused.len()
            )),
        );
    }
    for g in &network.segments {
        let (a, d, l) = g.axis();
        let f = FitOut {
            radius_m: g.radius_m,
            radius_std_m: g.radius_std_m,
            rmse_m: g.rmse_m,
            inliers: g.inliers,
            axis: Axis {
                point: a.into(),
                direction: d.into(),
            },
        };
        if args.json {
            let out = SegmentOut {
                fit: f,
                start: g.start,
                end: g.end,
                length_m: l,
                nominal: &g.nominal,
            };
            outln!("{}", serde_json::to_string(&out)?);
        } else {
            outln!(
                "radius {:.2} ± {:.2} mm, RMSE {:.2} mm, {} inliers; axis from ({:.4}, {:.4}, {:.4}) to ({:.4}, {:.4}, {:.4}), {:.3} m",
                g.radius_m * 1e3,
                g.radius_std_m * 1e3,
                g.rmse_m * 1e3,
                g.inliers,
                g.start[0],
                g.start[1],
                g.start[2],
                g.end[0],
                g.end[1],
                g.end[2],
                l
            );
        }
    }
    Ok(())
}
