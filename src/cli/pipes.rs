//! `pipemeasure pipes CLOUD [--json] [--csv FILE] [--ply FILE] [--clearance]
//! [--material M] [--radius-min M --radius-max M] [--seed N] [--device NAME]`: the pipe network
//! of a cloud (with `--device`, a site's photogrammetric cloud scaled from its targets),
//! every pipe once as straight segments, and what was refused.

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Result;
use pipemeasure::io::atomic::StagedFile;
use pipemeasure::io::ply::stage_binary;
use pipemeasure::measure::network::{Clearance, Network, clearances};
use pipemeasure::measure::scan::{Pass, ScanConfig, extract_network_from};
use pipemeasure::measure::site::{CloudSource, SiteRequest, site_network};
use pipemeasure::measure::{CylinderConfig, NetworkConfig, PipeMaterial};
use pipemeasure::report::network::{
    coloured_by_segment, refusals_text, segments_csv, segments_table,
};
use serde::Serialize;

use super::fit_cylinder::{checked, read_points};
use super::progress::{bar, counter};
use super::{Globals, NothingFound, values};

/// Arguments of `pipes`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The point cloud (PLY, or E57 by its extension).
    cloud: PathBuf,
    /// Print the network as JSON (segments, refused candidates, removed planes, clearances).
    #[arg(long)]
    json: bool,
    /// Also write the segments as CSV.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Also write the cloud coloured by segment (grey: no segment) as PLY.
    #[arg(long)]
    ply: Option<PathBuf>,
    /// Print the smallest distance between every pair of segments (surface to surface).
    #[arg(long)]
    clearance: bool,
    /// The material whose standard sizes are reported.
    #[arg(long, value_enum, default_value = "steel")]
    material: MaterialArg,
    /// Smallest pipe radius of interest (m).
    #[arg(long, default_value_t = 0.015, value_parser = values::positive)]
    radius_min: f64,
    /// Largest pipe radius of interest (m): wider curved surfaces (housings, tanks, a wall's
    /// bow) are not pipes.
    #[arg(long, default_value_t = 0.35, value_parser = values::positive)]
    radius_max: f64,
    /// Seed of the sampling.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Most points searched: a larger scan is read in chunks and every n-th point searched
    /// (the same scan at a coarser step), and each pipe found is then re-fitted on every point
    /// of the scan near it. Bounds the memory, whatever the scan's size.
    #[arg(long, default_value_t = ScanConfig::default().search_points, value_parser = at_least_1000)]
    search_points: usize,
    /// A site's photogrammetric cloud, scaled from its targets as the main command does: the
    /// device profile (a name or a path). The cloud is re-triangulated at
    /// the poses re-adjusted to the profile, brought into the TLS frame by the targets, and
    /// searched whole.
    #[arg(long)]
    device: Option<String>,
    /// With --device: the site's SfM model; default `sparse` next to the cloud or up to two
    /// folders above it.
    #[arg(long, requires = "device")]
    sfm: Option<PathBuf>,
    /// With --device: the site's frames; default `images` or `frames` next to the cloud or
    /// up to two folders above it.
    #[arg(long, requires = "device")]
    frames: Option<PathBuf>,
    /// With --device: TLS target coordinates `id,x,y,z` (m); default `tls_targets.csv` next
    /// to the cloud or up to two folders above it.
    #[arg(long, requires = "device")]
    tls_targets: Option<PathBuf>,
    /// With --device: smallest semi-minor axis of a target to use (px, at least 1).
    #[arg(long, default_value_t = pipemeasure::detect::MIN_SEMI_MINOR_TO_MEASURE_PX, value_parser = values::semi_minor_px, requires = "device")]
    min_semi_minor: f64,
}

/// A point budget of at least a thousand points.
fn at_least_1000(s: &str) -> Result<usize, String> {
    let n: usize = s
        .parse()
        .map_err(|e| format!("`{s}` is not a count of points: {e}"))?;
    if n < 1000 {
        return Err(format!("{n} points are too few to search (at least 1000)"));
    }
    Ok(n)
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum MaterialArg {
    /// Carbon steel, ASME B36.10M.
    Steel,
    /// Stainless steel, ASME B36.19M.
    Stainless,
    /// Ductile iron, AWWA C151.
    DuctileIron,
    /// Ductile iron, ISO 2531.
    DuctileIronIso,
}

impl From<MaterialArg> for PipeMaterial {
    fn from(m: MaterialArg) -> Self {
        match m {
            MaterialArg::Steel => PipeMaterial::Steel,
            MaterialArg::Stainless => PipeMaterial::Stainless,
            MaterialArg::DuctileIron => PipeMaterial::DuctileIron,
            MaterialArg::DuctileIronIso => PipeMaterial::DuctileIronIso,
        }
    }
}

#[derive(Serialize)]
struct Output<'a> {
    schema: &'static str,
    cloud: String,
    /// Points in the file (finite or not).
    points_in_file: usize,
    /// Every how many finite points one was searched (1: all).
    search_stride: usize,
    /// How a site's cloud was scaled (with `--device`).
    #[serde(skip_serializing_if = "Option::is_none")]
    scale: Option<&'a ScaleOut>,
    #[serde(flatten)]
    network: &'a Network,
    #[serde(skip_serializing_if = "Option::is_none")]
    clearances: Option<&'a [Clearance]>,
}

fn config(args: &Args) -> Result<ScanConfig> {
    Ok(ScanConfig {
        network: NetworkConfig {
            cylinder: checked(CylinderConfig {
                radius_min: args.radius_min,
                radius_max: args.radius_max,
                seed: args.seed,
                ..NetworkConfig::default().cylinder
            })?,
            material: args.material.into(),
            ..NetworkConfig::default()
        },
        search_points: args.search_points,
        ..ScanConfig::default()
    })
}

/// The network of the cloud, the points searched, the points in the file and the stride: from
/// the scan path, or (with `--device`) from the site's cloud scaled by its targets.
struct Searched {
    network: Network,
    points: Vec<nalgebra::Vector3<f64>>,
    points_in_file: usize,
    stride: usize,
    scale: Option<ScaleOut>,
}

/// How a site's cloud was scaled.
#[derive(Serialize)]
struct ScaleOut {
    /// Metres per cloud unit, and its σ.
    scale: f64,
    scale_std: f64,
    /// The coordinates are the TLS list's (true) or the cloud's own, in metres.
    tls_frame: bool,
    /// TLS targets used.
    targets: Vec<String>,
    /// The cloud re-triangulated at the re-adjusted poses (true) or used as fused.
    retriangulated: bool,
}

fn site(args: &Args, device: &str, config: &ScanConfig, globals: Globals) -> Result<Searched> {
    let log = |message: &str| globals.log(message);
    let request = SiteRequest {
        cloud: args.cloud.clone(),
        device: Some(device.to_string()),
        sfm: args.sfm.clone(),
        frames: args.frames.clone(),
        tls_targets: args.tls_targets.clone(),
        min_semi_minor_px: args.min_semi_minor,
        cylinder: config.network.cylinder.clone(),
        ..SiteRequest::default()
    };
    let points = read_points(&args.cloud, None)?;
    let points_in_file = points.len();
    let progress = bar(0, "detecting", globals.quiet);
    let found = site_network(&request, &points, &config.network, &log, &|total| {
        progress.set_length(total as u64);
        progress.inc(1);
    });
    progress.finish_and_clear();
    let found = found?;
    let (scale, scale_std) = found.scaled.scaling.scale();
    let scale = ScaleOut {
        scale,
        scale_std,
        tls_frame: found.scaled.scaling.in_tls_frame(),
        targets: found
            .scaled
            .targets
            .as_ref()
            .map(|t| t.tls_ids.clone())
            .unwrap_or_default(),
        retriangulated: found.scaled.cloud_source == CloudSource::Retriangulated,
    };
    log(&format!(
        "{}: scale {:.6} ± {:.6} m per unit from {} targets{}; searching {} points",
        args.cloud.display(),
        scale.scale,
        scale.scale_std,
        scale.targets.len(),
        if scale.tls_frame {
            ", in the TLS frame"
        } else {
            ""
        },
        found.points.len()
    ));
    Ok(Searched {
        network: found.network,
        points: found.points,
        points_in_file,
        stride: 1,
        scale: Some(scale),
    })
}

fn scan(args: &Args, config: &ScanConfig, globals: Globals) -> Result<Searched> {
    let bar = counter(&format!("{}: reading", args.cloud.display()), globals.quiet);
    let scan = extract_network_from(&args.cloud, config, &mut |pass, n| {
        if pass == Pass::Bands && bar.message().ends_with("reading") {
            bar.set_message(format!(
                "{}: re-fitting the pipes on every point",
                args.cloud.display()
            ));
        }
        bar.set_position(n as u64);
    });
    bar.finish_and_clear();
    let scan = scan?;
    if !globals.quiet {
        if scan.stride > 1 {
            eprintln!(
                "{}: {} points, every {}th ({}) searched; pipes re-fitted on every point",
                args.cloud.display(),
                scan.read.vertices_in_file,
                scan.stride,
                scan.searched.len()
            );
        } else {
            eprintln!(
                "{}: {} points; removing planes, searching pipes",
                args.cloud.display(),
                scan.searched.len()
            );
        }
    }
    Ok(Searched {
        network: scan.network,
        points: scan.searched,
        points_in_file: scan.read.vertices_in_file,
        stride: scan.stride,
        scale: None,
    })
}

pub fn run(args: &Args, globals: Globals) -> Result<()> {
    let config = config(args)?;
    let found = match &args.device {
        Some(device) => site(args, device, &config, globals)?,
        None => scan(args, &config, globals)?,
    };
    let network = &found.network;
    let pairs = args.clearance.then(|| clearances(&network.segments));
    if args.json {
        let out = Output {
            schema: "pipemeasure.pipes/1",
            cloud: args.cloud.display().to_string(),
            points_in_file: found.points_in_file,
            search_stride: found.stride,
            scale: found.scale.as_ref(),
            network,
            clearances: pairs.as_deref(),
        };
        outln!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        outln!(
            "{} pipe segments in {} points ({} planes removed, {} components searched)",
            network.segments.len(),
            network.points,
            network.planes.len(),
            network.components
        );
        if !network.segments.is_empty() {
            outln!("{}", segments_table(network));
        }
        outln!("{}", refusals_text(network));
        if let Some(pairs) = &pairs {
            for c in pairs {
                outln!("clearance {} – {}: {:.1} mm", c.a, c.b, c.distance_m * 1e3);
            }
        }
    }
    if network.segments.is_empty() {
        // Nothing found: no output file either.
        return Err(NothingFound(format!(
            "{}: no pipe segment ({} candidates refused, {} planes removed)",
            args.cloud.display(),
            network.refused.len(),
            network.planes.len()
        ))
        .into());
    }
    // Files staged first and moved into place together: nothing half-written.
    let mut staged: Vec<StagedFile> = Vec::new();
    if let Some(path) = &args.csv {
        let text = segments_csv(network);
        staged.push(StagedFile::write(path, |w| w.write_all(text.as_bytes()))?);
    }
    if let Some(path) = &args.ply {
        // The points searched (all finite points, or every stride-th), the segments' indices
        // into them.
        staged.push(stage_binary(
            path,
            &coloured_by_segment(&found.points, network),
        )?);
    }
    for file in staged {
        file.commit()?;
    }
    Ok(())
}
