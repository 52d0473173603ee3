//! The SfM stand-in: a COLMAP sparse model as structure from motion would deliver it, made
//! from the truth so that later stages can run without COLMAP.
//!
//! * the whole world under an arbitrary similarity (scale, rotation, translation; recorded in
//!   the truth);
//! * every pose perturbed at the level COLMAP reaches on such sequences: rotation errors of σ =
//!   0.1° per axis and camera-centre errors of σ = 3 mm per axis (true units) by default;
//! * one SIMPLE_RADIAL camera initialised from an EXIF-like focal guess (the true principal
//!   distance off by up to ±3 %, principal point at the image centre, no distortion);
//! * feature tracks of points on textured surfaces, observed through the true camera with
//!   σ = 0.5 px noise, and 3 % of the observations replaced by gross mismatches (random pixels);
//!   in a video ([`stand_in_observed`] with the video's observer) each feature is where the
//!   moving rolling-shutter camera sees it, in its own row, as a feature detector finds it in
//!   such a frame — the model's poses then absorb the rolling shutter as COLMAP's do.

use nalgebra::{Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::bundle::{BundleObservation, SimpleRadial, adjust, reprojection_error, umeyama};
use super::scene::Scene;
use super::truth::{SfmTruth, Similarity, StandInAdjustment, StandInTruth};
use crate::camera::BrownCamera;
use crate::geometry::Rigid3;
use crate::geometry::pose::{camera_centre, colmap_from_rigid};
use crate::io::colmap::{
    CameraId, ColmapCamera, ColmapModel, Image, ImageId, Point2D, Point3D, Point3dId,
    Reconstruction, TrackElement,
};
use crate::robust::standard_normal as gaussian;

/// Options of the SfM stand-in.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SfmConfig {
    /// σ of the pose rotation error per axis (degrees), default 0.1.
    pub rotation_noise_deg: f64,
    /// σ of the camera-centre error per axis (m, true units), default 0.003.
    pub translation_noise_m: f64,
    /// Largest relative error of the EXIF-like focal guess, default 0.03.
    pub focal_guess_error: f64,
    /// σ of feature positions (px), default 0.5.
    pub feature_noise_px: f64,
    /// Fraction of observations that are gross mismatches, default 0.03.
    pub mismatch_fraction: f64,
    /// Number of 3D points, default 4000.
    pub points: usize,
    /// Apply a random similarity to the world (default true); false keeps the true frame.
    pub random_similarity: bool,
    /// Adjust the perturbed poses, points and the SIMPLE_RADIAL camera's `f` and `k` to the
    /// features, as COLMAP's bundle adjustment does ([`super::bundle`]), default true: the
    /// poses then absorb the errors of that camera, like a real SfM model's. False: the
    /// truth's poses perturbed, the camera left at its EXIF guess.
    pub adjust: bool,
}

impl Default for SfmConfig {
    fn default() -> Self {
        SfmConfig {
            rotation_noise_deg: 0.1,
            translation_noise_m: 0.003,
            focal_guess_error: 0.03,
            feature_noise_px: 0.5,
            mismatch_fraction: 0.03,
            points: 4000,
            random_similarity: true,
            adjust: true,
        }
    }
}

/// A random similarity: scale in [e^−1.5, e^1.5], uniform rotation, translation within ±5.
fn random_similarity(rng: &mut ChaCha8Rng) -> Similarity {
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        gaussian(rng),
        gaussian(rng),
        gaussian(rng),
        gaussian(rng),
    ));
    let (qvec, _) = colmap_from_rigid(&Rigid3::from_parts(Translation3::identity(), q));
    Similarity {
        scale: rng.random_range(-1.5f64..1.5).exp(),
        qvec,
        tvec: [
            rng.random_range(-5.0..5.0),
            rng.random_range(-5.0..5.0),
            rng.random_range(-5.0..5.0),
        ],
    }
}

/// A pose perturbed by a rotation of σ `rot_rad` per axis (about the camera centre) and a
/// camera-centre shift of σ `trans_m` per axis.
fn perturb(pose: &Rigid3, rot_rad: f64, trans_m: f64, rng: &mut ChaCha8Rng) -> Rigid3 {
    let omega = Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)) * rot_rad;
    let rotation = UnitQuaternion::from_scaled_axis(omega) * pose.rotation;
    let centre =
        camera_centre(pose) + Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)) * trans_m;
    Rigid3::from_parts(Translation3::from(-(rotation * centre.coords)), rotation)
}

/// Whether a surface point is seen in a frame: in front, inside the image, facing the camera,
/// not hidden. Returns its exact pixel.
pub(crate) fn observe(
    scene: &Scene,
    camera: &BrownCamera,
    cam_from_world: &Rigid3,
    p: &Point3<f64>,
    normal: &Vector3<f64>,
) -> Option<Vector2<f64>> {
    let eye = camera_centre(cam_from_world);
    if normal.dot(&(eye - p)) <= 0.0 {
        return None;
    }
    let uv = camera.project_world(cam_from_world, &p.coords)?;
    if !camera.contains(&uv, 1.0) || !scene.visible(&eye, p, 1e-4) {
        return None;
    }
    Some(uv)
}

/// How frame `k` sees surface point `p` (normal `n`): its exact pixel, `None` when not seen.
pub type Observer<'a> =
    dyn Fn(usize, &Point3<f64>, &Vector3<f64>) -> Option<Vector2<f64>> + Sync + 'a;

/// Builds the stand-in sparse model for still frames `names` at true poses `poses`.
#[must_use]
pub fn stand_in(
    scene: &Scene,
    camera: &BrownCamera,
    poses: &[Rigid3],
    names: &[String],
    config: &SfmConfig,
    seed: u64,
) -> (Reconstruction, SfmTruth) {
    let still =
        |k: usize, p: &Point3<f64>, n: &Vector3<f64>| observe(scene, camera, &poses[k], p, n);
    stand_in_observed(scene, camera, poses, names, config, seed, &still)
}

/// [`stand_in`] with the frames' features where `observer` sees them (a video's
/// rolling-shutter pixels); `poses` are the frame-time poses (points are found by casting
/// rays from them, and the perturbed model poses start from them).
#[must_use]
pub fn stand_in_observed(
    scene: &Scene,
    camera: &BrownCamera,
    poses: &[Rigid3],
    names: &[String],
    config: &SfmConfig,
    seed: u64,
    observer: &Observer<'_>,
) -> (Reconstruction, SfmTruth) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5F3);
    let similarity = if config.random_similarity {
        random_similarity(&mut rng)
    } else {
        Similarity::identity()
    };
    let i = camera.intrinsics;
    let focal_guess =
        i.c * (1.0 + rng.random_range(-config.focal_guess_error..=config.focal_guess_error));
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let mut model = Reconstruction::default();
    model.cameras.insert(
        CameraId(1),
        ColmapCamera {
            model: ColmapModel::SimpleRadial,
            width: u64::from(camera.width),
            height: u64::from(camera.height),
            params: vec![focal_guess, w / 2.0, h / 2.0, 0.0],
        },
    );
    for (k, (pose, name)) in poses.iter().zip(names).enumerate() {
        let noisy = perturb(
            pose,
            config.rotation_noise_deg.to_radians(),
            config.translation_noise_m,
            &mut rng,
        );
        let mut image = Image {
            qvec: [1.0, 0.0, 0.0, 0.0],
            tvec: [0.0; 3],
            camera_id: CameraId(1),
            name: name.clone(),
            points2d: Vec::new(),
        };
        image.set_cam_from_world(&similarity.pose_in_sfm(&noisy));
        model.images.insert(ImageId(k as u32 + 1), image);
    }
    // Points on textured surfaces: cast rays through random pixels of random frames, keep
    // hits outside target plates.
    let mut mismatches = 0;
    let mut attempts = 0;
    let mut true_points = Vec::new();
    while model.points3d.len() < config.points && attempts < config.points * 20 {
        attempts += 1;
        let f = rng.random_range(0..poses.len());
        let uv = Vector2::new(rng.random_range(0.0..w), rng.random_range(0.0..h));
        let Ok(xy) = i.ideal_from_pixel(&uv) else {
            continue;
        };
        let eye = camera_centre(&poses[f]);
        let dir = poses[f].rotation.inverse() * Vector3::new(xy.x, xy.y, 1.0);
        let Some(hit) = scene.intersect(&eye, &dir) else {
            continue;
        };
        if hit.region & 0xf != 0 {
            continue; // on a target plate: no texture to match
        }
        let p = eye + dir * hit.t;
        let mut track = Vec::new();
        let mut observations = Vec::new();
        for k in 0..poses.len() {
            if let Some(uv) = observer(k, &p, &hit.normal) {
                observations.push((k, uv));
            }
        }
        if observations.len() < 2 {
            continue;
        }
        let id = Point3dId(model.points3d.len() as u64 + 1);
        for (k, uv) in observations {
            let observed = if rng.random_bool(config.mismatch_fraction.clamp(0.0, 1.0)) {
                mismatches += 1;
                Vector2::new(rng.random_range(0.0..w), rng.random_range(0.0..h))
            } else {
                uv + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * config.feature_noise_px
            };
            let image = model
                .images
                .get_mut(&ImageId(k as u32 + 1))
                .unwrap_or_else(|| unreachable!("every frame has an image"));
            track.push(TrackElement {
                image_id: ImageId(k as u32 + 1),
                point2d_idx: image.points2d.len() as u32,
            });
            image.points2d.push(Point2D {
                uv: observed,
                point3d_id: Some(id),
            });
        }
        true_points.push(p);
        let noisy = p + Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng))
            * config.translation_noise_m;
        let x = similarity.apply(&noisy);
        let grey = (hit.albedo * 255.0).round().clamp(0.0, 255.0) as u8;
        model.points3d.insert(
            id,
            Point3D {
                xyz: [x.x, x.y, x.z],
                rgb: [grey; 3],
                error: config.feature_noise_px,
                track,
            },
        );
    }
    let (similarity, adjustment) = if config.adjust {
        let adjustment = adjust_model(&mut model, &true_points);
        (adjustment.similarity.clone(), Some(adjustment))
    } else {
        (similarity, None)
    };
    let truth = SfmTruth {
        source: "stand-in".into(),
        points: model.points3d.len(),
        stand_in: Some(StandInTruth {
            similarity,
            rotation_noise_deg: config.rotation_noise_deg,
            translation_noise_m: config.translation_noise_m,
            focal_guess_px: focal_guess,
            feature_noise_px: config.feature_noise_px,
            mismatch_fraction: config.mismatch_fraction,
            mismatches,
            adjustment,
        }),
    };
    (model, truth)
}

/// COLMAP's global bundle adjustment on the stand-in model, in place (poses, points, `f`, `k`
/// of its one SIMPLE_RADIAL camera; [`super::bundle`]): adjust, remove the observations off by
/// more than 4 px and the points left with fewer than two, adjust again. `true_points[j]` is
/// the world point of the `j`-th model point (id `j + 1`); the returned similarity maps the
/// world onto the adjusted points best (the SfM frame is the adjustment's).
///
/// Kept whole (one function over 150 lines): COLMAP's adjust, filter, adjust on one model, the
/// filters reading the first adjustment's residuals in place.
fn adjust_model(model: &mut Reconstruction, true_points: &[Point3<f64>]) -> StandInAdjustment {
    const MAX_ERROR_PX: f64 = 4.0;
    let ids: Vec<ImageId> = model.images.keys().copied().collect();
    let frame_of = |id: ImageId| ids.iter().position(|&i| i == id);
    let params = &model.cameras[&CameraId(1)].params;
    let mut camera = SimpleRadial {
        f: params[0],
        cx: params[1],
        cy: params[2],
        k: params[3],
    };
    let initial_f = camera.f;
    let mut poses: Vec<Rigid3> = ids
        .iter()
        .map(|id| model.images[id].cam_from_world())
        .collect();
    let point_ids: Vec<Point3dId> = model.points3d.keys().copied().collect();
    let mut points: Vec<Point3<f64>> = point_ids
        .iter()
        .map(|id| Point3::from(model.points3d[id].xyz))
        .collect();
    let mut keep: Vec<Vec<bool>> = point_ids
        .iter()
        .map(|id| vec![true; model.points3d[id].track.len()])
        .collect();
    // Per point, its track's observations (`None` for an image the model does not have).
    let per_point: Vec<Vec<Option<BundleObservation>>> = point_ids
        .iter()
        .enumerate()
        .map(|(j, id)| {
            model.points3d[id]
                .track
                .iter()
                .map(|e| {
                    Some(BundleObservation {
                        frame: frame_of(e.image_id)?,
                        point: j,
                        uv: model
                            .images
                            .get(&e.image_id)?
                            .points2d
                            .get(e.point2d_idx as usize)?
                            .uv,
                    })
                })
                .collect()
        })
        .collect();
    let observations = |keep: &[Vec<bool>]| -> Vec<BundleObservation> {
        per_point
            .iter()
            .zip(keep)
            .flat_map(|(list, k)| {
                list.iter()
                    .zip(k)
                    .filter(|(_, k)| **k)
                    .filter_map(|(o, _)| *o)
            })
            .collect()
    };
    let initial_rms = {
        let obs = observations(&keep);
        let sq: f64 = obs
            .iter()
            .map(|o| {
                reprojection_error(&camera, &poses[o.frame], &points[o.point], &o.uv)
                    .powi(2)
                    .min(1e4)
            })
            .sum();
        (sq / obs.len().max(1) as f64).sqrt()
    };
    adjust(
        &mut camera,
        &mut poses,
        &mut points,
        &observations(&keep),
        40,
    );
    let mut removed_observations = 0;
    for (list, k) in per_point.iter().zip(keep.iter_mut()) {
        for (o, k) in list.iter().zip(k.iter_mut()) {
            let off = o.is_none_or(|o| {
                reprojection_error(&camera, &poses[o.frame], &points[o.point], &o.uv) > MAX_ERROR_PX
            });
            if off && *k {
                *k = false;
                removed_observations += 1;
            }
        }
        if k.iter().filter(|k| **k).count() < 2 {
            k.iter_mut().for_each(|k| *k = false);
        }
    }
    let final_rms = adjust(
        &mut camera,
        &mut poses,
        &mut points,
        &observations(&keep),
        40,
    );
    // Write the adjusted model back; removed observations unlinked, emptied points deleted.
    if let Some(cam) = model.cameras.get_mut(&CameraId(1)) {
        cam.params = vec![camera.f, camera.cx, camera.cy, camera.k];
    }
    for (id, pose) in ids.iter().zip(&poses) {
        if let Some(image) = model.images.get_mut(id) {
            image.set_cam_from_world(pose);
        }
    }
    let mut removed_points = 0;
    let mut kept_true = Vec::new();
    let mut kept_adjusted = Vec::new();
    for (j, id) in point_ids.iter().enumerate() {
        let Some(mut point) = model.points3d.remove(id) else {
            continue;
        };
        let mut track = Vec::new();
        for (e, k) in point.track.iter().zip(&keep[j]) {
            if *k {
                track.push(*e);
            } else if let Some(p2) = model
                .images
                .get_mut(&e.image_id)
                .and_then(|im| im.points2d.get_mut(e.point2d_idx as usize))
            {
                p2.point3d_id = None;
            }
        }
        if track.is_empty() {
            removed_points += 1;
            continue;
        }
        point.track = track;
        point.xyz = points[j].coords.into();
        kept_true.push(true_points[j]);
        kept_adjusted.push(points[j]);
        model.points3d.insert(*id, point);
    }
    let similarity =
        umeyama(&kept_true, &kept_adjusted).map_or_else(Similarity::identity, |(s, r, t)| {
            let rotation = nalgebra::UnitQuaternion::from_matrix(&r);
            let (qvec, _) =
                colmap_from_rigid(&Rigid3::from_parts(Translation3::identity(), rotation));
            Similarity {
                scale: s,
                qvec,
                tvec: t.into(),
            }
        });
    StandInAdjustment {
        similarity,
        initial_focal_px: initial_f,
        focal_px: camera.f,
        k: camera.k,
        initial_rms_px: initial_rms,
        rms_px: final_rms,
        removed_observations,
        removed_points,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::devices::{P30, preset_camera};
    use crate::sim::lab::{LabConfig, build_scene, path};

    #[test]
    fn stand_in_tracks_reproject_through_the_true_camera_in_the_sfm_frame() {
        let cfg = LabConfig {
            frames: 6,
            ..Default::default()
        };
        let scene = build_scene(&cfg, 0.01, 3);
        let camera = preset_camera(&P30, 640, 360);
        let poses: Vec<_> = path(&cfg, 3).iter().map(|s| s.cam_from_world).collect();
        let names: Vec<_> = (1..=6).map(|k| format!("frame_{k:04}.png")).collect();
        let sfm = SfmConfig {
            points: 300,
            rotation_noise_deg: 0.0,
            translation_noise_m: 0.0,
            feature_noise_px: 0.0,
            adjust: false,
            ..Default::default()
        };
        let (model, truth) = stand_in(&scene, &camera, &poses, &names, &sfm, 3);
        assert_eq!(model.images.len(), 6);
        assert_eq!(model.points3d.len(), 300);
        // Without noise, every non-mismatched observation is the true camera's projection of
        // the SfM point in the SfM frame (the camera frame scales with the world).
        let mut good = 0;
        let mut bad = 0;
        for p in model.points3d.values() {
            for el in &p.track {
                let image = &model.images[&el.image_id];
                let p_cam = image.cam_from_world() * Point3::from(p.xyz);
                let uv = camera.intrinsics.project(&p_cam.coords).unwrap();
                let e = (uv - image.points2d[el.point2d_idx as usize].uv).norm();
                if e < 1e-6 { good += 1 } else { bad += 1 }
            }
        }
        let stand_in = truth.stand_in.unwrap();
        assert_eq!(bad, stand_in.mismatches);
        assert!(good > 600 && bad > 0, "{good} good, {bad} mismatched");
        assert_ne!(stand_in.similarity.scale, 1.0);
    }

    /// The adjusted stand-in is co-adapted like COLMAP's model: its own camera reprojects its
    /// features at the noise level, while the true camera at its poses does not (its poses
    /// absorbed the EXIF camera's missing distortion); and its points stay the world's up to
    /// the recorded similarity within the pose noise.
    #[test]
    fn adjusted_stand_in_poses_fit_its_own_camera_not_the_true_one() {
        let cfg = LabConfig {
            frames: 10,
            ..Default::default()
        };
        let scene = build_scene(&cfg, 0.01, 4);
        let camera = preset_camera(&P30, 960, 540);
        let poses: Vec<_> = path(&cfg, 4).iter().map(|s| s.cam_from_world).collect();
        let names: Vec<_> = (1..=10).map(|k| format!("frame_{k:04}.png")).collect();
        let sfm = SfmConfig {
            points: 1500,
            mismatch_fraction: 0.0,
            ..Default::default()
        };
        let (model, truth) = stand_in(&scene, &camera, &poses, &names, &sfm, 4);
        let adjustment = truth.stand_in.unwrap().adjustment.unwrap();
        let own = crate::camera::convert::brown_from_colmap(&model.cameras[&CameraId(1)])
            .unwrap()
            .camera
            .intrinsics;
        let rms = |i: &crate::camera::Intrinsics| {
            let (mut sq, mut n) = (0.0, 0);
            for p in model.points3d.values() {
                for el in &p.track {
                    let image = &model.images[&el.image_id];
                    let p_cam = image.cam_from_world() * Point3::from(p.xyz);
                    if let Some(uv) = i.project(&p_cam.coords) {
                        sq += (uv - image.points2d[el.point2d_idx as usize].uv).norm_squared();
                        n += 1;
                    }
                }
            }
            (sq / f64::from(n)).sqrt()
        };
        let (own_rms, true_rms) = (rms(&own), rms(&camera.intrinsics));
        // 0.5 px per coordinate: 0.71 px per observation, less the points' own fit.
        assert!(
            own_rms < 0.75 && (own_rms - adjustment.rms_px).abs() < 1e-9,
            "{own_rms}"
        );
        assert!(
            true_rms > 2.0 * own_rms,
            "true camera {true_rms} px, own {own_rms} px"
        );
        assert!((adjustment.focal_px - adjustment.initial_focal_px).abs() > 1.0);
    }
}
