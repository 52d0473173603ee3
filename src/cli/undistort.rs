//! `pipemeasure undistort --device NAME IN_DIR OUT_DIR`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use pipemeasure::calibrate::checks::check_distortion;
use pipemeasure::camera::undistort_map::{Interpolation, OutputView, RemapTable, pinhole_for_view};
use pipemeasure::io::atomic::{StagedDir, check_writable_dir};
use pipemeasure::io::colmap::{CameraId, ColmapCamera, ColmapModel, write_cameras_text};
use pipemeasure::io::frames::{first_of_another_size, list_frames, read_frame_sized, write_png};
use pipemeasure::profile::load_device;
use rayon::prelude::*;

use super::Globals;
use super::progress::bar;

/// Arguments of `undistort`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Device profile: a name (looked up in $PIPEMEASURE_CALIBRATIONS, ./calibrations/, the
    /// user's data folder, then the presets built in) or a path to a profile file.
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
    let size = (camera.width, camera.height);
    check_writable_dir(&args.output)?;

    // Every frame's size from its header before anything is decoded or written.
    if let Some((f, (w, h))) =
        first_of_another_size(&frames, size).context("reading the size of a frame")?
    {
        bail!(
            "frame {} is {w}x{h} but device profile {} ({}) is for {}x{} frames",
            f.display(),
            profile.device,
            profile_path.display(),
            camera.width,
            camera.height
        );
    }
    // A distortion that folds back inside the frame cannot be inverted there: the undistorted
    // frames would be black where it folds (all black when it folds everywhere).
    let check = check_distortion(&camera.intrinsics, size);
    if !check.ok {
        bail!(
            "device profile {} ({}): its distortion cannot be inverted over the frame (it folds \
             back from {:.0} px from the principal point; the frame reaches {:.0} px, {} of the \
             checked pixels fail): frames cannot be undistorted with it",
            profile.device,
            profile_path.display(),
            check.first_failure_radius_px.unwrap_or(0.0),
            check.frame_radius_px,
            check.failing_pixels
        );
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

    // Everything goes to a folder beside OUT_DIR and is moved into it at the end: a failure
    // leaves OUT_DIR as it was.
    let staged = StagedDir::new(&args.output)?;
    let progress = bar(frames.len() as u64, "undistorting", globals.quiet);
    frames.par_iter().try_for_each(|f| -> Result<()> {
        let frame = read_frame_sized(f, Some(size))?;
        let out = table
            .apply(&frame)
            .with_context(|| format!("undistorting {}", f.display()))?;
        write_png(&output_name(staged.path(), f), &out)?;
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
    write_cameras_text(
        &staged.path().join("cameras.txt"),
        &BTreeMap::from([(CameraId(1), pinhole)]),
    )?;
    staged.commit()?;
    let cameras_txt = args.output.join("cameras.txt");
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
