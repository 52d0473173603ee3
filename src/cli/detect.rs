//! `pipemeasure detect [--json] [--overlay DIR] FRAME...`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use image::{DynamicImage, Rgb, RgbImage};
use pipemeasure::detect::{DetectConfig, Detection, Detector, DiscPolarity};
use pipemeasure::io::atomic::StagedDir;
use pipemeasure::io::frames::{read_frame, write_png};
use rayon::prelude::*;
use serde::Serialize;

use super::progress::bar;
use super::{Globals, NothingFound, values};

/// Arguments of `detect`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Frames (PNG, JPEG, TIFF, BMP; any bit depth and colour type).
    #[arg(required = true)]
    frames: Vec<PathBuf>,
    /// Print one JSON object per frame (JSON Lines) instead of a summary.
    #[arg(long)]
    json: bool,
    /// Write each frame with the detected ellipses drawn into this folder (PNG).
    #[arg(long)]
    overlay: Option<PathBuf>,
    /// Smallest semi-minor axis to report (px, at least 1).
    #[arg(long, default_value_t = pipemeasure::detect::MIN_SEMI_MINOR_PX, value_parser = values::semi_minor_px)]
    min_semi_minor: f64,
    /// Only targets of this polarity: `dark` (black discs on white, as a dot calibration grid),
    /// `light`, or `both` whatever their numbers. When not given, both, except that a polarity
    /// making up at most 5 % of all the frames' detections is dropped as the stray round things
    /// around a field printed the other way (white pins beside black dots).
    #[arg(long, value_enum)]
    polarity: Option<Polarity>,
}

/// `--polarity`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Polarity {
    Dark,
    Light,
    Both,
}

#[derive(Serialize)]
struct FrameOutput<'a> {
    frame: String,
    #[serde(flatten)]
    detection: &'a Detection,
}

pub fn run(args: &Args, globals: Globals) -> Result<()> {
    let config = DetectConfig {
        min_semi_minor_px: args.min_semi_minor,
        polarity: match args.polarity {
            Some(Polarity::Dark) => Some(DiscPolarity::Dark),
            Some(Polarity::Light) => Some(DiscPolarity::Light),
            Some(Polarity::Both) | None => None,
        },
        stray_polarity_share: match args.polarity {
            None => pipemeasure::detect::STRAY_POLARITY_SHARE,
            Some(_) => 0.0,
        },
        ..DetectConfig::default()
    };
    Detector::new(config.clone())?;
    // Overlays go to a folder beside the destination, moved into place once every frame is done.
    let overlay_dir = args.overlay.as_deref().map(StagedDir::new).transpose()?;
    let progress = bar(
        args.frames.len() as u64,
        "detecting",
        globals.quiet || args.json,
    );
    // Frames in parallel, one detector (and its buffers) per worker; results in input order.
    let mut detections: Vec<Detection> = args
        .frames
        .par_iter()
        .map_init(
            || Detector::new(config.clone()),
            |detector, path| {
                let detector = detector.as_mut().map_err(|e| anyhow::anyhow!("{e}"))?;
                let frame = read_frame(path)
                    .with_context(|| format!("detecting targets in {}", path.display()))?;
                progress.inc(1);
                Ok(detector.detect(&frame))
            },
        )
        .collect::<Result<_>>()?;
    progress.finish_and_clear();
    // The stray polarity is judged over every frame given, before anything is drawn.
    pipemeasure::detect::drop_stray_polarity(&mut detections, config.stray_polarity_share);
    if let Some(dir) = overlay_dir.as_ref().map(StagedDir::path) {
        args.frames.par_iter().zip(&detections).try_for_each(
            |(path, detection)| -> Result<()> {
                let frame = read_frame(path)?;
                let stem = path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                write_png(
                    &dir.join(format!("{stem}.png")),
                    &DynamicImage::ImageRgb8(overlay(&frame, detection)),
                )?;
                Ok(())
            },
        )?;
    }
    let mut found = 0;
    for (path, detection) in args.frames.iter().zip(&detections) {
        found += detection.ellipses.len();
        if args.json {
            let out = FrameOutput {
                frame: path.display().to_string(),
                detection,
            };
            outln!("{}", serde_json::to_string(&out)?);
        } else {
            outln!(
                "{}: {} targets ({}x{})",
                path.display(),
                detection.ellipses.len(),
                detection.width,
                detection.height
            );
            for e in &detection.ellipses {
                outln!(
                    "  centre ({:.3}, {:.3}) axes {:.2} x {:.2} px, angle {:.1}°, {:?}, rms {:.3} px, σ {:.4} px",
                    e.cx,
                    e.cy,
                    e.a,
                    e.b,
                    e.theta.to_degrees(),
                    e.polarity,
                    e.rms_px,
                    e.centre_std_px
                );
            }
        }
    }
    if let Some(dir) = overlay_dir {
        dir.commit()?;
    }
    if found == 0 {
        return Err(
            NothingFound(format!("no target found in {} frame(s)", args.frames.len())).into(),
        );
    }
    Ok(())
}

/// The frame with each ellipse drawn in green and its centre marked in red.
fn overlay(frame: &DynamicImage, detection: &Detection) -> RgbImage {
    let mut img = frame.to_rgb8();
    let (w, h) = (img.width() as i64, img.height() as i64);
    let mut put = |x: f64, y: f64, c: Rgb<u8>| {
        let (px, py) = ((x - 0.5).round() as i64, (y - 0.5).round() as i64);
        if px >= 0 && py >= 0 && px < w && py < h {
            img.put_pixel(px as u32, py as u32, c);
        }
    };
    for d in &detection.ellipses {
        let e = d.ellipse();
        let n = (e.a * 8.0).clamp(64.0, 4000.0) as usize;
        for k in 0..n {
            let p = e.point(std::f64::consts::TAU * k as f64 / n as f64);
            put(p.x, p.y, Rgb([0, 255, 0]));
        }
        for k in -3..=3 {
            put(e.cx + f64::from(k), e.cy, Rgb([255, 0, 0]));
            put(e.cx, e.cy + f64::from(k), Rgb([255, 0, 0]));
        }
    }
    img
}
