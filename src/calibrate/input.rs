//! The calibration's input from a folder of frames: the frames' SfM model (read, or
//! reconstructed by COLMAP from the frames alone, a video's neighbour frames left out), the
//! frame size the model's single camera holds, and the frames the model names, each checked
//! to be in the folder.

use std::path::{Path, PathBuf};

use crate::io::ReadError;
use crate::io::colmap::{
    ColmapOptions, ColmapProgress, ColmapRunError, Reconstruction, run_colmap_sfm_with,
};
use crate::io::sidecar::FramesSidecar;

/// How many missing frames [`InputError::MissingFrames`] names.
const NAMED_MISSING: usize = 3;

/// Why the frames and their model cannot be calibrated from.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InputError {
    /// The model has no camera.
    #[error("the SfM model has no camera")]
    NoCamera,
    /// The model's cameras are of different sizes.
    #[error(
        "the SfM model has cameras of different sizes ({}x{} and {}x{}): calibrate one device at one frame size",
        first.0,
        first.1,
        other.0,
        other.1
    )]
    MixedSizes {
        /// The first camera's size (px).
        first: (u64, u64),
        /// Another's.
        other: (u64, u64),
    },
    /// A camera's size does not fit in 32 bits.
    #[error("the SfM model's camera is {0}x{1} px: too large")]
    TooLarge(u64, u64),
    /// Images of the model are not in the frames folder.
    #[error(
        "{missing} of the model's {images} images are not in {} (first: {}): is it the folder the model was built from?",
        frames.display(),
        first.join(", ")
    )]
    MissingFrames {
        /// How many are missing.
        missing: usize,
        /// The model's image count.
        images: usize,
        /// The frames folder.
        frames: PathBuf,
        /// The first few missing names.
        first: Vec<String>,
    },
    /// The frames' sidecar (`frames.json`) could not be read.
    #[error(transparent)]
    Sidecar(#[from] ReadError),
    /// COLMAP's reconstruction failed.
    #[error("COLMAP sparse reconstruction: {0}")]
    Colmap(#[from] ColmapRunError),
}

/// The SfM model of the frames in `frames`, reconstructed by COLMAP in `work` (features,
/// sequential matching, mapping; `progress` as COLMAP reports). A video's frames extracted by
/// `pipemeasure frames` list themselves in `frames.json`: only they are reconstructed, not
/// their neighbours in the video (which COLMAP would otherwise read, recursively).
///
/// # Errors
///
/// [`InputError::Sidecar`] for an unreadable `frames.json`, [`InputError::Colmap`] when COLMAP
/// is missing or fails.
pub fn reconstruct_frames(
    frames: &Path,
    work: &Path,
    options: &ColmapOptions,
    progress: &dyn Fn(ColmapProgress),
) -> Result<Reconstruction, InputError> {
    let list = listed_frames(frames)?;
    Ok(run_colmap_sfm_with(
        frames,
        work,
        list.as_deref(),
        options,
        progress,
    )?)
}

/// The frames `frames.json` lists in `frames`, when there is one.
///
/// # Errors
///
/// [`ReadError`] for a sidecar that cannot be read.
pub fn listed_frames(frames: &Path) -> Result<Option<Vec<String>>, ReadError> {
    let sidecar = frames.join("frames.json");
    if !sidecar.is_file() {
        return Ok(None);
    }
    Ok(Some(
        FramesSidecar::read(&sidecar)?
            .frames
            .into_iter()
            .map(|f| f.name)
            .collect(),
    ))
}

/// The frame size of the model's (single) camera, checked against every camera.
///
/// # Errors
///
/// [`InputError::NoCamera`], [`InputError::MixedSizes`], [`InputError::TooLarge`].
pub fn frame_size(model: &Reconstruction) -> Result<(u32, u32), InputError> {
    let mut sizes = model.cameras.values().map(|c| (c.width, c.height));
    let Some(first) = sizes.next() else {
        return Err(InputError::NoCamera);
    };
    if let Some(other) = sizes.find(|s| *s != first) {
        return Err(InputError::MixedSizes { first, other });
    }
    match (u32::try_from(first.0), u32::try_from(first.1)) {
        (Ok(w), Ok(h)) => Ok((w, h)),
        _ => Err(InputError::TooLarge(first.0, first.1)),
    }
}

/// The names of the model's images, each a file in `frames`.
///
/// # Errors
///
/// [`InputError::MissingFrames`] naming the first few that are not.
pub fn model_frames(model: &Reconstruction, frames: &Path) -> Result<Vec<String>, InputError> {
    let names: Vec<String> = model.images.values().map(|i| i.name.clone()).collect();
    let missing: Vec<&String> = names.iter().filter(|n| !frames.join(n).is_file()).collect();
    if missing.is_empty() {
        return Ok(names);
    }
    Err(InputError::MissingFrames {
        missing: missing.len(),
        images: names.len(),
        frames: frames.to_path_buf(),
        first: missing
            .iter()
            .take(NAMED_MISSING)
            .map(|s| (*s).clone())
            .collect(),
    })
}
