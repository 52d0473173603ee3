//! The site's workspace: the model, frames and TLS targets found next to the cloud (COLMAP's
//! workspace layout and the simulator's, searched in the cloud's folder and up to two folders
//! above it, nearest first), the model's image size, and the device profile's intrinsics at
//! that size.

use std::path::{Path, PathBuf};

use super::SiteError;
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
    what: &str,
    flag: &str,
) -> Result<PathBuf, SiteError> {
    if let Some(p) = given {
        if !p.exists() {
            return Err(SiteError::Input(format!(
                "{flag} {}: not found",
                p.display()
            )));
        }
        return Ok(p.clone());
    }
    search_up(cloud, names, ok).ok_or_else(|| {
        SiteError::Input(format!(
            "no {what} found next to {} or up to two folders above it (looked for {}); give it with {flag}",
            cloud.display(),
            names.join(", ")
        ))
    })
}

/// The image size of the model's (first) camera.
///
/// # Errors
///
/// [`SiteError::Input`] for a model without a camera.
pub fn model_image_size(model: &Reconstruction) -> Result<(u32, u32), SiteError> {
    let Some(camera) = model.cameras.values().next() else {
        return Err(SiteError::Input("the model has no camera".into()));
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
/// [`SiteError::Input`] when the profile is for another aspect ratio, or the model's pinhole
/// camera is not the profile's.
pub fn site_intrinsics(
    device: &str,
    profile_path: &Path,
    profile_cam: &BrownCamera,
    model: &Reconstruction,
) -> Result<(Intrinsics, bool), SiteError> {
    let Some(cam) = model.cameras.values().next() else {
        return Err(SiteError::Input("the model has no camera".into()));
    };
    let (w, h) = model_image_size(model)?;
    if u64::from(profile_cam.width) * u64::from(h) != u64::from(profile_cam.height) * u64::from(w) {
        return Err(SiteError::Input(format!(
            "device {device} ({}) is for {}x{} frames but the model's camera is {w}x{h}: another aspect ratio, so these frames are not from this device",
            profile_path.display(),
            profile_cam.width,
            profile_cam.height
        )));
    }
    let scaled = profile_cam.scaled(w, h);
    let model_cam = brown_from_colmap(cam)
        .map_err(|e| SiteError::Input(format!("the model's camera: {e}")))?
        .camera;
    // COLMAP's undistorter (and `pipemeasure undistort`) write pinhole cameras; a model with a
    // distortion model (even one estimated as zero, or never refined) has the frames as recorded.
    let pinhole = matches!(cam.model, ColmapModel::Pinhole | ColmapModel::SimplePinhole);
    if !pinhole || model_cam.intrinsics.has_distortion() {
        return Ok((scaled.intrinsics, false));
    }
    let rel = (model_cam.intrinsics.c / scaled.intrinsics.c - 1.0).abs();
    if rel > 0.05 {
        return Err(SiteError::Input(format!(
            "the model's pinhole camera has a principal distance of {:.1} px, device {device} {:.1} px at {w}x{h} ({:.0} % apart): these frames were not undistorted with this device's profile",
            model_cam.intrinsics.c,
            scaled.intrinsics.c,
            100.0 * rel
        )));
    }
    Ok((model_cam.intrinsics, true))
}
