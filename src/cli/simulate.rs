//! `pipemeasure simulate lab|site --like DEVICE --out DIR`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use pipemeasure::sim::devices::preset;
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::render::RenderConfig;
use pipemeasure::sim::simulate::{
    SfmSource, SimulateOptions, SiteOptions, simulate_lab, simulate_site,
};

use super::progress::bar;
use super::{Globals, usage, values};

/// `simulate` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// The calibration lab: a room corner with circular targets, the ladder path of the paper.
    Lab(LabArgs),
    /// A pipe site: mock pipes before a target wall, a path around the pipe of interest, dense
    /// observations, the dense cloud, a TLS scan and TLS target coordinates.
    Site(SiteArgs),
}

/// Options shared by the scenes.
#[derive(Debug, clap::Args)]
pub struct Common {
    /// Device preset to imitate: p30, iphone11 or s10.
    #[arg(long, default_value = "p30")]
    like: String,
    /// Output folder (frames/, truth.json, sparse/).
    #[arg(long)]
    out: PathBuf,
    /// Frame width in pixels, 64–8192 (intrinsics scale with it; the height follows the 16:9
    /// aspect).
    #[arg(long, default_value_t = 3840, value_parser = clap::value_parser!(u32).range(64..=8192))]
    width: u32,
    /// Frame height in pixels (default: from the width).
    #[arg(long)]
    height: Option<u32>,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Stratified samples per axis at edges (N×N), 1–16.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=16))]
    samples: u32,
    /// Supersample every pixel instead of only those with an edge.
    #[arg(long)]
    no_adaptive: bool,
    /// σ of the Gaussian optical blur (px, 0 or more).
    #[arg(long, default_value_t = 0.7, value_parser = values::non_negative)]
    blur: f64,
    /// Read noise σ (8-bit levels, 0 or more).
    #[arg(long, default_value_t = 1.0, value_parser = values::non_negative)]
    read_noise: f64,
    /// Shot noise: variance per grey level of signal (0 or more).
    #[arg(long, default_value_t = 0.02, value_parser = values::non_negative)]
    shot_noise: f64,
    /// Brightness loss at the image corners (0 to below 1).
    #[arg(long, default_value_t = 0.25, value_parser = values::below_one)]
    vignetting: f64,
    /// Write JPEG frames with this quality (1–100) instead of PNG.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=100))]
    jpeg_quality: Option<u8>,
    /// Sparse model: the simulated stand-in, or the real COLMAP run on the frames.
    #[arg(long, value_enum, default_value = "stand-in")]
    sfm: SfmArg,
    /// Replace an existing simulation in the output folder.
    #[arg(long)]
    force: bool,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum SfmArg {
    StandIn,
    Colmap,
}

/// `simulate lab`.
#[derive(Debug, clap::Args)]
pub struct LabArgs {
    #[command(flatten)]
    common: Common,
    /// Number of frames (half portrait going up, half landscape coming down).
    #[arg(long, default_value_t = 90)]
    frames: usize,
    /// Approximate number of targets on the two walls.
    #[arg(long, default_value_t = 200)]
    targets: usize,
    /// Leave out the floor.
    #[arg(long)]
    no_floor: bool,
}

/// `simulate site`.
#[derive(Debug, clap::Args)]
pub struct SiteArgs {
    #[command(flatten)]
    common: Common,
    /// Number of frames (half portrait, half landscape).
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Number of targets on the wall.
    #[arg(long, default_value_t = 8)]
    targets: usize,
    /// σ of the dense observations (px, 0 or more).
    #[arg(long, default_value_t = 0.3, value_parser = values::non_negative)]
    dense_noise: f64,
    /// Offset added to the TLS coordinates, e.g. 500000,5600000,0 (site coordinates).
    #[arg(long, value_parser = values::point)]
    tls_offset: Option<nalgebra::Vector3<f64>>,
}

fn options(c: &Common) -> Result<SimulateOptions> {
    let Some(p) = preset(&c.like) else {
        return Err(usage(format!(
            "--like {}: unknown device preset; presets: p30, iphone11, s10",
            c.like
        )));
    };
    let height = c.height.unwrap_or_else(|| {
        (f64::from(c.width) * f64::from(p.camera.height) / f64::from(p.camera.width)).round() as u32
    });
    Ok(SimulateOptions {
        device: c.like.clone(),
        width: c.width,
        height,
        seed: c.seed,
        render: RenderConfig {
            samples: c.samples,
            adaptive: !c.no_adaptive,
            blur_sigma_px: c.blur,
            read_noise_dn: c.read_noise,
            shot_noise: c.shot_noise,
            vignetting: c.vignetting,
            jpeg_quality: c.jpeg_quality,
            ..RenderConfig::default()
        },
        sfm_source: match c.sfm {
            SfmArg::StandIn => SfmSource::StandIn,
            SfmArg::Colmap => SfmSource::Colmap,
        },
        command: std::env::args().collect::<Vec<_>>().join(" "),
        ..SimulateOptions::default()
    })
}

fn check_out(c: &Common) -> Result<()> {
    if c.out.join("truth.json").exists() && !c.force {
        bail!(
            "{} already holds a simulation; pass --force to replace it",
            c.out.display()
        );
    }
    Ok(())
}

pub fn run(cmd: &Command, globals: Globals) -> Result<()> {
    match cmd {
        Command::Lab(args) => {
            check_out(&args.common)?;
            let opts = options(&args.common)?;
            let lab = LabConfig {
                frames: args.frames,
                targets: args.targets,
                floor: !args.no_floor,
                ..LabConfig::default()
            };
            // Every value comes from an option: what the simulator refuses is a usage error.
            opts.validate().map_err(|e| usage(e.to_string()))?;
            lab.validate().map_err(|e| usage(e.to_string()))?;
            let progress = bar(args.frames as u64, "rendering", globals.quiet);
            let truth = simulate_lab(&opts, &lab, &args.common.out, &|done| {
                progress.set_position(done as u64)
            })
            .with_context(|| format!("simulating a lab into {}", args.common.out.display()))?;
            progress.finish_and_clear();
            let visible: usize = truth.frames.iter().map(|f| f.targets.len()).sum();
            outln!(
                "simulated lab: {} frames {}x{} ({}), {} targets, {:.1} visible per frame, sparse model: {} ({} points)\nwritten to {}",
                truth.frames.len(),
                truth.camera.width,
                truth.camera.height,
                truth.camera.device,
                truth.targets.len(),
                visible as f64 / truth.frames.len() as f64,
                truth.sfm.as_ref().map_or("none", |s| s.source.as_str()),
                truth.sfm.as_ref().map_or(0, |s| s.points),
                args.common.out.display()
            );
        }
        Command::Site(args) => {
            check_out(&args.common)?;
            let opts = options(&args.common)?;
            let mut site = SiteOptions::default();
            site.site.frames = args.frames;
            site.site.targets = args.targets;
            site.dense.noise_px = args.dense_noise;
            if let Some(o) = args.tls_offset {
                site.tls.offset = o.into();
            }
            opts.validate().map_err(|e| usage(e.to_string()))?;
            site.site.validate().map_err(|e| usage(e.to_string()))?;
            let progress = bar(args.frames as u64, "rendering", globals.quiet);
            let truth = simulate_site(&opts, &site, &args.common.out, &|done| {
                progress.set_position(done as u64)
            })
            .with_context(|| format!("simulating a site into {}", args.common.out.display()))?;
            progress.finish_and_clear();
            let pipe = truth.pipes.iter().find(|p| p.of_interest);
            let dense = truth.dense.as_ref();
            outln!(
                "simulated site: {} frames {}x{} ({}), {} targets, pipe of interest {} (r = {:.2} mm)\ndense: {} points, {} observations, fused cloud {} points; TLS scan {} points\nwritten to {}",
                truth.frames.len(),
                truth.camera.width,
                truth.camera.height,
                truth.camera.device,
                truth.targets.len(),
                pipe.map_or("?", |p| p.name.as_str()),
                pipe.map_or(0.0, |p| p.radius * 1000.0),
                dense.map_or(0, |d| d.points),
                dense.map_or(0, |d| d.observations),
                dense.map_or(0, |d| d.fused_points),
                truth.tls.as_ref().map_or(0, |t| t.points),
                args.common.out.display()
            );
        }
    }
    Ok(())
}
