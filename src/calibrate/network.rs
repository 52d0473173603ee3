//! The adjusted network of a calibration: every target with its covariance, views and residual
//! RMS, every adjusted frame's pose with its σ (for `report.json`), and the network as a COLMAP
//! model (`calibrate --network DIR`): the profile's camera where COLMAP can hold it, the images
//! at their adjusted poses, the targets as points3D with their observations.

use nalgebra::{Matrix3, Matrix3x6, Matrix6};
use serde::Serialize;

use super::pipeline::Calibration;
use crate::camera::BrownCamera;
use crate::camera::convert::{ColmapModel, ConvertError, colmap_from_brown};
use crate::geometry::pose::{camera_centre, colmap_from_rigid, skew};
use crate::io::colmap::{
    CameraId, Image, ImageId, Point2D, Point3D, Point3dId, Reconstruction, TrackElement,
};

/// An adjusted target.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NetworkTarget {
    /// Index (0-based, the order of [`Calibration::points`]).
    pub id: usize,
    /// Coordinates in the SfM frame (the inner-constraint datum of the adjustment).
    pub xyz: [f64; 3],
    /// σ per axis (SfM units), minimum trace over all targets.
    pub std: Option<[f64; 3]>,
    /// Full covariance (SfM units²), row-major.
    pub covariance: Option<[[f64; 3]; 3]>,
    /// The frames it is observed in (names).
    pub views: Vec<String>,
    /// RMS of its image residuals per coordinate (px).
    pub residual_rms_px: f64,
}

/// An adjusted frame.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NetworkFrame {
    /// Image name.
    pub name: String,
    /// `cam_from_world` rotation (w, x, y, z), COLMAP's convention.
    pub qvec: [f64; 4],
    /// `cam_from_world` translation.
    pub tvec: [f64; 3],
    /// Projection centre in the SfM frame.
    pub centre: [f64; 3],
    /// σ of the rotation about the camera's axes (degrees).
    pub rotation_std_deg: Option<[f64; 3]>,
    /// σ of the projection centre per SfM axis (SfM units).
    pub centre_std: Option<[f64; 3]>,
}

/// The adjusted network.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Network {
    /// Targets.
    pub targets: Vec<NetworkTarget>,
    /// Frames of the final adjustment.
    pub frames: Vec<NetworkFrame>,
}

/// σ of the projection centre from the covariance of `(δω, δt)` ([`crate::geometry::pose`]'s
/// step: `R ← exp([δω]×)R`, `t ← t + δt`): `C = −Rᵀt`, so `δC = −Rᵀ([t]×δω + δt)`.
fn centre_covariance(pose: &crate::geometry::Rigid3, cov: &Matrix6<f64>) -> Matrix3<f64> {
    let rt = pose.rotation.inverse().to_rotation_matrix().into_inner();
    let mut j = Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-rt * skew(&pose.translation.vector)));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rt));
    j * cov * j.transpose()
}

/// The network of a calibration.
#[must_use]
pub fn network(cal: &Calibration) -> Network {
    let n = cal.points.len();
    let mut views: Vec<Vec<String>> = vec![Vec::new(); n];
    let mut sq = vec![(0.0, 0usize); n];
    for o in &cal.observations {
        if let (Some(v), Some(s)) = (views.get_mut(o.target), sq.get_mut(o.target)) {
            v.push(cal.frame_names[o.frame].clone());
            s.0 += o.residual[0].powi(2) + o.residual[1].powi(2);
            s.1 += 2;
        }
    }
    let targets = cal
        .points
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let cov = cal.point_covariance.as_ref().and_then(|c| c.get(k));
            NetworkTarget {
                id: k,
                xyz: (*p).into(),
                std: cov.map(|c| [0, 1, 2].map(|i| c[(i, i)].max(0.0).sqrt())),
                covariance: cov.map(|c| [0, 1, 2].map(|i| [0, 1, 2].map(|j| c[(i, j)]))),
                views: std::mem::take(&mut views[k]),
                residual_rms_px: if sq[k].1 > 0 {
                    (sq[k].0 / sq[k].1 as f64).sqrt()
                } else {
                    0.0
                },
            }
        })
        .collect();
    let frames = cal
        .adjusted_frames
        .iter()
        .enumerate()
        .map(|(j, &f)| {
            let pose = &cal.cam_from_world[f];
            let (qvec, tvec) = colmap_from_rigid(pose);
            let cov = cal.pose_covariance.as_ref().and_then(|c| c.get(j));
            NetworkFrame {
                name: cal.frame_names[f].clone(),
                qvec,
                tvec,
                centre: camera_centre(pose).coords.into(),
                rotation_std_deg: cov
                    .map(|c| [0, 1, 2].map(|i| c[(i, i)].max(0.0).sqrt().to_degrees())),
                centre_std: cov.map(|c| {
                    let cc = centre_covariance(pose, c);
                    [0, 1, 2].map(|i| cc[(i, i)].max(0.0).sqrt())
                }),
            }
        })
        .collect();
    Network { targets, frames }
}

/// The network as a COLMAP model, with how exactly its camera holds the profile's.
#[derive(Clone, Debug)]
pub struct ColmapNetwork {
    /// The model.
    pub model: Reconstruction,
    /// The COLMAP camera model used.
    pub camera_model: ColmapModel,
    /// Whether it holds the profile exactly.
    pub exact: bool,
    /// Largest projection difference to the profile over the image when not exact (px).
    pub max_error_px: f64,
    /// Terms COLMAP's model lacks.
    pub missing_terms: Vec<&'static str>,
}

/// The adjusted network as a COLMAP model: the camera in the simplest COLMAP model that holds
/// `camera` exactly (OPENCV or FULL_OPENCV when it has tangential or k3 terms; the one of
/// least error otherwise — affinity and shear b1, b2 have no COLMAP counterpart), one image
/// per adjusted frame at its adjusted pose with its target observations as points2D (observed
/// pixels of the corrected centres), one point3D per target with its track and residual RMS.
///
/// # Errors
///
/// [`ConvertError`] when no COLMAP model can be fitted to the camera over its image.
pub fn colmap_network(
    cal: &Calibration,
    camera: &BrownCamera,
) -> Result<ColmapNetwork, ConvertError> {
    let mut best: Option<(ColmapModel, crate::camera::convert::Converted<_>)> = None;
    let mut last_err = None;
    for model in ColmapModel::CONVERTIBLE {
        match colmap_from_brown(camera, model) {
            Ok(c) => {
                let better = best
                    .as_ref()
                    .is_none_or(|(_, b)| !b.exact && c.max_error_px < b.max_error_px - 1e-12);
                if better {
                    best = Some((model, c));
                }
                if best.as_ref().is_some_and(|(_, b)| b.exact) {
                    break;
                }
            }
            Err(e) => last_err = Some(e),
        }
    }
    let Some((camera_model, converted)) = best else {
        return Err(last_err.unwrap_or(ConvertError::InvalidParameters));
    };
    let mut model = Reconstruction::default();
    model.cameras.insert(CameraId(1), converted.camera.clone());
    let net = network(cal);
    // Image ids 1.. in the order of the adjusted frames; frame index → image id.
    let mut image_of = vec![None; cal.frame_names.len()];
    for (j, &f) in cal.adjusted_frames.iter().enumerate() {
        let id = ImageId(j as u32 + 1);
        image_of[f] = Some(id);
        let mut image = Image {
            qvec: [1.0, 0.0, 0.0, 0.0],
            tvec: [0.0; 3],
            camera_id: CameraId(1),
            name: cal.frame_names[f].clone(),
            points2d: Vec::new(),
        };
        image.set_cam_from_world(&cal.cam_from_world[f]);
        model.images.insert(id, image);
    }
    let mut tracks: Vec<Vec<TrackElement>> = vec![Vec::new(); cal.points.len()];
    for o in &cal.observations {
        let Some(id) = image_of.get(o.frame).copied().flatten() else {
            continue;
        };
        let Some(image) = model.images.get_mut(&id) else {
            continue;
        };
        tracks[o.target].push(TrackElement {
            image_id: id,
            point2d_idx: image.points2d.len() as u32,
        });
        image.points2d.push(Point2D {
            uv: nalgebra::Vector2::new(o.uv[0], o.uv[1]),
            point3d_id: Some(Point3dId(o.target as u64 + 1)),
        });
    }
    for (k, (track, target)) in tracks.into_iter().zip(&net.targets).enumerate() {
        if track.is_empty() {
            continue;
        }
        model.points3d.insert(
            Point3dId(k as u64 + 1),
            Point3D {
                xyz: target.xyz,
                rgb: [255, 255, 255],
                error: target.residual_rms_px * std::f64::consts::SQRT_2,
                track,
            },
        );
    }
    Ok(ColmapNetwork {
        model,
        camera_model,
        exact: converted.exact,
        max_error_px: converted.max_error_px,
        missing_terms: converted.missing_terms,
    })
}
