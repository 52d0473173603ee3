//! Paper Algorithm 1 steps 1–3 on an SfM model: the robust fundamental matrix of every
//! overlapping image pair from its shared features (step 2, docs/math.md §4.1–4.2), and the
//! robust triangulation of every feature track (step 3, math §4.3). The output — per pair `F_ij`,
//! `σ_ij` and the inlier features, per track the inlier observations — feeds Algorithm 2
//! (`F_ij`, `σ_ij` of eq. 2) and the bundle adjustment of step 4.
//!
//! Everything is in undistorted pixels of the model's camera (see [`super::views`]), so that
//! the two-view geometry is exact projective geometry.

use std::collections::HashMap;

use nalgebra::{Matrix3, Point3, Vector2};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::views::FrameCamera;
use crate::camera::Intrinsics;
use crate::geometry::triangulation::Observation;
use crate::io::colmap::{ImageId, Point3dId, Reconstruction};
use crate::robust::fundamental::{FundamentalConfig, estimate_fundamental};
use crate::robust::triangulation::{reprojection_squared, triangulate_robust};
use crate::robust::{CHI2_MEDIAN_2DOF, LmedsConfig, lower_median};

/// Options of Algorithm 1 steps 1–3.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RefineConfig {
    /// Fewest shared 3D points for two images to count as overlapping, default 16.
    pub min_shared: usize,
    /// The fundamental-matrix estimator.
    pub fundamental: FundamentalConfig,
    /// Robust triangulation of tracks.
    pub triangulation: LmedsConfig,
    /// A-priori σ of a feature position (px) for tracks of fewer than five views, default 1.
    pub feature_sigma_px: f64,
    /// Seed of the samplers (each pair and track derives its own).
    pub seed: u64,
}

impl Default for RefineConfig {
    fn default() -> Self {
        RefineConfig {
            min_shared: 16,
            fundamental: FundamentalConfig::default(),
            triangulation: LmedsConfig::default(),
            feature_sigma_px: 1.0,
            seed: 1,
        }
    }
}

/// A registered frame of the model.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelFrame {
    /// COLMAP image id.
    pub image_id: ImageId,
    /// File name.
    pub name: String,
    /// Camera.
    pub camera: FrameCamera,
}

/// The robust two-view geometry of an overlapping pair `(a, b)`, `a < b` (frame indices).
#[derive(Clone, Debug, PartialEq)]
pub struct PairGeometry {
    /// First frame.
    pub a: usize,
    /// Second frame.
    pub b: usize,
    /// `F` with `x_bᵀ F x_a = 0` in undistorted pixels, unit Frobenius norm.
    pub f: Matrix3<f64>,
    /// σ_ij of paper eq. 2 (px): the standard deviation of the symmetric epipolar distance of
    /// the inliers.
    pub sigma: f64,
    /// Number of shared features.
    pub shared: usize,
    /// Inlier features: indices into the two images' `points2d`.
    pub inlier_features: Vec<[u32; 2]>,
}

/// Metric cameras of a pair in a frame of its own, consistent with the pair's robust `F`
/// rather than with the (noisier) SfM poses: `P_a = K_a [I | 0]`, `P_b = K_b [R | t]` with
/// `(R, t)` from the essential matrix `E = K_bᵀ F K_a`, the one of its four decompositions
/// nearest the poses' relative pose, and `|t|` the poses' baseline. Quan's construction and
/// Algorithm 3 depend on the two cameras only through their relative pose, so a pose error
/// that `F` does not share cannot spoil them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalPair {
    /// Camera of frame a.
    pub p_a: nalgebra::Matrix3x4<f64>,
    /// Centre of camera a (the origin).
    pub eye_a: Point3<f64>,
    /// Camera of frame b.
    pub p_b: nalgebra::Matrix3x4<f64>,
    /// Centre of camera b.
    pub eye_b: Point3<f64>,
}

impl PairGeometry {
    /// Projective cameras exactly consistent with `F` (Hartley & Zisserman result 9.14):
    /// `P_a = [I | 0]`, `P_b = [[e']× F | e']`, built in coordinates scaled by `1/scale` (e.g.
    /// the image width) for conditioning and returned for pixel coordinates. Quan's condition
    /// is invariant to the projective frame (math §2.2), so these cameras give δ with the
    /// precision of `F` itself, untouched by pose errors that `F` does not share.
    #[must_use]
    pub fn projective_cameras(
        &self,
        scale: f64,
    ) -> Option<(nalgebra::Matrix3x4<f64>, nalgebra::Matrix3x4<f64>)> {
        let s = if scale > 0.0 { scale } else { 1.0 };
        let n_inv = Matrix3::new(s, 0.0, 0.0, 0.0, s, 0.0, 0.0, 0.0, 1.0);
        let f = n_inv.transpose() * self.f * n_inv;
        let f = f / f.norm();
        // e' spans the left null space of F: Fᵀ e' = 0.
        let svd = f.transpose().svd(false, true);
        let v_t = svd.v_t?;
        let k = svd.singular_values.imin();
        let e: nalgebra::Vector3<f64> = v_t.row(k).transpose();
        let mut pa = nalgebra::Matrix3x4::zeros();
        pa.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        let mut pb = nalgebra::Matrix3x4::zeros();
        pb.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(crate::geometry::pose::skew(&e) * f));
        pb.set_column(3, &e);
        Some((n_inv * pa, n_inv * pb))
    }

    /// The pair's [`LocalPair`]; `None` for a degenerate `F` or zero baseline.
    #[must_use]
    pub fn local_cameras(&self, cam_a: &FrameCamera, cam_b: &FrameCamera) -> Option<LocalPair> {
        let (ka, kb) = (cam_a.k(), cam_b.k());
        let e = kb.transpose() * self.f * ka;
        let rel = cam_b.cam_from_world * cam_a.cam_from_world.inverse();
        let r_pose = *rel.rotation.to_rotation_matrix().matrix();
        let baseline = rel.translation.vector.norm();
        if baseline <= 0.0 {
            return None;
        }
        let t_pose = rel.translation.vector / baseline;
        let four = crate::geometry::epipolar::decompose_essential(&e)?;
        let (r, t) = four.into_iter().min_by(|(r1, t1), (r2, t2)| {
            let score = |r: &Matrix3<f64>, t: &nalgebra::Vector3<f64>| {
                (r - r_pose).norm() + (t - t_pose).norm()
            };
            score(r1, t1).total_cmp(&score(r2, t2))
        })?;
        let t = t * baseline;
        let mut rt = nalgebra::Matrix3x4::zeros();
        rt.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        rt.set_column(3, &t);
        let mut it = nalgebra::Matrix3x4::zeros();
        it.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        Some(LocalPair {
            p_a: ka * it,
            eye_a: Point3::origin(),
            p_b: kb * rt,
            eye_b: Point3::from(-(r.transpose() * t)),
        })
    }
}

/// A feature track after robust triangulation.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackInliers {
    /// The COLMAP point.
    pub point3d_id: Point3dId,
    /// The point refined on the inlier views.
    pub point: Point3<f64>,
    /// Per track element, whether it is an inlier.
    pub inliers: Vec<bool>,
}

/// The outcome of Algorithm 1 steps 1–3.
#[derive(Clone, Debug, Default)]
pub struct Algorithm1 {
    /// Registered frames in image-id order.
    pub frames: Vec<ModelFrame>,
    /// Overlapping pairs with a robust `F` (pairs where LMedS failed are left out).
    pub pairs: Vec<PairGeometry>,
    /// Tracks with at least two inlier views.
    pub tracks: Vec<TrackInliers>,
    /// Tracks that could not be triangulated robustly.
    pub rejected_tracks: usize,
    /// Robust σ (px, per coordinate) of the inlier features' reprojection errors with the
    /// model's poses, `sqrt(median r² / 1.3863)` (r² is σ²·χ²(2)): how well the poses and
    /// intrinsics explain the images, the a-priori σ for small target tracks.
    pub reprojection_sigma: f64,
}

impl Algorithm1 {
    /// The pair `(a, b)` in either order, with `F` oriented from the first to the second.
    #[must_use]
    pub fn pair(&self, a: usize, b: usize) -> Option<(Matrix3<f64>, f64)> {
        let (lo, hi) = (a.min(b), a.max(b));
        let k = self
            .pairs
            .binary_search_by(|p| (p.a, p.b).cmp(&(lo, hi)))
            .ok()?;
        let p = &self.pairs[k];
        Some(if a == lo {
            (p.f, p.sigma)
        } else {
            (p.f.transpose(), p.sigma)
        })
    }

    /// Fraction of all track observations that are inliers.
    #[must_use]
    pub fn track_inlier_fraction(&self) -> f64 {
        let (inl, all) = self.tracks.iter().fold((0usize, 0usize), |(i, a), t| {
            (
                i + t.inliers.iter().filter(|b| **b).count(),
                a + t.inliers.len(),
            )
        });
        if all == 0 {
            0.0
        } else {
            inl as f64 / all as f64
        }
    }
}

/// Why Algorithm 1 could not run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RefineError {
    /// An image refers to a camera the model does not have, or the camera has no Brown form.
    #[error("image {image} ({name}): camera {camera}: {reason}")]
    Camera {
        /// Image id.
        image: u32,
        /// Image name.
        name: String,
        /// Camera id.
        camera: u32,
        /// What is wrong.
        reason: String,
    },
    /// A feature cannot be undistorted with the model's camera.
    #[error("image {image} ({name}): feature {index} at ({u:.1}, {v:.1}) cannot be undistorted")]
    Feature {
        /// Image id.
        image: u32,
        /// Image name.
        name: String,
        /// Index into `points2d`.
        index: usize,
        /// Position.
        u: f64,
        /// Position.
        v: f64,
    },
}

/// The frames of a model with their cameras: the model's own camera converted to Brown
/// (exactly for every COLMAP model but the fisheye ones), or `intrinsics` for every frame when
/// given (e.g. a device profile or the bundle adjustment's estimate).
///
/// # Errors
///
/// [`RefineError::Camera`] when an image's camera is missing or cannot be converted.
pub fn model_frames(
    model: &Reconstruction,
    intrinsics: Option<&Intrinsics>,
) -> Result<Vec<ModelFrame>, RefineError> {
    model
        .images
        .iter()
        .map(|(&image_id, image)| {
            let intrinsics = match intrinsics {
                Some(i) => *i,
                None => {
                    let err = |reason: String| RefineError::Camera {
                        image: image_id.0,
                        name: image.name.clone(),
                        camera: image.camera_id.0,
                        reason,
                    };
                    let cam = model
                        .cameras
                        .get(&image.camera_id)
                        .ok_or_else(|| err("not in the model".into()))?;
                    crate::camera::convert::brown_from_colmap(cam)
                        .map_err(|e| err(e.to_string()))?
                        .camera
                        .intrinsics
                }
            };
            Ok(ModelFrame {
                image_id,
                name: image.name.clone(),
                camera: FrameCamera {
                    intrinsics,
                    cam_from_world: image.cam_from_world(),
                },
            })
        })
        .collect()
}

/// Each frame's position by its COLMAP image id.
#[must_use]
pub fn frame_index(frames: &[ModelFrame]) -> HashMap<ImageId, usize> {
    frames
        .iter()
        .enumerate()
        .map(|(k, f)| (f.image_id, k))
        .collect()
}

/// Per frame, the undistorted pixel of every feature (`None` for features the camera cannot
/// undistort, which only happens far outside the image).
fn undistorted_features(
    model: &Reconstruction,
    frames: &[ModelFrame],
) -> Vec<Vec<Option<Vector2<f64>>>> {
    frames
        .par_iter()
        .map(|f| {
            model.images[&f.image_id]
                .points2d
                .iter()
                .map(|p| f.camera.undistort(&p.uv))
                .collect()
        })
        .collect()
}

/// A per-item seed mixed from the configured one (SplitMix64 finaliser).
fn mix(seed: u64, a: u64, b: u64) -> u64 {
    let mut z =
        seed ^ a.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ b.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Runs Algorithm 1 steps 1–3 (pairs and tracks in parallel; deterministic for any thread count).
///
/// # Errors
///
/// [`RefineError`] for a camera that cannot be used.
pub fn algorithm1(
    model: &Reconstruction,
    intrinsics: Option<&Intrinsics>,
    config: &RefineConfig,
) -> Result<Algorithm1, RefineError> {
    let frames = model_frames(model, intrinsics)?;
    let index_of = frame_index(&frames);
    let features = undistorted_features(model, &frames);

    // Step 1: overlapping pairs and their shared features.
    let mut shared: HashMap<(usize, usize), Vec<[u32; 2]>> = HashMap::new();
    for point in model.points3d.values() {
        let elems: Vec<(usize, u32)> = point
            .track
            .iter()
            .filter_map(|e| Some((*index_of.get(&e.image_id)?, e.point2d_idx)))
            .collect();
        for (x, &(fa, ia)) in elems.iter().enumerate() {
            for &(fb, ib) in &elems[x + 1..] {
                if fa == fb {
                    continue;
                }
                let key = if fa < fb {
                    ((fa, fb), [ia, ib])
                } else {
                    ((fb, fa), [ib, ia])
                };
                shared.entry(key.0).or_default().push(key.1);
            }
        }
    }
    let mut keys: Vec<(usize, usize)> = shared
        .iter()
        .filter(|(_, v)| v.len() >= config.min_shared)
        .map(|(k, _)| *k)
        .collect();
    keys.sort_unstable();

    // Step 2: robust F per pair.
    let pairs: Vec<PairGeometry> = keys
        .par_iter()
        .filter_map(|&(a, b)| {
            let list = &shared[&(a, b)];
            let mut idx = Vec::with_capacity(list.len());
            let (mut p1, mut p2) = (
                Vec::with_capacity(list.len()),
                Vec::with_capacity(list.len()),
            );
            for pair in list {
                if let (Some(Some(x1)), Some(Some(x2))) = (
                    features[a].get(pair[0] as usize),
                    features[b].get(pair[1] as usize),
                ) {
                    idx.push(*pair);
                    p1.push(*x1);
                    p2.push(*x2);
                }
            }
            let est = estimate_fundamental(
                &p1,
                &p2,
                &config.fundamental,
                mix(config.seed, a as u64, b as u64),
            )?;
            let inlier_features = idx
                .iter()
                .zip(&est.inliers)
                .filter(|(_, i)| **i)
                .map(|(p, _)| *p)
                .collect();
            Some(PairGeometry {
                a,
                b,
                f: est.f,
                sigma: est.sigma,
                shared: list.len(),
                inlier_features,
            })
        })
        .collect();

    // Step 3: robust triangulation per track.
    let (tracks, rejected_tracks, reprojection_sigma) =
        triangulate_tracks(model, &frames, &index_of, &features, config);
    Ok(Algorithm1 {
        frames,
        pairs,
        tracks,
        rejected_tracks,
        reprojection_sigma,
    })
}

/// Algorithm 1 step 3 again with the frames' current cameras (e.g. after the poses were
/// re-adjusted): every track robustly triangulated, its inliers and Algorithm 1's reprojection
/// σ recomputed. The pairs are left as they are.
pub fn retriangulate(model: &Reconstruction, a1: &mut Algorithm1, config: &RefineConfig) {
    let index_of = frame_index(&a1.frames);
    let features = undistorted_features(model, &a1.frames);
    let (tracks, rejected, sigma) =
        triangulate_tracks(model, &a1.frames, &index_of, &features, config);
    a1.tracks = tracks;
    a1.rejected_tracks = rejected;
    a1.reprojection_sigma = sigma;
}

/// Step 3: every track of the model robustly triangulated through the frames' cameras; the
/// tracks with two or more inlier views, the number rejected, and the robust reprojection σ of
/// the inliers, `sqrt(median r² / 1.3863)`.
fn triangulate_tracks(
    model: &Reconstruction,
    frames: &[ModelFrame],
    index_of: &HashMap<ImageId, usize>,
    features: &[Vec<Option<Vector2<f64>>>],
    config: &RefineConfig,
) -> (Vec<TrackInliers>, usize, f64) {
    let points: Vec<(&Point3dId, &crate::io::colmap::Point3D)> = model.points3d.iter().collect();
    let results: Vec<Option<(TrackInliers, Vec<f64>)>> = points
        .par_iter()
        .map(|(id, point)| {
            let mut obs = Vec::with_capacity(point.track.len());
            let mut usable = Vec::with_capacity(point.track.len());
            for e in &point.track {
                let f = index_of.get(&e.image_id).and_then(|&k| {
                    let xy = (*features[k].get(e.point2d_idx as usize)?)?;
                    Some(Observation {
                        p: frames[k].camera.p(),
                        xy,
                    })
                });
                usable.push(f.is_some());
                obs.extend(f);
            }
            let robust = triangulate_robust(&obs, config.feature_sigma_px, &config.triangulation)?;
            let residuals: Vec<f64> = obs
                .iter()
                .zip(&robust.inliers)
                .filter(|(_, i)| **i)
                .map(|(o, _)| reprojection_squared(o, &robust.point))
                .collect();
            let mut it = robust.inliers.iter();
            let inliers: Vec<bool> = usable
                .iter()
                .map(|u| *u && *it.next().unwrap_or(&false))
                .collect();
            let enough = inliers.iter().filter(|b| **b).count() >= 2;
            enough.then_some((
                TrackInliers {
                    point3d_id: **id,
                    point: robust.point,
                    inliers,
                },
                residuals,
            ))
        })
        .collect();
    let rejected_tracks = results.iter().filter(|r| r.is_none()).count();
    let mut squared: Vec<f64> = results
        .iter()
        .flatten()
        .flat_map(|(_, r)| r.iter().copied())
        .collect();
    let reprojection_sigma = if squared.is_empty() {
        config.feature_sigma_px
    } else {
        (lower_median(&mut squared) / CHI2_MEDIAN_2DOF).sqrt()
    };
    let tracks = results.into_iter().flatten().map(|(t, _)| t).collect();
    (tracks, rejected_tracks, reprojection_sigma)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Quan's δ is the same with the projective cameras of F as with the metric cameras, and
    /// the local metric cameras reproduce F.
    #[test]
    fn cameras_from_f_keep_quans_condition_and_the_epipolar_geometry() {
        use crate::geometry::conic::conic_of_circle;
        use crate::geometry::epipolar::fundamental_from_poses;
        use crate::geometry::quan::delta;
        use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
        let intrinsics = Intrinsics::pinhole(1500.0, 970.0, 530.0);
        let ca = FrameCamera {
            intrinsics,
            cam_from_world: Isometry3::from_parts(
                Translation3::new(0.1, 0.0, 3.0),
                UnitQuaternion::from_euler_angles(0.05, 0.1, 0.0),
            ),
        };
        let cb = FrameCamera {
            intrinsics,
            cam_from_world: Isometry3::from_parts(
                Translation3::new(-0.9, 0.1, 3.2),
                UnitQuaternion::from_euler_angles(0.0, 0.45, -0.05),
            ),
        };
        let f = fundamental_from_poses(&ca.k(), &ca.cam_from_world, &cb.k(), &cb.cam_from_world)
            .unwrap();
        let pair = PairGeometry {
            a: 0,
            b: 1,
            f: f / f.norm(),
            sigma: 1.0,
            shared: 0,
            inlier_features: Vec::new(),
        };
        let (pa, pb) = pair.projective_cameras(1920.0).unwrap();
        let normal = Vector3::new(0.2, -0.1, -1.0).normalize();
        let circle = |c: Vector3<f64>, cam: &FrameCamera| {
            conic_of_circle(&cam.k(), &cam.cam_from_world, &c, &normal, 0.04).unwrap()
        };
        let (x1, x2) = (Vector3::new(0.1, 0.2, 0.0), Vector3::new(0.3, 0.25, 0.1));
        let metric_true = delta(&ca.p(), &circle(x1, &ca), &cb.p(), &circle(x1, &cb));
        let proj_true = delta(&pa, &circle(x1, &ca), &pb, &circle(x1, &cb));
        let metric_false = delta(&ca.p(), &circle(x1, &ca), &cb.p(), &circle(x2, &cb));
        let proj_false = delta(&pa, &circle(x1, &ca), &pb, &circle(x2, &cb));
        assert!(
            metric_true.abs() < 1e-9 && proj_true.abs() < 1e-9,
            "{metric_true} {proj_true}"
        );
        assert!(
            (metric_false - proj_false).abs() < 1e-6 * metric_false.abs().max(1e-3),
            "{metric_false} vs {proj_false}"
        );
        assert!(proj_false.abs() > 1e-3);
        // Local metric cameras: their F equals the pair's F.
        let local = pair.local_cameras(&ca, &cb).unwrap();
        let fl = crate::geometry::epipolar::fundamental_from_cameras(
            &local.p_a,
            &local.eye_a,
            &local.p_b,
        )
        .unwrap();
        let fl = fl / fl.norm() * (fl / fl.norm()).dot(&pair.f).signum();
        assert!((fl - pair.f).norm() < 1e-9, "{}", (fl - pair.f).norm());
    }
    use crate::sim::lab::LabConfig;
    use crate::sim::simulate::{SimulateOptions, lab_geometry};

    /// On the SfM stand-in of a small lab: every overlapping pair gets an F that agrees with
    /// the true cameras (in the model's frame), and the injected gross feature mismatches are
    /// what the track triangulation rejects.
    #[test]
    fn pairs_and_tracks_on_the_stand_in() {
        let options = SimulateOptions {
            width: 960,
            height: 540,
            seed: 3,
            ..Default::default()
        };
        let lab = LabConfig {
            frames: 12,
            ..LabConfig::default()
        };
        let (truth, model) = lab_geometry(&options, &lab).unwrap();
        let intrinsics = truth.camera.intrinsics;
        // True intrinsics, stand-in poses.
        let config = RefineConfig {
            min_shared: 30,
            ..Default::default()
        };
        let a1 = algorithm1(&model, Some(&intrinsics), &config).unwrap();
        assert_eq!(a1.frames.len(), 12);
        assert!(a1.pairs.len() >= 30, "{} pairs", a1.pairs.len());
        // The pair's true cameras: true poses mapped into the model frame.
        let sim = truth
            .sfm
            .as_ref()
            .unwrap()
            .stand_in
            .as_ref()
            .unwrap()
            .similarity
            .clone();
        for pair in &a1.pairs {
            let cam = |k: usize| FrameCamera {
                intrinsics,
                cam_from_world: sim.pose_in_sfm(&truth.frames[k].cam_from_world()),
            };
            let (ca, cb) = (cam(pair.a), cam(pair.b));
            // Exact correspondences (the model's points, which the stand-in keeps exact, seen
            // by the true cameras) lie on the estimated epipolar lines to a fraction of the
            // features' 0.5 px noise.
            let mut sq = 0.0;
            let mut n = 0;
            for point in model.points3d.values().take(400) {
                let x = Point3::from(nalgebra::Vector3::from(point.xyz));
                let (pa, pb) = (ca.p() * x.to_homogeneous(), cb.p() * x.to_homogeneous());
                if pa.z <= 0.0 || pb.z <= 0.0 {
                    continue;
                }
                let (xa, xb) = (
                    nalgebra::Vector2::new(pa.x / pa.z, pa.y / pa.z),
                    nalgebra::Vector2::new(pb.x / pb.z, pb.y / pb.z),
                );
                if xa.x < 0.0
                    || xa.y < 0.0
                    || xa.x > 960.0
                    || xa.y > 540.0
                    || xb.x < 0.0
                    || xb.y < 0.0
                    || xb.x > 960.0
                    || xb.y > 540.0
                {
                    continue;
                }
                sq += crate::geometry::epipolar::symmetric_distance_squared(&pair.f, &xa, &xb);
                n += 1;
            }
            let rms = (sq / f64::from(n.max(1))).sqrt();
            assert!(
                n > 20 && rms < 0.3,
                "pair {:?}: exact points {rms} px from their epipolar lines ({n})",
                (pair.a, pair.b)
            );
            // Features carry σ = 0.5 px; σ_ij of the symmetric distance is near 2·0.5.
            assert!(pair.sigma > 0.4 && pair.sigma < 2.0, "σ_ij {}", pair.sigma);
        }
        // Gross mismatches (random pixels, 3 %) must be rejected: the inlier fraction lies
        // between 1 − 2·3 % and 1 − 1 %.
        let frac = a1.track_inlier_fraction();
        assert!(frac > 0.94 && frac < 0.995, "inlier fraction {frac}");
    }
}
