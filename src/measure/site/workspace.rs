//! The site's workspace: the model, frames and TLS targets found next to the cloud (COLMAP's
//! workspace layout and the simulator's, searched in the cloud's folder and up to two folders
//! above it, nearest first), the model's image size, and the device profile's intrinsics at
//! that size.

use std::path::{Path, PathBuf};

use super::{SiteError, SiteInput};
use crate::camera::convert::{ColmapModel, brown_from_colmap};
use crate::camera::{BrownCamera, Intrinsics};
use crate::io::colmap::Reconstruction;

/// The first existing `name` in the cloud's folder, its parent and grandparent.
fn search_up(cloud: &Path, names: &[&str], ok: impl Fn(&Path) -> bool) -> Option<PathBuf> {
    let dir = match cloud.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    dir.ancestors()
        .take(3)
        .flat_map(|d| names.iter().map(move |n| d.join(n)))
        .find(|p| ok(p))
}

/// Whether `dir` holds a COLMAP model (its cameras file, text or binary).
pub(super) fn is_model(dir: &Path) -> bool {
    ["cameras.txt", "cameras.bin"]
        .iter()
        .any(|f| dir.join(f).is_file())
}

/// A path given, or searched for, or a clear error naming where we looked.
pub(super) fn resolve(
    given: Option<&PathBuf>,
    cloud: &Path,
    names: &[&str],
    ok: impl Fn(&Path) -> bool,
    input: SiteInput,
) -> Result<PathBuf, SiteError> {
    if let Some(p) = given {
        if !p.exists() {
            return Err(SiteError::NotFound {
                input,
                path: p.clone(),
            });
        }
        return Ok(p.clone());
    }
    search_up(cloud, names, ok).ok_or_else(|| SiteError::NotBeside {
        input,
        cloud: cloud.to_path_buf(),
        looked_for: names.iter().map(|n| (*n).to_owned()).collect(),
    })
}

/// The image size of the model's (first) camera.
///
/// # Errors
///
/// [`SiteError::NoCamera`] for a model without a camera.
pub fn model_image_size(model: &Reconstruction) -> Result<(u32, u32), SiteError> {
    let Some(camera) = model.cameras.values().next() else {
        return Err(SiteError::NoCamera);
    };
    Ok((
        u32::try_from(camera.width).unwrap_or(u32::MAX),
        u32::try_from(camera.height).unwrap_or(u32::MAX),
    ))
}

/// The intrinsics to observe the targets with: the profile's for frames as recorded, the
/// model's pinhole camera for frames already undistorted (checked against the profile); with
/// whether the frames are undistorted.
///
/// # Errors
///
/// [`SiteError::AspectRatio`] when the profile is for another aspect ratio,
/// [`SiteError::NotUndistortedWithDevice`] when the model's pinhole camera is not the profile's.
pub fn site_intrinsics(
    device: &str,
    profile_path: &Path,
    profile_cam: &BrownCamera,
    model: &Reconstruction,
) -> Result<(Intrinsics, bool), SiteError> {
    let Some(cam) = model.cameras.values().next() else {
        return Err(SiteError::NoCamera);
    };
    let (w, h) = model_image_size(model)?;
    if u64::from(profile_cam.width) * u64::from(h) != u64::from(profile_cam.height) * u64::from(w) {
        return Err(SiteError::AspectRatio {
            device: device.to_owned(),
            profile: profile_path.to_path_buf(),
            profile_size: (profile_cam.width, profile_cam.height),
            model_size: (w, h),
        });
    }
    let scaled = profile_cam.scaled(w, h);
    let model_cam = brown_from_colmap(cam).map_err(SiteError::Camera)?.camera;
    // COLMAP's undistorter (and `pipemeasure undistort`) write pinhole cameras; a model with a
    // distortion model (even one estimated as zero, or never refined) has the frames as recorded.
    let pinhole = matches!(cam.model, ColmapModel::Pinhole | ColmapModel::SimplePinhole);
    if !pinhole || model_cam.intrinsics.has_distortion() {
        return Ok((scaled.intrinsics, false));
    }
    let rel = (model_cam.intrinsics.c / scaled.intrinsics.c - 1.0).abs();
    if rel > 0.05 {
        return Err(SiteError::NotUndistortedWithDevice {
            device: device.to_owned(),
            model_c: model_cam.intrinsics.c,
            device_c: scaled.intrinsics.c,
            size: (w, h),
        });
    }
    Ok((model_cam.intrinsics, true))
}
