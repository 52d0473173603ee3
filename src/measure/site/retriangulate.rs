//! The dense cloud re-triangulated through the profile's camera and the re-adjusted poses, when
//! COLMAP's `fused.ply.vis` says which images saw each point (otherwise the points as given).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::SiteError;
use super::scaling::{Ray, ray_pose};
use crate::calibrate::poses::RollingPoses;
use crate::calibrate::views::FrameCamera;
use crate::camera::convert::brown_from_colmap;
use crate::geometry::triangulation::{Observation, triangulate};
use crate::io::colmap::{ImageId, Reconstruction};

/// The dense cloud in the frame of the re-adjusted poses: each point projected through the
/// model's own camera at the model's poses into the images `visibility` names (positions in
/// `image_order`, the model's images file), and triangulated again from those pixels through
/// `cameras` (the profile's intrinsics at the re-adjusted poses). The cloud COLMAP fused with
/// its own camera carries that camera's errors; this is the same cloud as the profile sees it.
/// Points with fewer than two usable views are dropped; returned with how many, and per kept
/// point its views (index into `cameras`, ideal image coordinates under the new intrinsics,
/// the row). With `rolling`, each view is triangulated at its row's pose (the row where the
/// model's camera sees the point).
///
/// # Errors
///
/// [`SiteError`] for an image index or id the model does not have.
pub fn retriangulate_cloud(
    points: &[Vector3<f64>],
    visibility: &[Vec<u32>],
    model: &Reconstruction,
    image_order: &[ImageId],
    cameras: &[(ImageId, FrameCamera)],
    rolling: Option<&RollingPoses>,
) -> Result<RetriangulatedCloud, SiteError> {
    // Per position in the images file: the model's camera and pose, and the new camera.
    let mut views = Vec::with_capacity(image_order.len());
    for id in image_order {
        let image = model.images.get(id).ok_or(SiteError::ImageOrder(id.0))?;
        let cam = model
            .cameras
            .get(&image.camera_id)
            .ok_or(SiteError::ImageWithoutCamera(id.0))?;
        let original = brown_from_colmap(cam)
            .map_err(SiteError::Camera)?
            .camera
            .intrinsics;
        let new = cameras.iter().position(|(i, _)| i == id);
        views.push((original, image.cam_from_world(), new));
    }
    let n_views = views.len();
    if let Some(bad) = visibility
        .iter()
        .flatten()
        .find(|&&k| k as usize >= n_views)
    {
        return Err(SiteError::Visibility {
            image: *bad,
            images: n_views,
        });
    }
    let out: Vec<Option<(Vector3<f64>, Vec<Ray>)>> = points
        .par_iter()
        .zip(visibility)
        .map(|(x, vis)| {
            let rays: Vec<Ray> = vis
                .iter()
                .filter_map(|&k| {
                    let (original, pose, new) = views.get(k as usize)?;
                    let frame = (*new)?;
                    let uv = original.project(&(pose * Point3::from(*x)).coords)?;
                    let xy = cameras[frame].1.intrinsics.ideal_from_pixel(&uv).ok()?;
                    Some(Ray {
                        frame,
                        xy,
                        row_px: uv.y,
                    })
                })
                .collect();
            let p = triangulate_rays(&rays, &|j| cameras[j].1.cam_from_world, rolling)?;
            Some((p, rays))
        })
        .collect();
    let dropped = out.iter().filter(|p| p.is_none()).count();
    let (points, rays) = out.into_iter().flatten().unzip();
    Ok(RetriangulatedCloud {
        points,
        rays,
        dropped,
    })
}

/// The cloud re-triangulated by [`retriangulate_cloud`].
#[derive(Clone, Debug, Default)]
pub struct RetriangulatedCloud {
    /// The points.
    pub points: Vec<Vector3<f64>>,
    /// Per point its views (ideal image coordinates).
    pub rays: Vec<Vec<Ray>>,
    /// Points dropped for fewer than two usable views.
    pub dropped: usize,
}

/// A point triangulated from ideal image coordinates in the frames' cameras `pose(frame)`
/// (each ray at its row's pose with `rolling`); `None` for fewer than two views or a
/// degenerate configuration.
pub(super) fn triangulate_rays(
    rays: &[Ray],
    pose: &dyn Fn(usize) -> crate::geometry::Rigid3,
    rolling: Option<&RollingPoses>,
) -> Option<Vector3<f64>> {
    if rays.len() < 2 {
        return None;
    }
    let obs: Vec<Observation> = rays
        .iter()
        .map(|ray| Observation::normalized(&ray_pose(rolling, ray, &pose(ray.frame)), ray.xy))
        .collect();
    triangulate(&obs).map(|p| p.coords)
}

/// The cloud as given, with no views.
pub(super) fn as_given(points: &[Vector3<f64>]) -> RetriangulatedCloud {
    RetriangulatedCloud {
        points: points.to_vec(),
        rays: Vec::new(),
        dropped: 0,
    }
}
