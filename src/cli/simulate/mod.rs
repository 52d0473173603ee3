//! `pipemeasure simulate lab|site --like DEVICE --out DIR`.

use std::path::Path;

use anyhow::{Context, Result, bail};
use pipemeasure::sim::dense::NoiseDirection;
use pipemeasure::sim::lab::{LabConfig, WallTexture};
use pipemeasure::sim::plant::{PlantLayout, PlantScanConfig, simulate_plant};
use pipemeasure::sim::simulate::{
    SimError, SimulateOptions, SiteOptions, frames_to_render, simulate_lab, simulate_site,
};
use pipemeasure::sim::site::SiteConfig;
use pipemeasure::sim::truth::Truth;
use pipemeasure::sim::video::speeds;

mod args;

pub use args::Command;
use args::{Common, Layout, NoiseAlong, PlantLayoutArg, WallTextureArg, options};

use super::Globals;
use super::progress::bar;
use super::usage;

/// What the video added, for the summary line.
fn video_summary(truth: &Truth) -> String {
    let Some(v) = &truth.video else {
        return String::new();
    };
    let speeds: Vec<(f64, f64)> = truth
        .frames
        .iter()
        .filter_map(|f| f.motion.as_ref().map(speeds))
        .collect();
    let n = speeds.len().max(1) as f64;
    let mut text = format!(
        "\nvideo: readout {:.1} ms, exposure {:.1} ms, at the frames {:.1} °/s and {:.3} m/s on average{}{}",
        v.readout_s * 1e3,
        v.exposure_s * 1e3,
        speeds.iter().map(|s| s.0).sum::<f64>() / n,
        speeds.iter().map(|s| s.1).sum::<f64>() / n,
        if v.focus_breathing_m > 0.0 {
            ", focus breathing"
        } else {
            ""
        },
        if truth.frames.iter().any(|f| !f.neighbours.is_empty()) {
            ", neighbours in frames/neighbours"
        } else {
            ""
        },
    );
    if let Some(full) = &v.full_rate {
        let place = match (full.streamed, full.mp4.as_deref()) {
            (true, Some(m)) => format!("streamed into {m} (no PNG)"),
            (_, Some(m)) => format!("in video/, {m}"),
            (_, None) => "in video/".to_string(),
        };
        text += &format!(
            "\nfull-rate video: {} frames {}x{} at {} fps {place}",
            full.frames, full.width, full.height, v.frame_rate,
        );
    }
    text
}

/// Warns on stderr when the full-rate video could not be encoded.
fn warn_encoding(truth: &Truth) {
    if let Some(note) = truth
        .video
        .as_ref()
        .and_then(|v| v.full_rate.as_ref())
        .and_then(|f| f.note.as_ref())
    {
        eprintln!("warning: no video.mp4: {note}");
    }
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

/// Renders a lab or a site (`what`) of `frames` frames into `out` with a progress bar over
/// every frame rendered, and warns when its full-rate video could not be encoded.
fn rendered(
    opts: &SimulateOptions,
    frames: usize,
    what: &str,
    out: &Path,
    globals: Globals,
    simulate: impl FnOnce(&(dyn Fn(usize) + Sync)) -> Result<Truth, SimError>,
) -> Result<Truth> {
    let total = frames_to_render(opts, frames).unwrap_or(frames);
    let progress = bar(total as u64, "rendering", globals.quiet);
    let truth = simulate(&|done| progress.set_position(done as u64))
        .with_context(|| format!("simulating a {what} into {}", out.display()))?;
    progress.finish_and_clear();
    warn_encoding(&truth);
    Ok(truth)
}

pub fn run(cmd: &Command, globals: Globals) -> Result<()> {
    match cmd {
        Command::Plant(args) => {
            if args.out.join("truth.json").exists() && !args.force {
                bail!(
                    "{} already holds a simulation; pass --force to replace it",
                    args.out.display()
                );
            }
            let config = PlantScanConfig {
                step_rad: args.step_mrad * 1e-3,
                range_noise_m: args.range_noise_mm * 1e-3,
                stations: usize::from(args.stations),
                ..PlantScanConfig::default()
            };
            if !globals.quiet {
                eprintln!("scanning the plant room from {} stations", args.stations);
            }
            let truth = simulate_plant(
                match args.layout {
                    PlantLayoutArg::RiserHeader => PlantLayout::RiserHeader,
                    PlantLayoutArg::Process => PlantLayout::Process,
                },
                args.seed,
                &config,
                args.e57,
                &args.out,
            )
            .with_context(|| format!("simulating a plant room into {}", args.out.display()))?;
            let [l, w, h] = truth.room;
            outln!(
                "simulated plant room {l:.2} x {w:.2} x {h:.2} m (seed {}): {} pipe segments, {} other objects; TLS scan {} points ({} mixed pixels)\nwritten to {}",
                args.seed,
                truth.segments.len(),
                truth.objects.len(),
                truth.scan.as_ref().map_or(0, |s| s.points),
                truth.scan.as_ref().map_or(0, |s| s.mixed_pixels),
                args.out.display()
            );
        }
        Command::Lab(args) => {
            check_out(&args.common)?;
            let opts = options(&args.common)?;
            let lab = LabConfig {
                frames: args.frames,
                targets: args.targets,
                floor: !args.no_floor,
                wall_texture: match args.wall_texture {
                    WallTextureArg::Plaster => WallTexture::Plaster,
                    WallTextureArg::Speckled => WallTexture::Speckled,
                },
                ..LabConfig::default()
            };
            // Every value comes from an option: what the simulator refuses (the video's options
            // included) is a usage error.
            opts.validate().map_err(|e| usage(e.to_string()))?;
            lab.validate().map_err(|e| usage(e.to_string()))?;
            let truth = rendered(&opts, args.frames, "lab", &args.common.out, globals, |p| {
                simulate_lab(&opts, &lab, &args.common.out, p)
            })?;
            let visible: usize = truth.frames.iter().map(|f| f.targets.len()).sum();
            outln!(
                "simulated lab: {} frames {}x{} ({}), {} targets, {:.1} visible per frame, sparse model: {} ({} points){}\nwritten to {}",
                truth.frames.len(),
                truth.camera.width,
                truth.camera.height,
                truth.camera.device,
                truth.targets.len(),
                visible as f64 / truth.frames.len() as f64,
                truth.sfm.as_ref().map_or("none", |s| s.source.as_str()),
                truth.sfm.as_ref().map_or(0, |s| s.points),
                video_summary(&truth),
                args.common.out.display()
            );
        }
        Command::Site(args) => {
            check_out(&args.common)?;
            let opts = options(&args.common)?;
            let mut site = SiteOptions::default();
            if matches!(args.layout, Layout::TwoPipes) {
                site.site = SiteConfig::two_pipes();
            }
            site.site.frames = args.frames.unwrap_or(site.site.frames);
            site.site.targets = args.targets.unwrap_or(site.site.targets);
            site.dense.noise_px = args.dense_noise;
            site.dense.point_noise_m = args.dense_point_noise * 1e-3;
            site.dense.point_noise_along = match args.dense_noise_along {
                NoiseAlong::Normal => NoiseDirection::Normal,
                NoiseAlong::Ray => NoiseDirection::Ray,
            };
            site.dense.outlier_fraction = args.dense_outliers;
            site.dense.pipe_spacing_at_width_m = args.dense_spacing.map(|mm| mm * 1e-3);
            site.plant = args.plant;
            if let Some(o) = args.tls_offset {
                site.tls.offset = o.into();
            }
            opts.validate().map_err(|e| usage(e.to_string()))?;
            site.site.validate().map_err(|e| usage(e.to_string()))?;
            let frames = site.site.frames;
            let truth = rendered(&opts, frames, "site", &args.common.out, globals, |p| {
                simulate_site(&opts, &site, &args.common.out, p)
            })?;
            let pipe = truth.pipes.iter().find(|p| p.of_interest);
            let dense = truth.dense.as_ref();
            let (what, content, room) = if args.plant {
                (
                    "plant-room site",
                    " on boards".to_string(),
                    " (plant.json: the room's pipe segments)",
                )
            } else {
                (
                    "site",
                    format!(
                        ", pipe of interest {} (r = {:.2} mm)",
                        pipe.map_or("?", |p| p.name.as_str()),
                        pipe.map_or(0.0, |p| p.radius * 1000.0)
                    ),
                    "",
                )
            };
            outln!(
                "simulated {what}: {} frames {}x{} ({}), {} targets{content}\ndense: {} points, {} observations, fused cloud {} points; TLS scan {} points{}\nwritten to {}{room}",
                truth.frames.len(),
                truth.camera.width,
                truth.camera.height,
                truth.camera.device,
                truth.targets.len(),
                dense.map_or(0, |d| d.points),
                dense.map_or(0, |d| d.observations),
                dense.map_or(0, |d| d.fused_points),
                truth.tls.as_ref().map_or(0, |t| t.points),
                video_summary(&truth),
                args.common.out.display()
            );
        }
    }
    Ok(())
}
