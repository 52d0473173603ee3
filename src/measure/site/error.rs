//! Why a site could not be measured: each input named as the request holds it
//! ([`SiteInput`]), so that a front end can say how to give it (the command line names its
//! option) while the library names only what the input is.

use std::fmt;
use std::path::PathBuf;

use super::super::cylinder::CylinderError;
use super::super::network::NetworkError;
use super::super::scale::ScaleError;
use crate::calibrate::pipeline::CalibrateError;
use crate::camera::convert::ConvertError;
use crate::detect::DetectFilesError;
use crate::io::ReadError;
use crate::profile::ProfileError;

/// An input of the site's measurement, as [`super::SiteRequest`] holds it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SiteInput {
    /// The device profile.
    Device,
    /// The SfM model.
    Sfm,
    /// The frames folder.
    Frames,
    /// The TLS target list.
    TlsTargets,
    /// The TLS targets selected from the list.
    TlsIds,
    /// A given scale.
    Scale,
}

impl fmt::Display for SiteInput {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SiteInput::Device => "device profile",
            SiteInput::Sfm => "SfM model",
            SiteInput::Frames => "frames folder",
            SiteInput::TlsTargets => "TLS target list",
            SiteInput::TlsIds => "TLS target selection",
            SiteInput::Scale => "scale",
        })
    }
}

/// Why the site could not be measured.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SiteError {
    /// No device profile, and no scale given: the targets cannot be observed.
    #[error("a device profile is needed to scale the cloud from the targets (or a given scale)")]
    NoDevice,
    /// A path given for an input does not exist.
    #[error("{input} {}: not found", path.display())]
    NotFound {
        /// The input.
        input: SiteInput,
        /// The path given.
        path: PathBuf,
    },
    /// An input not given was not found next to the cloud either.
    #[error(
        "no {input} found next to {} or up to two folders above it (looked for {})",
        cloud.display(),
        looked_for.join(", ")
    )]
    NotBeside {
        /// The input.
        input: SiteInput,
        /// The cloud it was searched beside.
        cloud: PathBuf,
        /// The names searched for.
        looked_for: Vec<String>,
    },
    /// A TLS target selected is not in the list.
    #[error("target `{id}` is not in {} (its ids: {})", path.display(), known.join(", "))]
    UnknownTlsId {
        /// The id selected.
        id: String,
        /// The TLS target list.
        path: PathBuf,
        /// The list's ids.
        known: Vec<String>,
    },
    /// Fewer than two TLS targets (after the selection).
    #[error("{}: {found} TLS target(s); the scale needs at least two", path.display())]
    TooFewTlsTargets {
        /// The TLS target list.
        path: PathBuf,
        /// How many it holds (selected).
        found: usize,
    },
    /// A given scale that is not a positive number.
    #[error("scale {0}: must be a positive number")]
    BadScale(f64),
    /// The SfM model has no registered image.
    #[error("the model {} has no registered images", .0.display())]
    NoImages(PathBuf),
    /// The SfM model has no camera.
    #[error("the model has no camera")]
    NoCamera,
    /// An image's camera is not in the model.
    #[error("image {0} has no camera")]
    ImageWithoutCamera(u32),
    /// The images file names an image twice, or one the model lacks.
    #[error("the images file names image {0} twice or not at all")]
    ImageOrder(u32),
    /// The model's camera cannot be read as a Brown camera.
    #[error("the model's camera: {0}")]
    Camera(#[source] ConvertError),
    /// The dense cloud's visibility names an image the model does not have.
    #[error("fused.ply.vis names image {image} but the model has {images} images")]
    Visibility {
        /// The image index named.
        image: u32,
        /// The model's image count.
        images: usize,
    },
    /// The profile is for frames of another aspect ratio than the model's.
    #[error(
        "device {device} ({}) is for {}x{} frames but the model's camera is {}x{}: another aspect ratio, so these frames are not from this device",
        profile.display(),
        profile_size.0,
        profile_size.1,
        model_size.0,
        model_size.1
    )]
    AspectRatio {
        /// The device's name.
        device: String,
        /// Its profile's path.
        profile: PathBuf,
        /// The profile's frame size (px).
        profile_size: (u32, u32),
        /// The model's (px).
        model_size: (u32, u32),
    },
    /// The model's pinhole camera is not the profile's undistorted one.
    #[error(
        "the model's pinhole camera has a principal distance of {model_c:.1} px, device {device} {device_c:.1} px at {}x{} ({:.0} % apart): these frames were not undistorted with this device's profile",
        size.0,
        size.1,
        100.0 * (model_c / device_c - 1.0).abs()
    )]
    NotUndistortedWithDevice {
        /// The device's name.
        device: String,
        /// The model's principal distance (px).
        model_c: f64,
        /// The profile's, at the model's size (px).
        device_c: f64,
        /// The model's frame size (px).
        size: (u32, u32),
    },
    /// A file could not be read.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The device profile.
    #[error(transparent)]
    Profile(#[from] ProfileError),
    /// The poses could not be re-adjusted to the profile.
    #[error("Algorithm 1 on {}: {source}", path.display())]
    Poses {
        /// The model.
        path: PathBuf,
        /// Why.
        #[source]
        source: CalibrateError,
    },
    /// Detection in the frames.
    #[error("detecting the targets of the model's frames: {0}")]
    Detect(#[from] DetectFilesError),
    /// The scale.
    #[error("scale from {}: {source}", path.display())]
    Scale {
        /// The TLS target list.
        path: PathBuf,
        /// Why.
        #[source]
        source: ScaleError,
    },
    /// The pipe network.
    #[error("the pipe network of {}: {source}", path.display())]
    Network {
        /// The cloud.
        path: PathBuf,
        /// Why.
        #[source]
        source: NetworkError,
    },
    /// The pipe fit.
    #[error("fitting the pipe in {}: {source}", path.display())]
    Fit {
        /// The cloud (or scan).
        path: PathBuf,
        /// Why.
        #[source]
        source: CylinderError,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The library names inputs, never a front end's options: every input's error reads
    /// without a `--flag`.
    #[test]
    fn errors_name_inputs_not_options() {
        let inputs = [
            SiteInput::Device,
            SiteInput::Sfm,
            SiteInput::Frames,
            SiteInput::TlsTargets,
            SiteInput::TlsIds,
            SiteInput::Scale,
        ];
        let mut errors = vec![
            SiteError::NoDevice,
            SiteError::BadScale(-1.0),
            SiteError::UnknownTlsId {
                id: "99".into(),
                path: "tls.csv".into(),
                known: vec!["1".into(), "2".into()],
            },
            SiteError::TooFewTlsTargets {
                path: "tls.csv".into(),
                found: 1,
            },
        ];
        for input in inputs {
            errors.push(SiteError::NotFound {
                input,
                path: "nowhere".into(),
            });
            errors.push(SiteError::NotBeside {
                input,
                cloud: "fused.ply".into(),
                looked_for: vec!["sparse".into()],
            });
        }
        for e in errors {
            let text = e.to_string();
            assert!(!text.contains("--"), "{text}");
        }
        assert_eq!(
            SiteError::NotFound {
                input: SiteInput::Sfm,
                path: "nowhere".into()
            }
            .to_string(),
            "SfM model nowhere: not found"
        );
    }
}
