//! What `pipemeasure calibrate` reads before the loop: the checks made before minutes of work,
//! the video's frames, the SfM model (given or COLMAP's, with its progress), the detections in
//! the frames' neighbours.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use pipemeasure::calibrate::input::{listed_frames, reconstruct_frames};
use pipemeasure::calibrate::neighbours::detect_neighbours;
use pipemeasure::calibrate::pipeline::NeighbourDetections;
use pipemeasure::detect::DetectConfig;
use pipemeasure::io::atomic::check_writable_dir;
use pipemeasure::io::colmap::{ColmapOptions, ColmapProgress, Reconstruction};
use pipemeasure::io::tls::TlsTarget;
use pipemeasure::io::tools::{Tool, probe};
use pipemeasure::profile::{backup_path, default_profile_folder, validate_device_name};

use super::super::{progress, usage};
use super::{Args, RollingShutterMode};

/// The SfM model: the given one, or COLMAP's.
pub(super) fn sfm_model(args: &Args, quiet: bool) -> Result<Reconstruction> {
    if let Some(dir) = &args.sfm {
        return Reconstruction::read(dir).with_context(|| format!("--sfm {}", dir.display()));
    }
    let work = args.work.clone().unwrap_or_else(|| {
        args.frames()
            .parent()
            .unwrap_or_else(|| Path::new("."))
            .join("colmap")
    });
    // COLMAP's presence was checked in the preflight (and the run checks it again).
    if !quiet {
        eprintln!(
            "running COLMAP (features at up to {} px, sequential matching, mapping) into {}",
            args.colmap_image_size,
            work.display()
        );
    }
    // Only the frames (not a video's neighbours): their count is the registration's goal.
    let listed = listed_frames(args.frames())?.map(|l| l.len());
    let bar = progress::bar(0, "COLMAP", quiet);
    let report = |p: ColmapProgress| match p {
        ColmapProgress::Features { done, of } => {
            bar.set_message("COLMAP features");
            bar.set_length(of as u64);
            bar.set_position(done as u64);
        }
        ColmapProgress::Matching { done, of } => {
            bar.set_message("COLMAP matching");
            bar.set_length(of as u64);
            bar.set_position(done as u64);
        }
        ColmapProgress::Registered { images } => {
            bar.set_message("COLMAP images registered");
            if let Some(n) = listed {
                bar.set_length(n as u64);
            }
            bar.set_position(images as u64);
        }
        _ => {}
    };
    let options = ColmapOptions {
        max_image_size: args.colmap_image_size,
        ..ColmapOptions::default()
    };
    let model = reconstruct_frames(args.frames(), &work, &options, &report);
    bar.finish_and_clear();
    Ok(model?)
}

/// The detections in the frames' neighbours in the video, from `FRAMES/frames.json` when
/// there is one (empty otherwise, or with `--rolling-shutter off` or a held readout time,
/// which do not use them).
pub(super) fn neighbour_detections(
    args: &Args,
    names: &[String],
    size: (u32, u32),
    quiet: bool,
) -> Result<Vec<Vec<NeighbourDetections>>> {
    if args.rolling_shutter == RollingShutterMode::Off || args.readout_time.is_some() {
        return Ok(Vec::new());
    }
    let config = DetectConfig {
        min_semi_minor_px: args.min_semi_minor,
        ..DetectConfig::default()
    };
    let progress = progress::bar(0, "detecting the neighbours", quiet);
    let detected = detect_neighbours(
        args.frames(),
        names,
        size,
        &config,
        &|n| progress.set_length(n as u64),
        &|| progress.inc(1),
    )
    .context("detecting the targets of the frames' neighbours")?;
    progress.finish_and_clear();
    Ok(detected)
}
/// What is checked before minutes of calibration: the device name, the frames or video, the
/// check points (read: a bad file fails first), and every destination writable. Returns the
/// check points and the profile's path.
pub(super) fn preflight(args: &Args) -> Result<(Option<Vec<TlsTarget>>, PathBuf)> {
    validate_device_name(&args.device)
        .map_err(|e| usage(format!("--device: {}", super::super::hints::said(&e))))?;
    match &args.video {
        Some(video) if !video.is_file() => bail!("--video {}: no such file", video.display()),
        None if !args.frames().is_dir() => {
            bail!("--frames {}: not a folder", args.frames().display())
        }
        _ => {}
    }
    // The programs the options need, before minutes of work (`pipemeasure doctor` lists all).
    let needed: &[Tool] = match (&args.video, &args.sfm) {
        (Some(_), None) => &[Tool::Ffmpeg, Tool::Ffprobe, Tool::Colmap],
        (Some(_), Some(_)) => &[Tool::Ffmpeg, Tool::Ffprobe],
        (None, None) => &[Tool::Colmap],
        (None, Some(_)) => &[],
    };
    for &tool in needed {
        if !probe(tool).found() {
            bail!(
                "`{}` is not installed or not on PATH, and it is needed for {} (Debian/Ubuntu: `{}`){}",
                tool.program(),
                tool.needed_for(),
                tool.install(),
                if tool == Tool::Colmap {
                    "; or pass the sparse model of the frames with --sfm DIR"
                } else {
                    "; or extract the frames yourself and pass --frames DIR"
                }
            );
        }
    }
    // Read the check points first: a bad file fails before minutes of calibration.
    let check_list = args
        .check_points
        .as_ref()
        .map(|p| pipemeasure::io::tls::read_targets(p))
        .transpose()?;
    if let (Some(c), Some(p)) = (&check_list, &args.check_points)
        && c.len() < 4
    {
        bail!(
            "{}: {} check point(s); a 7-parameter similarity needs at least 4",
            p.display(),
            c.len()
        );
    }
    let out = match &args.out {
        Some(out) => out.clone(),
        None => default_profile_folder()?
            .path
            .join(format!("{}.json", args.device)),
    };
    if out.exists() && !args.force {
        bail!(
            "{} exists: pass --force to replace it (the old profile is kept as a numbered backup, \
             {}) or --out to write elsewhere",
            out.display(),
            backup_path(&out, 1).display()
        );
    }
    // Every destination before minutes of calibration: the profile's folder is created if
    // missing (the user's data folder), the report's and the network's too.
    check_writable_dir(
        out.parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new(".")),
    )?;
    if out.is_dir() {
        bail!(
            "--out {}: is a folder, expected the profile's file name",
            out.display()
        );
    }
    for dir in [&args.report, &args.network].into_iter().flatten() {
        check_writable_dir(dir)?;
    }
    Ok((check_list, out))
}

/// `--video`: chooses and writes the frames with their neighbours, and returns the arguments
/// with `--frames` set to their folder.
pub(super) fn frames_from_video(args: &Args, video: &Path, quiet: bool) -> Result<Args> {
    let dir = args
        .frames
        .clone()
        .unwrap_or_else(|| super::super::frames::default_dir(video));
    let rule = super::super::frames::rule(args.per_second, args.every_frame_at);
    super::super::frames::write_video_frames(video, &dir, rule, true, quiet)
        .with_context(|| "--video".to_string())?;
    Ok(Args {
        frames: Some(dir),
        video: None,
        ..args.clone()
    })
}
