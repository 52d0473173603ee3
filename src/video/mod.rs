//! Frame choice from a phone video: decode with ffmpeg (an external
//! program, like COLMAP), measure each video frame's apparent motion (sparse feature flow to
//! its two neighbours, [`flow`]) and sharpness, and pick in each window of `1/N` s the frame
//! that moves least and is sharpest; write it with its two neighbours in the video and the
//! sidecar `frames.json` ([`crate::io::sidecar`]) that the calibration reads to estimate the
//! rolling shutter's readout time.
//!
//! ```text
//! DIR/frame_0001.png …                   the chosen frames, in time order
//! DIR/neighbours/frame_0001-1.png        the video frames just before and after each
//! DIR/neighbours/frame_0001+1.png
//! DIR/frames.json                        schema pipemeasure.frames/1
//! DIR/choice.json                        per video frame: time, motion, sharpness, chosen
//! ```
//!
//! The paper extracts frames at a fixed 1 fps; a hand-held video's motion varies (pauses at
//! viewpoints, faster moves between), and a frame that moves less has less rolling-shutter
//! shear and motion blur. Times assume a constant frame rate (the stream's `r_frame_rate`).

pub mod flow;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use serde::{Deserialize, Serialize};

use crate::io::atomic::StagedDir;
use crate::io::error::WriteError;
use crate::io::sidecar::{FRAMES_SCHEMA, FramesEntry, FramesSidecar, NeighbourEntry};
use flow::{Grey, Pyramid, apparent_motion, sharpness};

/// Schema tag of `choice.json`.
pub const CHOICE_SCHEMA: &str = "pipemeasure.frame-choice/1";

/// Width (px) the motion and sharpness are measured at: wider videos are scaled down.
pub const ANALYSIS_WIDTH: u32 = 960;

/// Apparent motion (fraction of the image width per video frame) above which a chosen frame is
/// warned about: at 0.5 % a 4K phone (75° across) turns about 11 °/s at 30 fps, where the
/// rolling-shutter shear reaches ~10 px and the blur of an 8 ms exposure ~5 px.
pub const WARN_MOTION_FRACTION: f64 = 0.005;

/// Why a video could not be read or its frames written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum VideoError {
    /// `ffmpeg` or `ffprobe` is not on PATH.
    #[error(
        "`{0}` is not installed or not on PATH (Debian/Ubuntu: `apt-get install -y ffmpeg`); or extract the frames yourself"
    )]
    NotInstalled(&'static str),
    /// ffmpeg/ffprobe refused the file.
    #[error("{}: {program} failed ({status}): {message}", .path.display())]
    Failed {
        /// The video.
        path: PathBuf,
        /// `ffmpeg` or `ffprobe`.
        program: &'static str,
        /// Exit status.
        status: String,
        /// The end of its output.
        message: String,
    },
    /// The stream is unusable (no video stream, a bad size or frame rate, too few frames).
    #[error("{}: {reason}", .path.display())]
    Unusable {
        /// The video.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A file or folder could not be written.
    #[error("cannot write {}: {source}", .path.display())]
    Write {
        /// The path.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

impl From<WriteError> for VideoError {
    fn from(e: WriteError) -> Self {
        VideoError::Write {
            path: e.path,
            source: e.source,
        }
    }
}

/// The video stream's geometry and rate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct VideoInfo {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
    /// Frames per second.
    pub fps: f64,
}

/// How frames are chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FrameChoice {
    /// `N` frames per second, each the least moving and sharpest of its `1/N` s window.
    PerSecond(u32),
    /// Plain extraction: the frame nearest to every `1/rate` s (the paper's 1 fps).
    EveryFrameAt(f64),
}

/// What was measured of one video frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameMeasure {
    /// Index in the video (0-based).
    pub index: usize,
    /// Time (s).
    pub time_s: f64,
    /// Apparent motion (px per video frame at full resolution): the mean of the median feature
    /// flow to the previous and the next frame; `None` where no flow could be measured.
    pub motion_px: Option<f64>,
    /// Mean squared Laplacian at the analysis width.
    pub sharpness: f64,
    /// Whether it was chosen.
    pub chosen: bool,
}

/// The frame choice's record (`choice.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChoiceRecord {
    /// Always [`CHOICE_SCHEMA`].
    pub schema: String,
    /// The video file.
    pub video: String,
    /// Its stream.
    pub info: VideoInfo,
    /// `per-second N` or `every-frame-at R`.
    pub rule: String,
    /// Every video frame's measures.
    pub frames: Vec<FrameMeasure>,
}

impl ChoiceRecord {
    /// The mean measured motion (px per video frame) of the chosen frames and of the frames
    /// plain 1 fps extraction would take from the same video, frames without a measured
    /// motion left out (NaN when none has one).
    #[must_use]
    pub fn mean_motion_px(&self) -> (f64, f64) {
        let mean = |ks: &mut dyn Iterator<Item = usize>| {
            let v: Vec<f64> = ks.filter_map(|k| self.frames[k].motion_px).collect();
            v.iter().sum::<f64>() / v.len() as f64
        };
        let plain = choose(&self.frames, self.info.fps, FrameChoice::EveryFrameAt(1.0));
        (
            mean(&mut self.frames.iter().filter(|f| f.chosen).map(|f| f.index)),
            mean(&mut plain.into_iter()),
        )
    }
}

/// The frames written and what was noticed.
#[derive(Clone, Debug)]
pub struct Extraction {
    /// The record written as `choice.json`.
    pub record: ChoiceRecord,
    /// The sidecar written as `frames.json`.
    pub sidecar: FramesSidecar,
    /// Warnings: chosen frames that move so much that rolling shutter or blur dominate.
    pub warnings: Vec<String>,
}

fn tool_error(program: &'static str, e: &std::io::Error) -> Option<VideoError> {
    (e.kind() == std::io::ErrorKind::NotFound).then_some(VideoError::NotInstalled(program))
}

/// Reads the first video stream's size and frame rate with `ffprobe`.
///
/// # Errors
///
/// [`VideoError`]: no ffprobe, a file ffprobe refuses, no video stream, a zero size or rate.
pub fn probe(path: &Path) -> Result<VideoInfo, VideoError> {
    let out = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=width,height,r_frame_rate",
            "-of",
            "default=noprint_wrappers=1",
        ])
        .arg(path)
        .output()
        .map_err(|e| {
            tool_error("ffprobe", &e).unwrap_or_else(|| VideoError::Failed {
                path: path.into(),
                program: "ffprobe",
                status: "not started".into(),
                message: e.to_string(),
            })
        })?;
    if !out.status.success() {
        return Err(VideoError::Failed {
            path: path.into(),
            program: "ffprobe",
            status: out.status.to_string(),
            message: String::from_utf8_lossy(&out.stderr).trim().to_string(),
        });
    }
    parse_probe(&String::from_utf8_lossy(&out.stdout)).map_err(|reason| VideoError::Unusable {
        path: path.into(),
        reason,
    })
}

/// Parses ffprobe's `key=value` lines.
fn parse_probe(text: &str) -> Result<VideoInfo, String> {
    let value = |key: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(key)?.strip_prefix('='))
            .map(str::trim)
    };
    let size = |key: &str| -> Result<u32, String> {
        let v = value(key).ok_or("no video stream")?;
        match v.parse::<u32>() {
            Ok(n) if (16..=16384).contains(&n) => Ok(n),
            _ => Err(format!("video {key} {v:?}: expected 16 to 16384 px")),
        }
    };
    let (width, height) = (size("width")?, size("height")?);
    let rate = value("r_frame_rate").ok_or("no frame rate")?;
    let fps = match rate.split_once('/') {
        Some((n, d)) => match (n.parse::<f64>(), d.parse::<f64>()) {
            (Ok(n), Ok(d)) if d > 0.0 => n / d,
            _ => f64::NAN,
        },
        None => rate.parse().unwrap_or(f64::NAN),
    };
    if !(fps.is_finite() && (1.0..=1000.0).contains(&fps)) {
        return Err(format!("frame rate {rate:?}: expected 1 to 1000 frames/s"));
    }
    Ok(VideoInfo { width, height, fps })
}

/// The analysis size: the video's, scaled to at most [`ANALYSIS_WIDTH`] wide (even sizes).
fn analysis_size(info: &VideoInfo) -> (u32, u32) {
    if info.width <= ANALYSIS_WIDTH {
        return (info.width, info.height);
    }
    let h = f64::from(info.height) * f64::from(ANALYSIS_WIDTH) / f64::from(info.width);
    (ANALYSIS_WIDTH, ((h / 2.0).round() as u32 * 2).max(2))
}

/// Decodes the video as grey frames at the analysis size and measures each frame's apparent
/// motion and sharpness, holding three frames at a time. `progress` gets the frames decoded.
///
/// # Errors
///
/// [`VideoError`]: no ffmpeg, a stream ffmpeg cannot decode, fewer than 3 frames.
pub fn measure(
    path: &Path,
    info: &VideoInfo,
    progress: &dyn Fn(usize),
) -> Result<Vec<FrameMeasure>, VideoError> {
    let (w, h) = analysis_size(info);
    let scale = f64::from(info.width) / f64::from(w);
    let mut measures: Vec<FrameMeasure> = Vec::new();
    // Flow between consecutive frames k−1 → k.
    let mut flows: Vec<Option<f64>> = Vec::new();
    let mut previous: Option<Pyramid> = None;
    decode(path, (w, h), Pixels::Grey, &mut |index, bytes| {
        let Some(grey) = Grey::from_bytes(w as usize, h as usize, bytes) else {
            return Ok(true);
        };
        let sharp = sharpness(&grey);
        let pyramid = Pyramid::new(grey);
        if let Some(prev) = &previous {
            flows.push(apparent_motion(prev, &pyramid).map(|(m, _)| m * scale));
        }
        previous = Some(pyramid);
        measures.push(FrameMeasure {
            index,
            time_s: index as f64 / info.fps,
            motion_px: None,
            sharpness: sharp,
            chosen: false,
        });
        progress(index + 1);
        Ok(false)
    })?;
    if measures.len() < 3 {
        return Err(VideoError::Unusable {
            path: path.into(),
            reason: format!(
                "{} decodable video frames: at least 3 are needed",
                measures.len()
            ),
        });
    }
    // A frame's motion: the mean of its flows to both neighbours (one at the ends).
    for (k, m) in measures.iter_mut().enumerate() {
        let before = k.checked_sub(1).and_then(|j| flows[j]);
        let after = flows.get(k).copied().flatten();
        m.motion_px = match (before, after) {
            (Some(a), Some(b)) => Some(0.5 * (a + b)),
            (a, b) => a.or(b),
        };
    }
    Ok(measures)
}

/// The pixel format asked of ffmpeg.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pixels {
    Grey,
    Rgb,
}

/// Decodes the first video stream at `size` as raw frames through a pipe, calling `frame` with
/// each frame's index and bytes until it returns `true` (then ffmpeg is stopped) or the
/// stream ends. Returns the frames decoded.
fn decode<F>(
    path: &Path,
    size: (u32, u32),
    pixels: Pixels,
    frame: &mut F,
) -> Result<usize, VideoError>
where
    F: FnMut(usize, &[u8]) -> Result<bool, VideoError>,
{
    let failed = |status: String, message: String| VideoError::Failed {
        path: path.into(),
        program: "ffmpeg",
        status,
        message,
    };
    let (pix_fmt, channels) = match pixels {
        Pixels::Grey => ("gray", 1),
        Pixels::Rgb => ("rgb24", 3),
    };
    let mut child = Command::new("ffmpeg")
        .args(["-v", "error", "-nostdin", "-i"])
        .arg(path)
        .args(["-map", "0:v:0", "-vf"])
        .arg(format!("scale={}:{}", size.0, size.1))
        .args([
            "-fps_mode",
            "passthrough",
            "-f",
            "rawvideo",
            "-pix_fmt",
            pix_fmt,
            "pipe:1",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            tool_error("ffmpeg", &e).unwrap_or_else(|| failed("not started".into(), e.to_string()))
        })?;
    let mut stdout = child
        .stdout
        .take()
        .ok_or_else(|| failed("no output".into(), String::new()))?;
    // ffmpeg's messages are read on their own thread so a full stderr pipe cannot stall it.
    let stderr = child.stderr.take();
    let messages = std::thread::spawn(move || {
        let mut text = String::new();
        if let Some(mut s) = stderr {
            let _ = s.read_to_string(&mut text);
        }
        text
    });
    let mut buffer = vec![0_u8; size.0 as usize * size.1 as usize * channels];
    let mut index = 0;
    let mut stopped = false;
    let outcome = loop {
        match stdout.read_exact(&mut buffer) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => break Ok(()),
            Err(e) => break Err(failed("reading its output".into(), e.to_string())),
        }
        match frame(index, &buffer) {
            Ok(false) => index += 1,
            Ok(true) => {
                index += 1;
                stopped = true;
                break Ok(());
            }
            Err(e) => break Err(e),
        }
    };
    if stopped || outcome.is_err() {
        let _ = child.kill();
    }
    drop(stdout);
    let status = child
        .wait()
        .map_err(|e| failed("wait".into(), e.to_string()))?;
    let message = messages.join().unwrap_or_default();
    outcome?;
    if !stopped && !status.success() {
        return Err(failed(status.to_string(), message.trim().to_string()));
    }
    Ok(index)
}

/// Decodes full-size RGB frames for [`write_frames`].
fn decode_rgb<F>(path: &Path, info: &VideoInfo, frame: &mut F) -> Result<usize, VideoError>
where
    F: FnMut(usize, &image::RgbImage) -> Result<bool, VideoError>,
{
    decode(
        path,
        (info.width, info.height),
        Pixels::Rgb,
        &mut |k, bytes| {
            let Some(img) = image::RgbImage::from_raw(info.width, info.height, bytes.to_vec())
            else {
                return Ok(true);
            };
            frame(k, &img)
        },
    )
}

/// The chosen video frames (indices, increasing): only frames with both neighbours in the video
/// are candidates.
#[must_use]
pub fn choose(measures: &[FrameMeasure], fps: f64, rule: FrameChoice) -> Vec<usize> {
    let n = measures.len();
    if n < 3 {
        return Vec::new();
    }
    let duration = n as f64 / fps;
    match rule {
        FrameChoice::EveryFrameAt(rate) => {
            let mut chosen = Vec::new();
            let mut t = 0.0;
            while t < duration {
                let k = ((t * fps).round() as usize).clamp(1, n - 2);
                if chosen.last() != Some(&k) {
                    chosen.push(k);
                }
                t += 1.0 / rate;
            }
            chosen
        }
        FrameChoice::PerSecond(per_second) => {
            let window = 1.0 / f64::from(per_second.max(1));
            let windows = (duration / window).ceil() as usize;
            // Two choices at least half a window apart: the best frames of adjacent windows
            // often sit at their common border, a frame apart, adding no geometry.
            let spacing = ((0.5 * window * fps).round() as usize).max(1);
            let mut chosen: Vec<usize> = Vec::with_capacity(windows);
            for w in 0..windows {
                let mut lo = ((w as f64 * window * fps).ceil() as usize).max(1);
                if let Some(&last) = chosen.last() {
                    lo = lo.max(last + spacing);
                }
                let hi = (((w + 1) as f64 * window * fps).ceil() as usize).min(n - 1);
                if lo < hi
                    && let Some(k) = best_in(&measures[lo..hi])
                {
                    chosen.push(k);
                }
            }
            chosen
        }
    }
}

/// The best frame of a window: the smallest motion scaled by the window's median sharpness over
/// the frame's (so a frame twice as blurred counts as moving twice as much); frames without a
/// measured motion only when none has one, then the sharpest.
fn best_in(window: &[FrameMeasure]) -> Option<usize> {
    if window.is_empty() {
        return None;
    }
    let mut sharp: Vec<f64> = window.iter().map(|m| m.sharpness).collect();
    sharp.sort_by(f64::total_cmp);
    let median = sharp[sharp.len() / 2].max(f64::MIN_POSITIVE);
    let score = |m: &FrameMeasure| {
        m.motion_px
            .map(|px| (px + 0.05) * median / m.sharpness.max(f64::MIN_POSITIVE))
    };
    let moving = window
        .iter()
        .filter_map(|m| score(m).map(|s| (s, m.index)))
        .min_by(|a, b| a.0.total_cmp(&b.0));
    moving.map(|(_, k)| k).or_else(|| {
        window
            .iter()
            .max_by(|a, b| a.sharpness.total_cmp(&b.sharpness))
            .map(|m| m.index)
    })
}

/// The sidecar of the chosen frames: names `frame_0001.png` …, neighbours
/// `neighbours/frame_0001-1.png` and `+1` at `∓1/fps`.
#[must_use]
pub fn sidecar_for(chosen: &[usize], fps: f64, neighbours: bool) -> FramesSidecar {
    FramesSidecar {
        schema: FRAMES_SCHEMA.into(),
        frames: chosen
            .iter()
            .enumerate()
            .map(|(i, &k)| {
                let stem = format!("frame_{:04}", i + 1);
                FramesEntry {
                    name: format!("{stem}.png"),
                    time_s: k as f64 / fps,
                    neighbours: if neighbours {
                        vec![
                            NeighbourEntry {
                                name: format!("neighbours/{stem}-1.png"),
                                dt_s: -1.0 / fps,
                            },
                            NeighbourEntry {
                                name: format!("neighbours/{stem}+1.png"),
                                dt_s: 1.0 / fps,
                            },
                        ]
                    } else {
                        Vec::new()
                    },
                }
            })
            .collect(),
    }
}

/// Chooses frames from `video` and writes them, with `neighbours` their two neighbours in the
/// video (which the calibration's readout estimate uses; a site needs none), `frames.json` and
/// `choice.json` into `dir` (created; it must not hold frames already). Everything is written
/// into a staging folder beside `dir` first and moved into place at the end.
///
/// # Errors
///
/// [`VideoError`].
pub fn extract_frames(
    video: &Path,
    dir: &Path,
    rule: FrameChoice,
    neighbours: bool,
    progress: &dyn Fn(usize, Option<usize>),
) -> Result<Extraction, VideoError> {
    let info = probe(video)?;
    let measures = measure(video, &info, &|k| progress(k, None))?;
    let chosen = choose(&measures, info.fps, rule);
    if chosen.is_empty() {
        return Err(VideoError::Unusable {
            path: video.into(),
            reason: "no frame could be chosen".into(),
        });
    }
    let mut measures = measures;
    for &k in &chosen {
        measures[k].chosen = true;
    }
    let warnings = motion_warnings(&measures, &chosen, &info);
    let sidecar = sidecar_for(&chosen, info.fps, neighbours);
    let record = ChoiceRecord {
        schema: CHOICE_SCHEMA.into(),
        video: video.display().to_string(),
        info,
        rule: match rule {
            FrameChoice::PerSecond(n) => format!("per-second {n}"),
            FrameChoice::EveryFrameAt(r) => format!("every-frame-at {r}"),
        },
        frames: measures,
    };
    let files = chosen.len() * if neighbours { 3 } else { 1 };
    write_frames(video, &info, dir, &chosen, &sidecar, &record, &|k| {
        progress(k, Some(files));
    })?;
    Ok(Extraction {
        record,
        sidecar,
        warnings,
    })
}

/// Warnings for chosen frames whose motion exceeds [`WARN_MOTION_FRACTION`] of the width.
fn motion_warnings(measures: &[FrameMeasure], chosen: &[usize], info: &VideoInfo) -> Vec<String> {
    let limit = WARN_MOTION_FRACTION * f64::from(info.width);
    let fast: Vec<String> = chosen
        .iter()
        .enumerate()
        .filter_map(|(i, &k)| {
            let m = measures[k].motion_px?;
            (m > limit).then(|| format!("frame_{:04} ({:.1} px/frame)", i + 1, m))
        })
        .collect();
    if fast.is_empty() {
        return Vec::new();
    }
    let listed = if fast.len() > 8 {
        format!("{}, …", fast[..8].join(", "))
    } else {
        fast.join(", ")
    };
    vec![format!(
        "{} of the {} chosen frames move more than {:.1} px per video frame ({} % of the width): rolling-shutter shear and motion blur will dominate them; film slower or pause at viewpoints (choice.json lists every frame): {listed}",
        fast.len(),
        chosen.len(),
        limit,
        100.0 * WARN_MOTION_FRACTION,
    )]
}

/// Writes the chosen frames and their neighbours (PNG, full size) from a second decoding,
/// with the two records, into a folder staged beside `dir` ([`StagedDir`]: nothing
/// half-written stays behind) and moved into place at the end.
fn write_frames(
    video: &Path,
    info: &VideoInfo,
    dir: &Path,
    chosen: &[usize],
    sidecar: &FramesSidecar,
    record: &ChoiceRecord,
    progress: &dyn Fn(usize),
) -> Result<(), VideoError> {
    let write_err = |path: &Path, source| VideoError::Write {
        path: path.into(),
        source,
    };
    if dir.join("frames.json").exists() || dir.join("frame_0001.png").exists() {
        return Err(VideoError::Unusable {
            path: dir.into(),
            reason: "already holds extracted frames: remove it or choose another folder".into(),
        });
    }
    let staged = StagedDir::new(dir)?;
    let staging = staged.path();
    if sidecar.frames.iter().any(|f| !f.neighbours.is_empty()) {
        std::fs::create_dir_all(staging.join("neighbours"))
            .map_err(|e| write_err(&staging.join("neighbours"), e))?;
    }
    // Each wanted video frame and the files it becomes (a frame may be one chosen frame's
    // neighbour and another's main frame).
    let mut wanted: std::collections::BTreeMap<usize, Vec<PathBuf>> = Default::default();
    for (entry, &k) in sidecar.frames.iter().zip(chosen) {
        wanted.entry(k).or_default().push(staging.join(&entry.name));
        for n in &entry.neighbours {
            let src = (k as f64 + n.dt_s * info.fps).round().max(0.0) as usize;
            wanted.entry(src).or_default().push(staging.join(&n.name));
        }
    }
    let total = wanted.len();
    let mut done = 0;
    decode_rgb(video, info, &mut |index, rgb| {
        let Some(dests) = wanted.remove(&index) else {
            return Ok(wanted.is_empty());
        };
        for dest in dests {
            rgb.save_with_format(&dest, image::ImageFormat::Png)
                .map_err(|e| write_err(&dest, std::io::Error::other(e)))?;
        }
        done += 1;
        progress(done);
        Ok(wanted.is_empty())
    })?;
    if let Some(&k) = wanted.keys().next() {
        return Err(VideoError::Unusable {
            path: video.into(),
            reason: format!(
                "the second decoding ended before video frame {k} ({done} of {total} written)"
            ),
        });
    }
    write_json(&staging.join("frames.json"), sidecar)?;
    write_json(&staging.join("choice.json"), record)?;
    staged.commit()?;
    Ok(())
}

/// Writes `value` as pretty JSON.
fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), VideoError> {
    let write_err = |source| VideoError::Write {
        path: path.into(),
        source,
    };
    let text =
        serde_json::to_string_pretty(value).map_err(|e| write_err(std::io::Error::other(e)))?;
    std::fs::write(path, text).map_err(write_err)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(index: usize, motion: f64, sharpness: f64) -> FrameMeasure {
        FrameMeasure {
            index,
            time_s: index as f64 / 10.0,
            motion_px: Some(motion),
            sharpness,
            chosen: false,
        }
    }

    #[test]
    fn the_least_moving_frame_of_each_second_is_chosen() {
        // 10 fps, 3 s: the slowest frames are 4, 17 and 22.
        let measures: Vec<FrameMeasure> = (0..30)
            .map(|k| m(k, if [4, 17, 22].contains(&k) { 0.5 } else { 5.0 }, 100.0))
            .collect();
        assert_eq!(
            choose(&measures, 10.0, FrameChoice::PerSecond(1)),
            vec![4, 17, 22]
        );
        assert_eq!(
            choose(&measures, 10.0, FrameChoice::EveryFrameAt(1.0)),
            vec![1, 10, 20]
        );
        // Slowest at the border of two windows (9 and 10): the second window's choice keeps
        // half a window (5 frames) from the first; among equals the first is taken.
        let border: Vec<FrameMeasure> = (0..30)
            .map(|k| m(k, if [9, 10, 22].contains(&k) { 0.5 } else { 5.0 }, 100.0))
            .collect();
        assert_eq!(
            choose(&border, 10.0, FrameChoice::PerSecond(1)),
            vec![9, 14, 22]
        );
    }

    #[test]
    fn a_blurred_frame_loses_to_a_sharp_one_moving_alike() {
        let measures = [
            m(0, 1.0, 100.0),
            m(1, 1.0, 30.0),
            m(2, 1.1, 100.0),
            m(3, 1.0, 100.0),
        ];
        assert_eq!(best_in(&measures[1..3]), Some(2));
    }

    #[test]
    fn ffprobe_output_is_checked() {
        let ok = parse_probe("width=640\nheight=480\nr_frame_rate=30000/1001\n").unwrap();
        assert_eq!((ok.width, ok.height), (640, 480));
        assert!((ok.fps - 29.97).abs() < 1e-3);
        assert!(parse_probe("").unwrap_err().contains("no video stream"));
        assert!(parse_probe("width=0\nheight=480\nr_frame_rate=30/1").is_err());
        assert!(parse_probe("width=640\nheight=480\nr_frame_rate=0/0").is_err());
    }
}
