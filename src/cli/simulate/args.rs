//! The options of `pipemeasure simulate` and the simulator's settings they make.

use std::path::PathBuf;

use anyhow::Result;
use pipemeasure::sim::devices::preset;
use pipemeasure::sim::render::RenderConfig;
use pipemeasure::sim::simulate::{SfmSource, SimulateOptions};
use pipemeasure::sim::trajectory::MotionConfig;
use pipemeasure::sim::video::VideoConfig;

use super::super::{usage, values};

/// `simulate` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// The calibration lab: a room corner with circular targets, the ladder path of the paper.
    Lab(LabArgs),
    /// A pipe site: mock pipes before a target wall, a path around the pipe of interest, dense
    /// observations, the dense cloud, a TLS scan and TLS target coordinates.
    Site(SiteArgs),
    /// A plant room: pipe runs with elbows, a tee and a valve, a pump, supports, conduits, a
    /// column, walls, floor and ceiling (parry3d shapes), scanned by a TLS from its stations;
    /// writes tls_scan.ply and truth.json (every pipe segment and every other object).
    Plant(PlantArgs),
}

/// `simulate plant`.
#[derive(Debug, clap::Args)]
pub struct PlantArgs {
    /// Output folder (tls_scan.ply, truth.json; tls_scan.e57 with --e57).
    #[arg(long)]
    pub(super) out: PathBuf,
    /// Seed of the room and of the scan's noise.
    #[arg(long, default_value_t = 1)]
    pub(super) seed: u64,
    /// The room: `riser-header` (a riser and header, a valved header with a tee down to a
    /// pump, a small-bore line) or `process` (a tank with a flanged nozzle and a line welded
    /// into its shell, a reducer, a flange pair, a horizontal tee, a short spool between
    /// elbows, a run resting on a beam).
    #[arg(long, value_enum, default_value_t = PlantLayoutArg::RiserHeader)]
    pub(super) layout: PlantLayoutArg,
    /// Scanner stations, 1–4.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=4))]
    pub(super) stations: u8,
    /// Angular step of the scan (mrad), 0.5–20.
    #[arg(long, default_value_t = 3.0, value_parser = values::step_mrad)]
    pub(super) step_mrad: f64,
    /// Range noise σ (mm).
    #[arg(long, default_value_t = 1.5, value_parser = values::non_negative)]
    pub(super) range_noise_mm: f64,
    /// Also write the scan as E57 (`tls_scan.e57`), one scan per station in the station's own
    /// frame with its pose, as a scanner's software exports it.
    #[arg(long)]
    pub(super) e57: bool,
    /// Replace an existing simulation in --out.
    #[arg(long)]
    pub(super) force: bool,
}

/// `simulate plant --layout`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(super) enum PlantLayoutArg {
    RiserHeader,
    Process,
}

/// Options shared by the scenes.
#[derive(Debug, clap::Args)]
pub struct Common {
    /// Device preset to imitate: p30, iphone11 or s10.
    #[arg(long, default_value = "p30")]
    pub(super) like: String,
    /// Output folder (frames/, truth.json, sparse/).
    #[arg(long)]
    pub(super) out: PathBuf,
    /// Frame width in pixels, 64–8192 (intrinsics scale with it; the height follows the 16:9
    /// aspect).
    #[arg(long, default_value_t = 3840, value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub(super) width: u32,
    /// Frame height in pixels (default: from the width).
    #[arg(long)]
    pub(super) height: Option<u32>,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1)]
    pub(super) seed: u64,
    /// Stratified samples per axis at edges (N×N), 1–16.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub(super) samples: u32,
    /// Supersample every pixel instead of only those with an edge.
    #[arg(long)]
    pub(super) no_adaptive: bool,
    /// σ of the Gaussian optical blur (px, 0 or more).
    #[arg(long, default_value_t = 0.7, value_parser = values::non_negative)]
    pub(super) blur: f64,
    /// Read noise σ (8-bit levels, 0 or more).
    #[arg(long, default_value_t = 1.0, value_parser = values::non_negative)]
    pub(super) read_noise: f64,
    /// Shot noise: variance per grey level of signal (0 or more).
    #[arg(long, default_value_t = 0.02, value_parser = values::non_negative)]
    pub(super) shot_noise: f64,
    /// Brightness loss at the image corners (0 to below 1).
    #[arg(long, default_value_t = 0.25, value_parser = values::below_one)]
    pub(super) vignetting: f64,
    /// Write JPEG frames with this quality (1–100) instead of PNG.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub(super) jpeg_quality: Option<u8>,
    /// Sparse model: the simulated stand-in, or the real COLMAP run on the frames.
    #[arg(long, value_enum, default_value = "stand-in")]
    pub(super) sfm: SfmArg,
    /// Replace an existing simulation in the output folder.
    #[arg(long)]
    pub(super) force: bool,
    #[command(flatten)]
    pub(super) video: VideoArgs,
}

/// Video options (`--video` and the options that need it).
#[derive(Debug, clap::Args)]
pub struct VideoArgs {
    /// Film a hand-held phone video instead of still frames: a continuous trajectory through
    /// the stations, rolling shutter, motion blur; the frames are its 1 fps extraction.
    #[arg(long)]
    pub(super) video: bool,
    /// Rolling-shutter readout time in ms (default: the preset's, 20/25/30 ms; 0 = global
    /// shutter).
    #[arg(long, value_name = "MS", requires = "video", value_parser = parse_ms)]
    pub(super) readout: Option<f64>,
    /// Exposure time in ms (0 = no motion blur).
    #[arg(long, value_name = "MS", requires = "video", default_value = "8", value_parser = parse_ms)]
    pub(super) exposure: f64,
    /// Range of the angular speed at the extracted frames, °/s.
    #[arg(long, value_name = "MIN,MAX", requires = "video", default_value = "3,9", value_parser = parse_range)]
    pub(super) angular_speed: [f64; 2],
    /// Range of the camera's speed at the extracted frames, m/s.
    #[arg(long, value_name = "MIN,MAX", requires = "video", default_value = "0.05,0.15", value_parser = parse_range)]
    pub(super) linear_speed: [f64; 2],
    /// RMS angular rate of the hand tremor, °/s (0 = none).
    #[arg(long, value_name = "DEG_S", requires = "video", default_value_t = 0.5, value_parser = values::non_negative)]
    pub(super) tremor: f64,
    /// Length of the pause between two extracted frames, s (0 = none).
    #[arg(long, value_name = "S", requires = "video", default_value_t = 0.2, value_parser = values::non_negative)]
    pub(super) pause: f64,
    /// Autofocus on: the principal distance follows the focus distance (the preset's lens).
    #[arg(long, requires = "video")]
    pub(super) focus_breathing: bool,
    /// Also render each extracted frame's two neighbours in the video (t ± 1/fps) into
    /// frames/neighbours/, listed in frames/frames.json.
    #[arg(long, requires = "video")]
    pub(super) neighbours: bool,
    /// Video frame rate; given, also renders the full-rate video at --video-width into
    /// video/frame_%05d.png with video/motion.json (and video.mp4 when ffmpeg is installed).
    #[arg(long, value_name = "N", requires = "video", value_parser = parse_fps)]
    pub(super) fps: Option<f64>,
    /// Width of the full-rate video (px).
    #[arg(long, value_name = "W", requires = "fps", default_value_t = 320)]
    pub(super) video_width: u32,
    /// Pipe the full-rate frames straight into video.mp4 with ffmpeg (required) instead of
    /// writing them as PNG: a 90 s 4K30 video is some 50 GB of PNG.
    #[arg(long, requires = "fps")]
    pub(super) video_stream: bool,
}

/// Parses a duration in milliseconds into seconds.
fn parse_ms(s: &str) -> Result<f64, String> {
    let ms = values::non_negative(s)?;
    if ms > 1000.0 {
        return Err(format!("`{s}`: at most 1000 ms"));
    }
    Ok(ms / 1000.0)
}

/// Parses a frame rate between 1 and 240.
fn parse_fps(s: &str) -> Result<f64, String> {
    let v = values::non_negative(s)?;
    if !(1.0..=240.0).contains(&v) {
        return Err(format!("`{s}`: must be between 1 and 240 frames/s"));
    }
    Ok(v)
}

/// Parses `MIN,MAX` with 0 ≤ MIN ≤ MAX.
fn parse_range(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(values::non_negative)
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [lo, hi] if lo <= hi => Ok([*lo, *hi]),
        [_, _] => Err(format!("`{s}`: MIN must not exceed MAX")),
        _ => Err(format!("`{s}`: expected MIN,MAX")),
    }
}

pub(super) fn video_config(v: &VideoArgs) -> Option<VideoConfig> {
    v.video.then(|| VideoConfig {
        motion: MotionConfig {
            angular_speed_deg_s: v.angular_speed,
            linear_speed_m_s: v.linear_speed,
            tremor_deg_s: v.tremor,
            pause_s: v.pause,
        },
        readout_s: v.readout,
        exposure_s: v.exposure,
        frame_rate: v.fps.unwrap_or(30.0),
        focus_breathing: v.focus_breathing,
        neighbours: v.neighbours,
        full_rate_width: v.fps.map(|_| v.video_width),
        stream_full_rate: v.video_stream,
        ..VideoConfig::default()
    })
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(super) enum SfmArg {
    StandIn,
    Colmap,
}

/// `simulate lab`.
#[derive(Debug, clap::Args)]
pub struct LabArgs {
    #[command(flatten)]
    pub(super) common: Common,
    /// Number of frames (half portrait going up, half landscape coming down).
    #[arg(long, default_value_t = 90)]
    pub(super) frames: usize,
    /// Approximate number of targets on the two walls.
    #[arg(long, default_value_t = 200)]
    pub(super) targets: usize,
    /// Leave out the floor.
    #[arg(long)]
    pub(super) no_floor: bool,
    /// The walls between the targets: `plaster` (stains and speckle at every scale) or
    /// `speckled` (blobs of the targets' sizes sprayed over it, dark and light, some nearly
    /// round: a test of what the detector takes for a target).
    #[arg(long, value_enum, default_value_t = WallTextureArg::Plaster)]
    pub(super) wall_texture: WallTextureArg,
}

/// `--wall-texture`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub(super) enum WallTextureArg {
    Plaster,
    Speckled,
}

/// `simulate site`.
#[derive(Debug, clap::Args)]
pub struct SiteArgs {
    #[command(flatten)]
    pub(super) common: Common,
    /// Number of frames (half portrait, half landscape; default 60, 20 for `--layout
    /// two-pipes`).
    #[arg(long)]
    pub(super) frames: Option<usize>,
    /// Number of targets on the wall (default 8, 10 for `--layout two-pipes`).
    #[arg(long)]
    pub(super) targets: Option<usize>,
    /// The mock pipes: `three-pipes` (6", 4" and 2" pipes across the wall, the 4" of interest)
    /// or `two-pipes` (a capped 2" pipe 1.16 m long in front of a capped 6" one, 0.14 m further
    /// back; 20 frames on an arc around the 2" at 1.35–1.9 m).
    #[arg(
        long,
        value_enum,
        default_value = "three-pipes",
        conflicts_with = "plant"
    )]
    pub(super) layout: Layout,
    /// σ of the dense observations (px, 0 or more).
    #[arg(long, default_value_t = 0.3, value_parser = values::non_negative)]
    pub(super) dense_noise: f64,
    /// σ of a 3D error of every dense point (mm, 0 or more), as a multi-view stereo depth map
    /// has it, beside the pixel noise.
    #[arg(long, value_name = "MM", default_value_t = 0.0, value_parser = values::non_negative)]
    pub(super) dense_point_noise: f64,
    /// Direction of that error: the surface normal or the viewing ray of the point's reference
    /// view.
    #[arg(long, value_enum, default_value = "normal")]
    pub(super) dense_noise_along: NoiseAlong,
    /// Fraction of dense points that are outliers (0–0.5): a depth off by up to ±10 % along
    /// their reference view's ray.
    #[arg(long, value_name = "FRACTION", default_value_t = 0.0, value_parser = values::outlier_fraction)]
    pub(super) dense_outliers: f64,
    /// Spacing of the dense points on the pipes (mm; default 2.5 mm scaled by 3840 / width).
    #[arg(long, value_name = "MM", value_parser = values::positive)]
    pub(super) dense_spacing: Option<f64>,
    /// Offset added to the TLS coordinates, e.g. 500000,5600000,0 (site coordinates).
    #[arg(long, value_parser = values::point)]
    pub(super) tls_offset: Option<nalgebra::Vector3<f64>>,
    /// A plant room (the room `simulate plant --seed` draws) instead of the mock pipes: target
    /// boards on its walls, a walk around it looking in, its TLS scan from the room's stations,
    /// and plant.json (every pipe segment and object) beside truth.json.
    #[arg(long)]
    pub(super) plant: bool,
}

/// `--layout`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub(super) enum Layout {
    ThreePipes,
    TwoPipes,
}

/// `--dense-noise-along`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub(super) enum NoiseAlong {
    Normal,
    Ray,
}

pub(super) fn options(c: &Common) -> Result<SimulateOptions> {
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
        video: video_config(&c.video),
        ..SimulateOptions::default()
    })
}
