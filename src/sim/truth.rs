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
//!
//! # Video (optional fields; absent for the default still, global-shutter frames)
//!
//! With `SimulateOptions::video` the frames come from a moving rolling-shutter camera
//! ([`super::video`]); the truth then adds, compatibly:
//!
//! * per frame `motion` ([`FrameMotion`]): its time, readout and exposure times, the angular and
//!   linear velocities at the frame time (camera frame, [`super::trajectory`]'s convention) and
//!   the principal distance used (focus breathing); the frame's `qvec`/`tvec` are the pose at
//!   the frame time (the middle row);
//! * per frame `neighbours`: the frames rendered 1/fps before and after it, as frames (their
//!   `motion.dt_s` is the offset; they are not in the sparse model);
//! * per target view `time_s`: the view is what the rolling-shutter camera sees — `centre_px`
//!   is the exact rolling-shutter projection of the centre ([`super::shutter`]), seen at
//!   `time_s`; `fitted` is fitted to the 720 edge points each projected exactly in its own row;
//!   `pinhole` and `pinhole_centre_px` are those of the pose at `time_s`, and visibility is
//!   judged from there;
//! * `video` ([`VideoTruth`]): the options, and the trajectory itself, so that
//!   `cam_from_world(t)` can be recomputed from the truth file alone.

use nalgebra::{Matrix3, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use rayon::prelude::*;

use super::render::RenderConfig;
use super::scene::{Scene, Target};
use super::shutter::{Shutter, project_rolling_shutter};
use super::trajectory::Trajectory;
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
    /// Video frames: the time the centre is seen (the middle of its row's exposure, s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_s: Option<f64>,
}

/// How a video frame was taken (see the module documentation).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameMotion {
    /// Frame time: the middle of the middle row's exposure (s).
    pub time_s: f64,
    /// Readout time (s): row v is exposed around `time_s + (v/H − 1/2)·readout_s`.
    pub readout_s: f64,
    /// Exposure time of every row (s).
    pub exposure_s: f64,
    /// ω at the frame time, camera frame (rad/s).
    pub angular_velocity: [f64; 3],
    /// ν at the frame time, camera frame (m/s).
    pub linear_velocity: [f64; 3],
    /// The principal distance c of this frame (px): the camera's, or under focus breathing
    /// the one following the focus distance (b1 and b2 scale with it).
    pub principal_distance: f64,
    /// Neighbours: the offset from their main frame (s); absent for main frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dt_s: Option<f64>,
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
    /// Video frames: time, shutter and motion.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion: Option<FrameMotion>,
    /// Video frames with neighbours: the frames 1/fps before and after this one (their
    /// `image_id` is this frame's; they are not in the sparse model).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub neighbours: Vec<TruthFrame>,
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
    /// Video: the options and the trajectory (absent for still frames).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub video: Option<VideoTruth>,
}

/// How the video was filmed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VideoTruth {
    /// The video options as given.
    pub config: super::video_config::VideoConfig,
    /// Readout time used (s): the option, or the device preset's.
    pub readout_s: f64,
    /// Exposure time (s).
    pub exposure_s: f64,
    /// Video frame rate (frames/s).
    pub frame_rate: f64,
    /// Focus breathing β used (m; 0 when off): c = c₀·(1 + β·(1/d − 1/`focus_reference_m`)).
    pub focus_breathing_m: f64,
    /// Focus distance at which c is the camera's (m).
    pub focus_reference_m: f64,
    /// The camera's trajectory: `cam_from_world(t)` and its velocities.
    pub trajectory: super::trajectory::Trajectory,
    /// The full-rate video, when rendered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub full_rate: Option<FullRateTruth>,
}

impl VideoTruth {
    /// The timing of the frame taken at `time_s`.
    #[must_use]
    pub fn shutter(&self, time_s: f64) -> super::shutter::Shutter {
        super::shutter::Shutter {
            time_s,
            readout_s: self.readout_s,
            exposure_s: self.exposure_s,
        }
    }
}

/// The full-rate video (`OUT/video/`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FullRateTruth {
    /// Frame width (px).
    pub width: u32,
    /// Frame height (px).
    pub height: u32,
    /// Frames written (`video/frame_00001.png` …, frame j at time (j − 1)/frame_rate).
    pub frames: usize,
    /// The frames went straight into `video.mp4` and no PNG was written.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub streamed: bool,
    /// `video.mp4` when ffmpeg encoded it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mp4: Option<String>,
    /// Why there is no `video.mp4` (ffmpeg missing or failed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
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
    crate::geometry::plane_basis(normal)
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
        time_s: None,
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
        motion: None,
        neighbours: Vec::new(),
    }
}

/// The view of `target` from a moving rolling-shutter camera (`camera` is the frame's, with
/// its principal distance), or `None` if it is not visible; see the module documentation.
#[must_use]
pub fn target_view_moving(
    scene: &Scene,
    camera: &BrownCamera,
    shutter: &Shutter,
    pose_at: &(dyn Fn(f64) -> Rigid3 + Sync),
    target: &Target,
    margin_px: f64,
) -> Option<TargetView> {
    let centre = Vector3::from(target.centre);
    let normal = Vector3::from(target.normal);
    let frame_pose = pose_at(shutter.time_s);
    let p_frame = frame_pose.rotation * centre + frame_pose.translation.vector;
    if p_frame.z <= 0.0 {
        return None;
    }
    let seen = project_rolling_shutter(camera, shutter, pose_at, &centre, None)?;
    let pose = pose_at(seen.time_s);
    let eye = camera_centre(&pose);
    let p_cam = pose.rotation * centre + pose.translation.vector;
    if p_cam.z <= 0.0 || normal.dot(&(eye.coords - centre)) <= 0.0 {
        return None;
    }
    let (u, v) = plane_axes(&normal);
    let edge_world = |phi: f64| centre + (u * phi.cos() + v * phi.sin()) * target.radius;
    let mut edge_px = Vec::with_capacity(EDGE_POINTS);
    for k in 0..EDGE_POINTS {
        let phi = std::f64::consts::TAU * k as f64 / EDGE_POINTS as f64;
        let uv =
            project_rolling_shutter(camera, shutter, pose_at, &edge_world(phi), Some(seen.uv.y))?
                .uv;
        if !camera.contains(&uv, margin_px) {
            return None;
        }
        edge_px.push(uv);
    }
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
    let k = pinhole_matrix(&camera.intrinsics);
    let conic = conic_of_circle(&k, &pose, &centre, &normal, target.radius)?;
    let pinhole = Ellipse::from_conic(&conic)?;
    let pc = k * (p_cam / p_cam.z);
    let fitted = fit_ellipse_direct(&edge_px)?;
    Some(TargetView {
        id: target.id,
        centre_px: [seen.uv.x, seen.uv.y],
        pinhole_centre_px: [pc.x, pc.y],
        pinhole,
        fitted,
        time_s: Some(seen.time_s),
    })
}

/// A video frame's truth record: the pose at the frame time, the motion, and the targets as
/// the rolling-shutter camera `camera` (the frame's own) sees them along `trajectory`.
#[must_use]
pub fn frame_truth_moving(
    scene: &Scene,
    camera: &BrownCamera,
    trajectory: &Trajectory,
    shutter: &Shutter,
    label: (u32, &str, Orientation),
    margin_px: f64,
) -> TruthFrame {
    let (image_id, name, orientation) = label;
    let motion = trajectory.motion(shutter.time_s);
    let (qvec, tvec) = colmap_from_rigid(&motion.cam_from_world);
    let pose_at = |t: f64| trajectory.cam_from_world(t);
    let targets = scene
        .targets
        .par_iter()
        .filter_map(|t| target_view_moving(scene, camera, shutter, &pose_at, t, margin_px))
        .collect();
    TruthFrame {
        image_id,
        name: name.into(),
        qvec,
        tvec,
        orientation,
        targets,
        motion: Some(FrameMotion {
            time_s: shutter.time_s,
            readout_s: shutter.readout_s,
            exposure_s: shutter.exposure_s,
            angular_velocity: motion.angular_velocity.into(),
            linear_velocity: motion.linear_velocity.into(),
            principal_distance: camera.intrinsics.c,
            dt_s: None,
        }),
        neighbours: Vec::new(),
    }
}

/// The pixel of a world point in a frame, if in front of the camera (helper for consumers).
#[must_use]
pub fn project(camera: &BrownCamera, frame: &TruthFrame, p: &Point3<f64>) -> Option<Vector2<f64>> {
    camera.project_world(&frame.cam_from_world(), &p.coords)
}

/// The provenance note of a profile calibrated from simulated frames: frames from
/// `pipemeasure simulate lab` carry their truth (`truth.json`) in the folder above them; `None`
/// when there is none (a real phone's frames).
#[must_use]
pub fn simulated_provenance(frames: &std::path::Path) -> Option<serde_json::Value> {
    let truth = frames
        .parent()
        .map(|d| d.join("truth.json"))
        .filter(|p| p.is_file())
        .and_then(|p| Truth::read(&p).ok())?;
    Some(serde_json::json!({
        "scene": truth.scene,
        "device_preset": truth.camera.device,
        "seed": truth.seed,
        "simulate_command": truth.command,
        "note": "calibrated from simulated frames, not a real phone: calibrate your own phone and replace this profile",
    }))
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
