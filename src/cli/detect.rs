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
    #[arg(long, default_value_t = 3.0, value_parser = values::semi_minor_px)]
    min_semi_minor: f64,
    /// Only targets of this polarity: `dark` (black discs on white, as a dot calibration grid)
    /// or `light`; both when not given.
    #[arg(long, value_enum)]
    polarity: Option<Polarity>,
}

/// `--polarity`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Polarity {
    Dark,
    Light,
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
        polarity: args.polarity.map(|p| match p {
            Polarity::Dark => DiscPolarity::Dark,
            Polarity::Light => DiscPolarity::Light,
        }),
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
    let results: Vec<Result<Detection>> = args
        .frames
        .par_iter()
        .map_init(
            || Detector::new(config.clone()),
            |detector, path| {
                let detector = detector.as_mut().map_err(|e| anyhow::anyhow!("{e}"))?;
                let frame = read_frame(path)?;
                let detection = detector.detect(&frame);
                if let Some(dir) = overlay_dir.as_ref().map(StagedDir::path) {
                    let stem = path
                        .file_stem()
                        .map(|s| s.to_string_lossy().into_owned())
                        .unwrap_or_default();
                    write_png(
                        &dir.join(format!("{stem}.png")),
                        &DynamicImage::ImageRgb8(overlay(&frame, &detection)),
                    )?;
                }
                progress.inc(1);
                Ok(detection)
            },
        )
        .collect();
    progress.finish_and_clear();
    let mut found = 0;
    for (path, result) in args.frames.iter().zip(results) {
        let detection =
            result.with_context(|| format!("detecting targets in {}", path.display()))?;
        found += detection.ellipses.len();
        if args.json {
            let out = FrameOutput {
                frame: path.display().to_string(),
                detection: &detection,
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
