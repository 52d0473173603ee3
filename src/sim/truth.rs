//! Ground truth written beside every simulated scene (`truth.json`, schema
//! `pipemeasure.truth/1`): the true camera and poses, every target and pipe, and per frame per
//! visible target three exact image quantities:
//!
//! * `centre_px`: the projection of the true 3D centre through the full (distorted) camera;
//! * `pinhole`: the exact ellipse of the disc's edge in the *undistorted pinhole* image, i.e. the
//!   camera without distortion, pixels `u = (c + b1)·x + b2·y + u0`, `v = c·y + v0` (the conic
//!   of the projected circle, docs/math.md §3.2), with `pinhole_centre_px` the pinhole projection
//!   of the true centre (the eccentricity is `pinhole.centre − pinhole_centre_px`);
//! * `fitted`: the ellipse fitted by plain direct least squares to 720 exact points of the disc's
//!   edge projected through the full distorted camera — what an ideal detector should find.
//!
//! A target is visible in a frame when its centre is in front of the camera, its face points
//! toward the camera, all 720 edge points project inside the frame at least `margin_px` from
//! the border, and the centre and 16 edge points are not hidden by any surface.

use nalgebra::{Matrix3, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::render::RenderConfig;
use super::scene::{Scene, Target};
use crate::camera::{BrownCamera, Intrinsics};
use crate::geometry::Rigid3;
use crate::geometry::conic::{Ellipse, conic_of_circle, fit_ellipse_direct};
use crate::geometry::pose::{camera_centre, colmap_from_rigid, rigid_from_colmap};

/// Schema tag of truth files.
pub const TRUTH_SCHEMA: &str = "pipemeasure.truth/1";
/// Edge points used for the fitted ellipse.
const EDGE_POINTS: usize = 720;
/// Edge points tested for occlusion (plus the centre).
const OCCLUSION_POINTS: usize = 16;

/// How the phone was held.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Orientation {
    /// Upright (the camera rolled 90° about its optical axis).
    Portrait,
    /// Sideways (no roll).
    Landscape,
}

/// The true camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TruthCamera {
    /// Device preset imitated.
    pub device: String,
    /// Frame width (px).
    pub width: u32,
    /// Frame height (px).
    pub height: u32,
    /// True intrinsics.
    pub intrinsics: Intrinsics,
}

impl TruthCamera {
    /// As a camera.
    #[must_use]
    pub fn camera(&self) -> BrownCamera {
        BrownCamera {
            width: self.width,
            height: self.height,
            intrinsics: self.intrinsics,
        }
    }
}

/// One target as seen in one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TargetView {
    /// Target id.
    pub id: u32,
    /// Projection of the true centre through the distorted camera (px).
    pub centre_px: [f64; 2],
    /// Projection of the true centre in the undistorted pinhole image (px).
    pub pinhole_centre_px: [f64; 2],
    /// Exact ellipse of the disc edge in the undistorted pinhole image.
    pub pinhole: Ellipse,
    /// Ellipse fitted to exact distorted edge points: what a detector should find.
    pub fitted: Ellipse,
}

/// One frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TruthFrame {
    /// COLMAP image id (1-based, frame order).
    pub image_id: u32,
    /// File name in `frames/`.
    pub name: String,
    /// True pose `cam_from_world`: quaternion (w, x, y, z).
    pub qvec: [f64; 4],
    /// True pose `cam_from_world`: translation.
    pub tvec: [f64; 3],
    /// Portrait or landscape.
    pub orientation: Orientation,
    /// Visible targets.
    pub targets: Vec<TargetView>,
}

impl TruthFrame {
    /// The true pose.
    #[must_use]
    pub fn cam_from_world(&self) -> Rigid3 {
        rigid_from_colmap(self.qvec, self.tvec)
    }
}

/// The similarity from the true (world) frame to the SfM frame: `X_sfm = s·R·X + t`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Similarity {
    /// Scale s.
    pub scale: f64,
    /// Rotation R as a quaternion (w, x, y, z).
    pub qvec: [f64; 4],
    /// Translation t.
    pub tvec: [f64; 3],
}

impl Similarity {
    /// The identity.
    #[must_use]
    pub fn identity() -> Self {
        Similarity {
            scale: 1.0,
            qvec: [1.0, 0.0, 0.0, 0.0],
            tvec: [0.0; 3],
        }
    }

    /// Maps a world point to the SfM frame.
    #[must_use]
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        let r = rigid_from_colmap(self.qvec, self.tvec);
        let rotated = r.rotation * p.coords * self.scale;
        Point3::from(rotated + r.translation.vector)
    }

    /// `cam_from_sfm` for a camera at true pose `cam_from_world`: the camera frame is scaled
    /// with the world, `p_cam' = s·p_cam`.
    #[must_use]
    pub fn pose_in_sfm(&self, cam_from_world: &Rigid3) -> Rigid3 {
        let r = rigid_from_colmap(self.qvec, self.tvec);
        let rotation = cam_from_world.rotation * r.rotation.inverse();
        let t = cam_from_world.translation.vector * self.scale - rotation * r.translation.vector;
        Rigid3::from_parts(nalgebra::Translation3::from(t), rotation)
    }
}

/// How the sparse model was made and how far it is from the truth.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SfmTruth {
    /// `stand-in` (simulated) or `colmap` (real COLMAP on the rendered frames).
    pub source: String,
    /// 3D points in the model.
    pub points: usize,
    /// What the stand-in did (absent for COLMAP, whose own frame and errors are unknown).
    pub stand_in: Option<StandInTruth>,
}

/// The perturbations the SfM stand-in applied.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StandInTruth {
    /// Similarity from the true frame to the SfM frame.
    pub similarity: Similarity,
    /// σ of the rotation error of each pose, per axis (degrees).
    pub rotation_noise_deg: f64,
    /// σ of the camera-centre error per axis (m, true units).
    pub translation_noise_m: f64,
    /// The focal length the SIMPLE_RADIAL camera was initialised with (px).
    pub focal_guess_px: f64,
    /// σ of the feature positions (px).
    pub feature_noise_px: f64,
    /// Fraction of feature observations made gross mismatches.
    pub mismatch_fraction: f64,
    /// Observations that were made gross mismatches.
    pub mismatches: usize,
    /// The stand-in's bundle adjustment, when it ran (then `similarity` is the best fit of the
    /// world onto the adjusted points).
    #[serde(default)]
    pub adjustment: Option<StandInAdjustment>,
}

/// What the SfM stand-in's bundle adjustment ([`super::bundle`]) did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StandInAdjustment {
    /// The least-squares similarity from the true world onto the adjusted points.
    pub similarity: Similarity,
    /// The SIMPLE_RADIAL camera's focal length before (the EXIF-like guess) and after (px).
    pub initial_focal_px: f64,
    /// Focal length after (px).
    pub focal_px: f64,
    /// Radial coefficient after.
    pub k: f64,
    /// RMS reprojection error before and after (px; each error capped at 100 px before).
    pub initial_rms_px: f64,
    /// RMS after.
    pub rms_px: f64,
    /// Observations removed for an error above 4 px.
    pub removed_observations: usize,
    /// Points removed for fewer than two observations left.
    pub removed_points: usize,
}

/// A pipe of the site.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PipeTruth {
    /// Name (`pipe_4in`, ...).
    pub name: String,
    /// Outside radius (m).
    pub radius: f64,
    /// A point of the axis (world).
    pub axis_point: [f64; 3],
    /// Unit axis direction.
    pub axis_direction: [f64; 3],
    /// Length (m).
    pub length: f64,
    /// Whether this is the pipe the site survey is about.
    pub of_interest: bool,
}

/// The TLS survey of the site.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TlsTruth {
    /// Scanner position (world).
    pub station: [f64; 3],
    /// Offset added to world coordinates in the TLS files (site coordinates are large).
    pub offset: [f64; 3],
    /// σ of the range noise of scan points (m).
    pub range_noise_m: f64,
    /// σ of the target coordinates per axis (m).
    pub target_noise_m: f64,
    /// Points in `tls_scan.ply`.
    pub points: usize,
}

/// The dense observations of a site.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DenseTruth {
    /// Surface points in `dense/observations.bin`.
    pub points: usize,
    /// Their observations.
    pub observations: usize,
    /// σ of the observation noise (px).
    pub noise_px: f64,
    /// Points in `dense/fused.ply`.
    pub fused_points: usize,
    /// Label names by index (`wall`, `floor`, then the pipes).
    pub labels: Vec<String>,
}

/// Everything known about a simulated scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    /// Always [`TRUTH_SCHEMA`].
    pub schema: String,
    /// `lab` or `site`.
    pub scene: String,
    /// The seed.
    pub seed: u64,
    /// The command that made it.
    pub command: String,
    /// The true camera.
    pub camera: TruthCamera,
    /// Rendering options.
    pub render: RenderConfig,
    /// Visibility margin used for `targets` per frame (px).
    pub margin_px: f64,
    /// Targets.
    pub targets: Vec<Target>,
    /// Frames.
    pub frames: Vec<TruthFrame>,
    /// The sparse model.
    pub sfm: Option<SfmTruth>,
    /// Pipes (site).
    #[serde(default)]
    pub pipes: Vec<PipeTruth>,
    /// TLS survey (site).
    #[serde(default)]
    pub tls: Option<TlsTruth>,
    /// Dense observations (site).
    #[serde(default)]
    pub dense: Option<DenseTruth>,
}

impl Truth {
    /// Reads a truth file.
    ///
    /// # Errors
    ///
    /// A read error naming the file, or the JSON field that does not match.
    pub fn read(path: &std::path::Path) -> Result<Self, crate::io::ReadError> {
        use crate::io::{ReadError, ReadErrorKind};
        let text = std::fs::read_to_string(path)
            .map_err(|e| ReadError::new(path, ReadErrorKind::Io(e)))?;
        let de = &mut serde_json::Deserializer::from_str(&text);
        serde_path_to_error::deserialize(de).map_err(|e| {
            ReadError::new(
                path,
                ReadErrorKind::Json {
                    field: e.path().to_string(),
                    message: e.inner().to_string(),
                },
            )
        })
    }
}

/// Unit vectors spanning the target's plane.
fn plane_axes(normal: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if normal.z.abs() < 0.9 {
        Vector3::z()
    } else {
        Vector3::x()
    };
    let u = helper.cross(normal).normalize();
    (u, normal.cross(&u))
}

/// The calibration matrix of the undistorted pinhole image
/// ([`Intrinsics::pinhole_matrix`]).
#[must_use]
pub fn pinhole_matrix(i: &Intrinsics) -> Matrix3<f64> {
    i.pinhole_matrix()
}

/// The view of `target` from a camera, or `None` if it is not visible by the rule of the module
/// documentation.
#[must_use]
pub fn target_view(
    scene: &Scene,
    camera: &BrownCamera,
    cam_from_world: &Rigid3,
    target: &Target,
    margin_px: f64,
) -> Option<TargetView> {
    let centre = Vector3::from(target.centre);
    let normal = Vector3::from(target.normal);
    let eye = camera_centre(cam_from_world);
    let p_cam = cam_from_world.rotation * centre + cam_from_world.translation.vector;
    if p_cam.z <= 0.0 || normal.dot(&(eye.coords - centre)) <= 0.0 {
        return None;
    }
    let (u, v) = plane_axes(&normal);
    let edge_world = |phi: f64| centre + (u * phi.cos() + v * phi.sin()) * target.radius;
    let mut edge_px = Vec::with_capacity(EDGE_POINTS);
    for k in 0..EDGE_POINTS {
        let phi = std::f64::consts::TAU * k as f64 / EDGE_POINTS as f64;
        let uv = camera.project_world(cam_from_world, &edge_world(phi))?;
        if !camera.contains(&uv, margin_px) {
            return None;
        }
        edge_px.push(uv);
    }
    // Occlusion: the centre and 16 edge points must be in view (a target's own wall is ignored
    // within 1 mm).
    let tolerance = 1e-3;
    if !scene.visible(&eye, &Point3::from(centre), tolerance) {
        return None;
    }
    for k in 0..OCCLUSION_POINTS {
        let phi = std::f64::consts::TAU * k as f64 / OCCLUSION_POINTS as f64;
        if !scene.visible(&eye, &Point3::from(edge_world(phi)), tolerance) {
            return None;
        }
    }
    let centre_px = camera.project_world(cam_from_world, &centre)?;
    let k = pinhole_matrix(&camera.intrinsics);
    let conic = conic_of_circle(&k, cam_from_world, &centre, &normal, target.radius)?;
    let pinhole = Ellipse::from_conic(&conic)?;
    let pc = k * (p_cam / p_cam.z);
    let fitted = fit_ellipse_direct(&edge_px)?;
    Some(TargetView {
        id: target.id,
        centre_px: [centre_px.x, centre_px.y],
        pinhole_centre_px: [pc.x, pc.y],
        pinhole,
        fitted,
    })
}

/// A frame's truth record.
#[must_use]
pub fn frame_truth(
    scene: &Scene,
    camera: &BrownCamera,
    image_id: u32,
    name: &str,
    cam_from_world: &Rigid3,
    orientation: Orientation,
    margin_px: f64,
) -> TruthFrame {
    let (qvec, tvec) = colmap_from_rigid(cam_from_world);
    let targets = scene
        .targets
        .iter()
        .filter_map(|t| target_view(scene, camera, cam_from_world, t, margin_px))
        .collect();
    TruthFrame {
        image_id,
        name: name.into(),
        qvec,
        tvec,
        orientation,
        targets,
    }
}

/// The pixel of a world point in a frame, if in front of the camera (helper for consumers).
#[must_use]
pub fn project(camera: &BrownCamera, frame: &TruthFrame, p: &Point3<f64>) -> Option<Vector2<f64>> {
    camera.project_world(&frame.cam_from_world(), &p.coords)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn similarity_maps_poses_consistently() {
        let s = Similarity {
            scale: 2.5,
            qvec: {
                let (q, _) = colmap_from_rigid(&Isometry3::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_euler_angles(0.3, 1.0, -2.0),
                ));
                q
            },
            tvec: [1.0, -2.0, 3.0],
        };
        let pose = Isometry3::from_parts(
            Translation3::new(0.2, 0.1, 4.0),
            UnitQuaternion::from_euler_angles(-0.2, 0.4, 0.1),
        );
        let x = Point3::new(0.3, -0.7, 1.1);
        let p_cam = pose * x;
        let p_cam_sfm = s.pose_in_sfm(&pose) * s.apply(&x);
        assert!((p_cam_sfm.coords - p_cam.coords * 2.5).norm() < 1e-12);
    }
}
