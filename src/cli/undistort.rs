//! `pipemeasure undistort --device NAME IN_DIR OUT_DIR`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use pipemeasure::camera::undistort_map::{Interpolation, OutputView, RemapTable, pinhole_for_view};
use pipemeasure::io::colmap::{CameraId, ColmapCamera, ColmapModel, write_cameras_text};
use pipemeasure::io::frames::{list_frames, read_frame, write_png};
use pipemeasure::profile::load_device;
use rayon::prelude::*;

use super::Globals;
use super::progress::bar;

/// Arguments of `undistort`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Device profile: a name (looked up in $PIPEMEASURE_CALIBRATIONS, then ./calibrations/) or
    /// a path to a profile file.
    #[arg(long)]
    device: String,
    /// Folder of frames (PNG, JPEG, TIFF, BMP).
    input: PathBuf,
    /// Output folder for the undistorted PNG frames and cameras.txt (created if missing).
    output: PathBuf,
    /// Output camera: `same` keeps c and the principal point; `valid` is the largest view with
    /// no black border; `full` keeps every source pixel.
    #[arg(long, value_enum, default_value = "same")]
    view: ViewArg,
    /// Interpolation kernel.
    #[arg(long, value_enum, default_value = "bicubic")]
    interpolation: InterpolationArg,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum ViewArg {
    Same,
    Valid,
    Full,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum InterpolationArg {
    Bicubic,
    Bilinear,
}

pub fn run(args: &Args, globals: Globals) -> Result<()> {
    let (profile_path, profile) = load_device(&args.device)?;
    let frames = list_frames(&args.input).context("listing the frames to undistort")?;
    let camera = profile.camera();

    // Check every frame's size before writing anything.
    for f in &frames {
        let (w, h) = image::image_dimensions(f)
            .with_context(|| format!("reading the size of frame {}", f.display()))?;
        if (w, h) != (camera.width, camera.height) {
            bail!(
                "frame {} is {w}x{h} but device profile {} ({}) is for {}x{} frames",
                f.display(),
                profile.device,
                profile_path.display(),
                camera.width,
                camera.height
            );
        }
    }

    let view = match args.view {
        ViewArg::Same => OutputView::Same,
        ViewArg::Valid => OutputView::Valid,
        ViewArg::Full => OutputView::Full,
    };
    let interpolation = match args.interpolation {
        InterpolationArg::Bicubic => Interpolation::Bicubic,
        InterpolationArg::Bilinear => Interpolation::Bilinear,
    };
    let target = pinhole_for_view(&camera, view)
        .with_context(|| format!("choosing the output view for {}", profile_path.display()))?;
    let table = RemapTable::new(&camera, target, interpolation);

    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating the output folder {}", args.output.display()))?;
    let progress = bar(frames.len() as u64, "undistorting", globals.quiet);
    frames.par_iter().try_for_each(|f| -> Result<()> {
        let frame = read_frame(f)?;
        let out = table
            .apply(&frame)
            .with_context(|| format!("undistorting {}", f.display()))?;
        write_png(&output_name(&args.output, f), &out)?;
        progress.inc(1);
        Ok(())
    })?;
    progress.finish_and_clear();

    let pinhole = ColmapCamera {
        model: ColmapModel::Pinhole,
        width: u64::from(target.width),
        height: u64::from(target.height),
        params: vec![target.fx, target.fy, target.cx, target.cy],
    };
    let cameras_txt = args.output.join("cameras.txt");
    write_cameras_text(&cameras_txt, &BTreeMap::from([(CameraId(1), pinhole)]))?;
    outln!(
        "undistorted {} frames with {} into {}\nPINHOLE camera: fx {:.4} fy {:.4} cx {:.4} cy {:.4} ({})",
        frames.len(),
        profile.device,
        args.output.display(),
        target.fx,
        target.fy,
        target.cx,
        target.cy,
        cameras_txt.display()
    );
    Ok(())
}

/// `OUT/stem.png` for an input frame.
fn output_name(out_dir: &Path, frame: &Path) -> PathBuf {
    let stem = frame
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    out_dir.join(format!("{stem}.png"))
}
