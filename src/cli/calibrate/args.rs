//! The options of `pipemeasure calibrate`.

use std::path::{Path, PathBuf};

use pipemeasure::io::colmap::ColmapOptions;

use super::super::values;

/// Arguments of `calibrate`.
#[derive(Clone, Debug, clap::Args)]
pub struct Args {
    /// Device name (a name, not a path): the profile is written as `NAME.json` in the user's
    /// data folder (`~/.local/share/pipemeasure/calibrations` on Linux), or in
    /// $PIPEMEASURE_CALIBRATIONS when it is set, unless `--out` says otherwise.
    #[arg(long)]
    pub(super) device: String,
    /// Folder of the lab video's frames (image names in the SfM model are relative to it). With
    /// `--video`, where the chosen frames are written (default: `VIDEO_STEM_frames` beside the
    /// video; it must not hold frames already).
    #[arg(long, required_unless_present = "video")]
    pub(super) frames: Option<PathBuf>,
    /// The lab video itself: decoded with ffmpeg; per second the frame that moves least and is
    /// sharpest is chosen and written with its two neighbours in the video and
    /// `frames.json` (which the rolling-shutter readout estimate uses).
    #[arg(long, conflicts_with = "sfm")]
    pub(super) video: Option<PathBuf>,
    /// With `--video`: frames chosen per second (1 to 30; each the best of its 1/N s).
    #[arg(long, value_name = "N", requires = "video", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=30))]
    pub(super) per_second: u32,
    /// With `--video`: plain extraction at this rate instead of the choice (`1fps` or `1`: the
    /// frame nearest every second, the paper's extraction).
    #[arg(long, value_name = "RATE", requires = "video", conflicts_with = "per_second",
          value_parser = values::frame_rate)]
    pub(super) every_frame_at: Option<f64>,
    /// COLMAP sparse model of the frames (text or binary). Without it, COLMAP is run (CPU
    /// features, sequential matcher, mapper) into `--work`.
    #[arg(long)]
    pub(super) sfm: Option<PathBuf>,
    /// COLMAP's work folder when `--sfm` is not given (default: `FRAMES/../colmap`).
    #[arg(long)]
    pub(super) work: Option<PathBuf>,
    /// Without `--sfm`: the longest side (px) COLMAP extracts its features at (larger frames
    /// are downsized for it; the model only starts the calibration). COLMAP's own default is
    /// 3200.
    #[arg(long, value_name = "PX", default_value_t = ColmapOptions::default().max_image_size,
          value_parser = clap::value_parser!(u32).range(256..=16384))]
    pub(super) colmap_image_size: u32,
    /// Where to write the profile (default `DEVICE.json` in the user's data folder, or in
    /// $PIPEMEASURE_CALIBRATIONS when it is set).
    #[arg(long)]
    pub(super) out: Option<PathBuf>,
    /// Replace an existing profile (the old one is kept as a numbered backup, `PATH.1.bak`,
    /// `PATH.2.bak`, …).
    #[arg(long)]
    pub(super) force: bool,
    /// Write plots (SVG), `report.json` and `report.md` into this folder.
    #[arg(long)]
    pub(super) report: Option<PathBuf>,
    /// Also calibrate on two disjoint halves of the frames (alternate frames) and report how
    /// much their projections differ over the image.
    #[arg(long)]
    pub(super) cross_validate: bool,
    /// Smallest semi-minor axis of a target to use (px, at least 1).
    #[arg(long, default_value_t = pipemeasure::detect::MIN_SEMI_MINOR_TO_MEASURE_PX, value_parser = values::semi_minor_px)]
    pub(super) min_semi_minor: f64,
    /// Cap on matching/adjustment iterations (at least 1). Simulated labs stop in 2–3; real
    /// videos' matches change by a few views at the gate for longer (BoofCV's hexagonal video:
    /// 7 iterations until the camera moved by less than a tenth of its σ).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u16).range(1..))]
    pub(super) max_iterations: u16,
    /// Write the adjusted network as a COLMAP model (text) into this folder: the profile's
    /// camera, the images at their adjusted poses, the targets as points3D.
    #[arg(long)]
    pub(super) network: Option<PathBuf>,
    /// Reference coordinates of the targets (`id,x,y,z` in metres, any frame; ids need not
    /// match): the object-space accuracy of the adjusted targets after a 7-parameter
    /// similarity, in the report and on stdout.
    #[arg(long)]
    pub(super) check_points: Option<PathBuf>,
    /// σ per axis of the check points (m, 0 or more), for the predicted RMS.
    #[arg(long, default_value_t = 0.0, value_parser = values::non_negative)]
    pub(super) check_point_sigma: f64,
    /// The rolling-shutter model (a motion per frame and the readout time): `auto` lets the
    /// term selection keep it when the frames show it (significant and lowering the BIC),
    /// `off` leaves it out (a global-shutter camera).
    #[arg(long, value_enum, default_value_t = RollingShutterMode::Auto)]
    pub(super) rolling_shutter: RollingShutterMode,
    /// The readout time (ms), when known (a device's data sheet, an earlier calibration): held
    /// at this value. Without it the readout time is estimated from the frames' neighbours in
    /// the video listed in `FRAMES/frames.json`, or held at 25 ms when there are none (the
    /// camera is then still right: only readout × velocity shows in one frame).
    #[arg(long, value_name = "MS", value_parser = values::readout_ms)]
    pub(super) readout_time: Option<f64>,
}

impl Args {
    /// The frames folder (given, or where `--video`'s frames were written).
    pub(super) fn frames(&self) -> &Path {
        self.frames.as_deref().unwrap_or(Path::new("."))
    }
}

/// `--rolling-shutter` (of `calibrate` and of the main command).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum RollingShutterMode {
    /// Calibration: tried by the term selection, kept when significant. Site: modelled when
    /// the readout time is known (the profile's, or `--readout-time`).
    #[default]
    Auto,
    /// Left out.
    Off,
}
