//! The video options of a simulation ([`super::video`]): how the hand-held phone moves and
//! what its camera does. The truth records them ([`super::truth`]).

use serde::{Deserialize, Serialize};

use super::devices::DEFAULT_EXPOSURE_S;
use super::trajectory::MotionConfig;

/// A bad video option: which, and why.
#[derive(Debug, thiserror::Error)]
#[error("option `{field}`: {reason}")]
pub struct VideoConfigError {
    /// The option.
    pub field: &'static str,
    /// What is wrong.
    pub reason: String,
}

/// Video options: how the hand-held phone moves and what its camera does.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VideoConfig {
    /// Hand-held motion (speeds at the extracted frames, tremor, pauses).
    pub motion: MotionConfig,
    /// Rolling-shutter readout time (s); `None` (default) takes the device preset's
    /// (20, 25, 30 ms); 0 = global shutter.
    pub readout_s: Option<f64>,
    /// Exposure time of each row (s), default 0.008; 0 = no motion blur.
    pub exposure_s: f64,
    /// Video frame rate (frames/s), default 30: the neighbours' spacing and the full-rate
    /// video's rate.
    pub frame_rate: f64,
    /// Time between extracted frames (s), default 1 (the paper's 1 fps extraction); a whole
    /// number of video frames.
    pub interval_s: f64,
    /// Autofocus on: the principal distance follows the focus distance (default false).
    pub focus_breathing: bool,
    /// Render each extracted frame's two neighbours at ±1/`frame_rate` (default false).
    pub neighbours: bool,
    /// Render every video frame at this width into `video/` (default `None`: not rendered).
    pub full_rate_width: Option<u32>,
    /// Encode the full-rate frames into `video.mp4` with ffmpeg when it is on the PATH
    /// (default true).
    pub encode: bool,
    /// Pipe the full-rate frames straight into `video.mp4` (ffmpeg required) instead of
    /// writing them as PNG (default false).
    pub stream_full_rate: bool,
}

impl Default for VideoConfig {
    fn default() -> Self {
        VideoConfig {
            motion: MotionConfig::default(),
            readout_s: None,
            exposure_s: DEFAULT_EXPOSURE_S,
            frame_rate: 30.0,
            interval_s: 1.0,
            focus_breathing: false,
            neighbours: false,
            full_rate_width: None,
            encode: true,
            stream_full_rate: false,
        }
    }
}

impl VideoConfig {
    /// Checks the values.
    ///
    /// # Errors
    ///
    /// [`VideoConfigError`] naming the first bad option.
    pub fn validate(&self) -> Result<(), VideoConfigError> {
        let bad = |field, reason: String| Err(VideoConfigError { field, reason });
        if !(self.frame_rate.is_finite() && (1.0..=240.0).contains(&self.frame_rate)) {
            return bad(
                "video.frame_rate",
                "must be between 1 and 240 frames/s".into(),
            );
        }
        let frame_s = 1.0 / self.frame_rate;
        if let Some(r) = self.readout_s
            && !(r.is_finite() && (0.0..=frame_s).contains(&r))
        {
            return bad(
                "video.readout_s",
                format!("must be between 0 and one frame ({:.1} ms)", frame_s * 1e3),
            );
        }
        if !(self.exposure_s.is_finite() && (0.0..=frame_s).contains(&self.exposure_s)) {
            return bad(
                "video.exposure_s",
                format!("must be between 0 and one frame ({:.1} ms)", frame_s * 1e3),
            );
        }
        let per_interval = self.interval_s * self.frame_rate;
        if !(self.interval_s.is_finite()
            && (0.1..=60.0).contains(&self.interval_s)
            && (per_interval - per_interval.round()).abs() < 1e-9)
        {
            return bad(
                "video.interval_s",
                "must be between 0.1 and 60 s and a whole number of video frames".into(),
            );
        }
        if let Some(w) = self.full_rate_width
            && !((64..=3840).contains(&w) && w % 32 == 0)
        {
            return bad(
                "video.full_rate_width",
                "must be a multiple of 32 between 64 and 3840 px".into(),
            );
        }
        if self.stream_full_rate && (self.full_rate_width.is_none() || !self.encode) {
            return bad(
                "video.stream_full_rate",
                "needs the full-rate video (full_rate_width) and its encoding".into(),
            );
        }
        self.motion
            .validate(self.interval_s)
            .map_err(|e| VideoConfigError {
                field: "video.motion",
                reason: e.to_string(),
            })
    }
}
