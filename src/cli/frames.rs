//! `pipemeasure frames VIDEO [--out DIR] [--per-second N | --every-frame-at RATE]
//! [--neighbours]`: the frames of a video chosen as `calibrate --video` chooses them (per 1/N s
//! the frame that moves least and is sharpest), for the site's video before COLMAP; and the
//! writing and logging both share.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use pipemeasure::video::{FrameChoice, extract_frames};

use super::{Globals, progress, values};

/// Arguments of `frames`.
#[derive(Clone, Debug, clap::Args)]
pub struct Args {
    /// The video (anything ffmpeg decodes).
    pub video: PathBuf,
    /// Where the chosen frames go (default: `VIDEO_STEM_frames` beside the video; it must not
    /// hold frames already). Give it to COLMAP as the image folder.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Frames chosen per second (1 to 30; each the best of its 1/N s).
    #[arg(long, value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=30))]
    per_second: u32,
    /// Plain extraction at this rate instead of the choice (`1fps` or `1`: the frame nearest
    /// every second, the paper's extraction).
    #[arg(long, value_name = "RATE", conflicts_with = "per_second",
          value_parser = values::frame_rate)]
    every_frame_at: Option<f64>,
    /// Also write each frame's two neighbours in the video into `OUT/neighbours/` (what
    /// `calibrate` estimates the readout time from; a site needs none, and COLMAP reads
    /// sub-folders: give it `OUT/frames.json`'s frames only then).
    #[arg(long)]
    neighbours: bool,
}

/// The default frames folder of `video`: `VIDEO_STEM_frames` beside it.
pub fn default_dir(video: &Path) -> PathBuf {
    let stem = video
        .file_stem()
        .map_or_else(|| "video".into(), |s| s.to_string_lossy().into_owned());
    video
        .parent()
        .unwrap_or(Path::new("."))
        .join(format!("{stem}_frames"))
}

/// Chooses the frames of `video` by `rule` and writes them into `dir` (with their neighbours
/// when asked), logging each chosen frame's motion and sharpness and the warnings.
pub fn write_video_frames(
    video: &Path,
    dir: &Path,
    rule: FrameChoice,
    neighbours: bool,
    quiet: bool,
) -> Result<()> {
    if !video.is_file() {
        bail!("{}: no such file", video.display());
    }
    let bar = progress::bar(0, "decoding the video", quiet);
    let extraction = extract_frames(video, dir, rule, neighbours, &|done, total| match total {
        None => bar.set_position(done as u64),
        Some(total) => {
            bar.set_message("writing the chosen frames");
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
    })
    .with_context(|| video.display().to_string())?;
    bar.finish_and_clear();
    let record = &extraction.record;
    if !quiet {
        let chosen: Vec<_> = record.frames.iter().filter(|f| f.chosen).collect();
        let (chosen_motion, plain_motion) = record.mean_motion_px();
        eprintln!(
            "{}: {} video frames of {}x{} at {:.3} fps; {} chosen ({}) into {}: mean motion {:.2} px per video frame (plain 1 fps extraction: {:.2})",
            video.display(),
            record.frames.len(),
            record.info.width,
            record.info.height,
            record.info.fps,
            chosen.len(),
            record.rule,
            dir.display(),
            chosen_motion,
            plain_motion,
        );
        for (i, f) in chosen.iter().enumerate() {
            eprintln!(
                "  frame_{:04}.png: video frame {} at {:.3} s, motion {}, sharpness {:.1}",
                i + 1,
                f.index,
                f.time_s,
                f.motion_px
                    .map_or_else(|| "not measured".into(), |m| format!("{m:.2} px/frame")),
                f.sharpness
            );
        }
    }
    for w in &extraction.warnings {
        eprintln!("warning: {w}");
    }
    Ok(())
}

/// The frame-choice rule of the options.
pub fn rule(per_second: u32, every_frame_at: Option<f64>) -> FrameChoice {
    match every_frame_at {
        Some(rate) => FrameChoice::EveryFrameAt(rate),
        None => FrameChoice::PerSecond(per_second),
    }
}

/// Runs `frames`.
pub fn run(args: &Args, globals: Globals) -> Result<()> {
    let dir = args.out.clone().unwrap_or_else(|| default_dir(&args.video));
    write_video_frames(
        &args.video,
        &dir,
        rule(args.per_second, args.every_frame_at),
        args.neighbours,
        globals.quiet,
    )
}
