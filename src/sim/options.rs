//! What a simulation is asked for ([`SimulateOptions`], shared by the lab and the site) and
//! why one fails ([`SimError`]). [`super::simulate`] runs it; [`super::video`] films it.

use serde::{Deserialize, Serialize};

use super::devices::{PRESETS, preset};
use super::lab::LabConfigError;
use super::render::{RenderConfig, RenderConfigError};
use super::sfm::SfmConfig;
use super::video_config::{VideoConfig, VideoConfigError};
use crate::camera::BrownCamera;
use crate::io::WriteError;

/// Where the sparse model comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SfmSource {
    /// The simulated stand-in (default; needs nothing outside the crate).
    #[default]
    StandIn,
    /// The real COLMAP (feature_extractor on CPU, sequential_matcher, mapper) on the frames.
    Colmap,
}

/// Options shared by both scenes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimulateOptions {
    /// Device preset to imitate (`p30`, `iphone11`, `s10`).
    pub device: String,
    /// Frame width (px); the preset's intrinsics scale with it. Default 3840.
    pub width: u32,
    /// Frame height (px); must keep the preset's 16:9 aspect. Default 2160.
    pub height: u32,
    /// Seed of every random choice. Default 1.
    pub seed: u64,
    /// Rendering options.
    pub render: RenderConfig,
    /// SfM stand-in options.
    pub sfm: SfmConfig,
    /// Source of the sparse model.
    pub sfm_source: SfmSource,
    /// Truth visibility margin (px): targets closer than this to the border are not listed.
    /// Default 4.
    pub margin_px: f64,
    /// The command line, recorded in the truth.
    pub command: String,
    /// Film a video ([`super::video`]); `None` (default): still, global-shutter frames.
    pub video: Option<VideoConfig>,
}

impl Default for SimulateOptions {
    fn default() -> Self {
        SimulateOptions {
            device: "p30".into(),
            width: 3840,
            height: 2160,
            seed: 1,
            render: RenderConfig::default(),
            sfm: SfmConfig::default(),
            sfm_source: SfmSource::StandIn,
            margin_px: 4.0,
            command: String::new(),
            video: None,
        }
    }
}

/// Why a simulation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// Unknown device preset.
    #[error("unknown device preset `{name}`; presets: {}", PRESETS.map(|p| p.name).join(", "))]
    UnknownDevice {
        /// The name asked for.
        name: String,
    },
    /// A bad option.
    #[error("option `{field}`: {reason}")]
    Option {
        /// The option.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// Bad render options.
    #[error(transparent)]
    Render(#[from] RenderConfigError),
    /// Bad lab options.
    #[error(transparent)]
    Lab(#[from] LabConfigError),
    /// Bad site options.
    #[error(transparent)]
    Site(#[from] super::site::SiteConfigError),
    /// A file could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// A frame could not be encoded.
    #[error("encoding frame {name}: {source}")]
    Encode {
        /// The frame.
        name: String,
        /// The cause.
        #[source]
        source: image::ImageError,
    },
    /// COLMAP failed or is missing.
    #[error(transparent)]
    Colmap(#[from] crate::io::colmap::ColmapRunError),
    /// ffmpeg, which encodes a streamed video, failed or is missing.
    #[error("encoding the video with ffmpeg: {reason}")]
    Ffmpeg {
        /// What went wrong, with ffmpeg's own message.
        reason: String,
    },
}

impl SimulateOptions {
    /// The true camera: the preset scaled to the frame size.
    ///
    /// # Errors
    ///
    /// [`SimError::UnknownDevice`], or [`SimError::Option`] when the size is out of range or
    /// does not keep the preset's aspect ratio.
    pub fn camera(&self) -> Result<BrownCamera, SimError> {
        let p = preset(&self.device).ok_or_else(|| SimError::UnknownDevice {
            name: self.device.clone(),
        })?;
        if !(64..=8192).contains(&self.width) {
            return Err(SimError::Option {
                field: "width",
                reason: "must be between 64 and 8192 px".into(),
            });
        }
        let expected = (f64::from(self.width) * f64::from(p.camera.height)
            / f64::from(p.camera.width))
        .round() as u32;
        if self.height.abs_diff(expected) > 1 {
            return Err(SimError::Option {
                field: "height",
                reason: format!(
                    "must keep the preset's aspect ratio: {expected} for width {}",
                    self.width
                ),
            });
        }
        Ok(p.camera.scaled(self.width, self.height))
    }

    /// Checks every option.
    ///
    /// # Errors
    ///
    /// The first problem found.
    pub fn validate(&self) -> Result<(), SimError> {
        self.camera()?;
        self.render.validate()?;
        let s = &self.sfm;
        for (field, v) in [
            ("sfm.rotation_noise_deg", s.rotation_noise_deg),
            ("sfm.translation_noise_m", s.translation_noise_m),
            ("sfm.feature_noise_px", s.feature_noise_px),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SimError::Option {
                    field,
                    reason: "must be a finite value ≥ 0".into(),
                });
            }
        }
        if !(0.0..0.5).contains(&s.focal_guess_error) {
            return Err(SimError::Option {
                field: "sfm.focal_guess_error",
                reason: "must be in [0, 0.5)".into(),
            });
        }
        if !(0.0..=0.5).contains(&s.mismatch_fraction) {
            return Err(SimError::Option {
                field: "sfm.mismatch_fraction",
                reason: "must be in [0, 0.5]".into(),
            });
        }
        if !(self.margin_px.is_finite() && self.margin_px >= 0.0) {
            return Err(SimError::Option {
                field: "margin_px",
                reason: "must be ≥ 0".into(),
            });
        }
        if let Some(video) = &self.video {
            video.validate()?;
        }
        Ok(())
    }

    /// The frame file name of frame `k` (0-based).
    #[must_use]
    pub fn frame_name(&self, k: usize) -> String {
        let ext = if self.render.jpeg_quality.is_some() {
            "jpg"
        } else {
            "png"
        };
        format!("frame_{:04}.{ext}", k + 1)
    }
}

impl From<VideoConfigError> for SimError {
    fn from(e: VideoConfigError) -> Self {
        SimError::Option {
            field: e.field,
            reason: e.reason,
        }
    }
}
