//! What a site survey produces besides frames: dense surface observations (the raw material of a
//! dense reconstruction), the dense cloud triangulated from them, and a terrestrial laser scan
//! with its target coordinates.
//!
//! * Dense points are sampled on the visible surfaces — pipes every `spacing` along and around,
//!   the wall and floor near the pipes more sparsely — and observed in every frame that sees
//!   them (in front, inside, facing, unoccluded), keeping at most 8 frames spread over the
//!   sequence, each observation with Gaussian pixel noise (σ = 0.3 px by default: dense
//!   matching precision). Points seen in fewer than 3 frames are dropped. In a video
//!   ([`super::video`]) each point is seen in its own row of the rolling-shutter frame
//!   ([`observe_samples`] with the video's [`Observer`]).
//! * `fused.ply` is each point triangulated from its noisy observations through the SfM
//!   model's own camera at its poses, in the SfM frame, as COLMAP's dense reconstruction does
//!   (through the true camera for the perturbed-truth stand-in, whose camera was never
//!   adjusted); `fused.ply.vis` says which images saw each point, in COLMAP's format.
//! * The TLS scan casts rays from one station on a regular angular grid and adds range noise;
//!   the TLS target list adds per-axis noise to the true centres. Both carry an optional
//!   coordinate offset (site coordinates are large).

use nalgebra::{Point3, Vector2, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::scene::Scene;
use crate::camera::BrownCamera;
use crate::geometry::Rigid3;
use crate::geometry::triangulation::{Observation, triangulate};
use crate::io::observations::{DenseObservations, DensePoint, PixelObservation};
use crate::io::ply::PointCloud;
use crate::robust::standard_normal as gaussian;

/// Dense sampling options.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenseConfig {
    /// Spacing of points on the pipes at 3840 px frame width (m); scaled by 3840 / width.
    /// Default 2.5 mm.
    pub pipe_spacing_m: f64,
    /// Spacing of points on the wall and floor at 3840 px (m), default 10 mm.
    pub surface_spacing_m: f64,
    /// σ of the pixel noise of dense observations (px), default 0.3.
    pub noise_px: f64,
    /// Most observations kept per point, default 8.
    pub max_views: usize,
    /// Fewest observations for a point to be kept, default 3.
    pub min_views: usize,
    /// σ of a 3D error of each dense point (m, true units), default 0: a multi-view stereo
    /// depth map's error, the same wherever the point is observed (the pixel noise above is
    /// the matching's, independent per view).
    pub point_noise_m: f64,
    /// The direction of that error, default along the surface normal.
    pub point_noise_along: NoiseDirection,
    /// Fraction of points that are outliers (0–0.5), default 0: their depth along their
    /// reference view's ray off by up to ±[`OUTLIER_DEPTH_FRACTION`] of it (uniform), seen
    /// there in every view, as a wrong depth that passed fusion is.
    pub outlier_fraction: f64,
    /// Spacing of points on the pipes at the frames' own width (m), overriding
    /// `pipe_spacing_m`'s scaling with the width: a denser or sparser cloud than the default.
    pub pipe_spacing_at_width_m: Option<f64>,
}

/// Along which direction a dense point's 3D error lies ([`DenseConfig::point_noise_m`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseDirection {
    /// The surface normal (a surface sampled with noise off the surface).
    #[default]
    Normal,
    /// The viewing ray of the point's reference view (a depth map's error, as multi-view
    /// stereo gives).
    Ray,
}

/// Largest depth error of an outlier, as a fraction of its depth ([`DenseConfig::outlier_fraction`]).
pub const OUTLIER_DEPTH_FRACTION: f64 = 0.1;

impl Default for DenseConfig {
    fn default() -> Self {
        DenseConfig {
            pipe_spacing_m: 0.0025,
            surface_spacing_m: 0.01,
            noise_px: 0.3,
            max_views: 8,
            min_views: 3,
            point_noise_m: 0.0,
            point_noise_along: NoiseDirection::Normal,
            outlier_fraction: 0.0,
            pipe_spacing_at_width_m: None,
        }
    }
}

/// TLS options.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TlsConfig {
    /// Scanner position (world, m), default in front of the wall at instrument height.
    pub station: [f64; 3],
    /// Angular step (rad), default 1.5 mrad (≈ 5 mm at 3.3 m).
    pub step_rad: f64,
    /// σ of the range noise (m), default 1.5 mm.
    pub range_noise_m: f64,
    /// σ of target coordinates per axis (m), default 1 mm.
    pub target_noise_m: f64,
    /// Offset added to all TLS coordinates (m), default none.
    pub offset: [f64; 3],
}

impl Default for TlsConfig {
    fn default() -> Self {
        TlsConfig {
            station: [0.3, 3.3, 1.6],
            step_rad: 0.0015,
            range_noise_m: 0.0015,
            target_noise_m: 0.001,
            offset: [0.0; 3],
        }
    }
}

/// A point to sample: position, outward normal, label index.
pub type Sample = (Point3<f64>, Vector3<f64>, u8);

impl DenseConfig {
    /// The pipe and surface spacings (m) at a frame `width` pixels wide (the configured ones
    /// are at 3840 px).
    #[must_use]
    pub fn spacings(&self, width: u32) -> (f64, f64) {
        let scale = 3840.0 / f64::from(width);
        (
            self.pipe_spacing_at_width_m
                .unwrap_or(self.pipe_spacing_m * scale),
            self.surface_spacing_m * scale,
        )
    }
}

/// Points on the pipe site's surfaces and their labels: pipes around their full circumference
/// over the central 2.4 m (a pipe of finite length over its whole length), the end caps of
/// capped pipes (label `NAME_cap`), the wall behind the pipes and the floor in front of them.
/// `pipes` are the site's pipe specifications, in the order of the scene's cylinders.
#[must_use]
pub fn site_samples(
    scene: &Scene,
    pipes: &[super::site::PipeSpec],
    pipe_spacing: f64,
    surface_spacing: f64,
) -> (Vec<Sample>, Vec<String>) {
    let mut labels: Vec<String> = vec!["wall".into(), "floor".into()];
    labels.extend(scene.cylinders.iter().map(|c| c.name.clone()));
    let mut out = Vec::new();
    let label_of_pipe = |k: usize| (2 + k) as u8;
    for (k, c) in scene.cylinders.iter().enumerate() {
        let (start, dir, length, radius) = c.geometry();
        let n_around = (std::f64::consts::TAU * radius / pipe_spacing).ceil() as usize;
        let finite = pipes.get(k).is_some_and(|p| p.length_m.is_some());
        let (s0, s1) = if finite {
            (0.0, length)
        } else {
            (length / 2.0 - 1.2, length / 2.0 + 1.2)
        };
        let n_along = ((s1 - s0) / pipe_spacing).ceil() as usize;
        for i in 0..n_along {
            let s = s0 + (i as f64 + 0.5) * (s1 - s0) / n_along as f64;
            for j in 0..n_around {
                let phi = std::f64::consts::TAU * (j as f64 + 0.5) / n_around as f64;
                let (p, n) = c.surface(phi, s);
                out.push((p, n, label_of_pipe(k)));
            }
        }
        if !pipes.get(k).is_some_and(|p| p.capped) {
            continue;
        }
        // The caps' outer faces: rings of the pipe spacing (their rims are the pipe's ends).
        labels.push(format!("{}_cap", c.name));
        let cap_label = (labels.len() - 1) as u8;
        let (e1, e2) = crate::geometry::plane_basis(&dir);
        for (centre, normal) in [(start, -dir), (start + dir * length, dir)] {
            let rings = (radius / pipe_spacing).ceil() as usize;
            for i in 0..rings {
                let rho = radius * (i as f64 + 0.5) / rings as f64;
                let n_ring = ((std::f64::consts::TAU * rho / pipe_spacing).ceil() as usize).max(1);
                for j in 0..n_ring {
                    let phi = std::f64::consts::TAU * (j as f64 + 0.5) / n_ring as f64;
                    let p = centre + (e1 * phi.cos() + e2 * phi.sin()) * rho;
                    out.push((p, normal, cap_label));
                }
            }
        }
    }
    for (k, r) in scene.rects.iter().enumerate() {
        let (w, h) = r.size();
        // Wall: 1.2 m either side of the middle, 0.3 to 2.6 m high; floor: 1.5 m deep.
        let (a0, a1, b0, b1) = if k == 0 {
            (w / 2.0 - 1.2, w / 2.0 + 1.2, 0.3, 2.6)
        } else {
            (w / 2.0 - 1.2, w / 2.0 + 1.2, 0.05, 1.5_f64.min(h))
        };
        let (na, nb) = (
            ((a1 - a0) / surface_spacing).ceil() as usize,
            ((b1 - b0) / surface_spacing).ceil() as usize,
        );
        for i in 0..na {
            for j in 0..nb {
                let (a, b) = (
                    a0 + (i as f64 + 0.5) * (a1 - a0) / na as f64,
                    b0 + (j as f64 + 0.5) * (b1 - b0) / nb as f64,
                );
                out.push((r.point(a, b), r.normal(), k as u8));
            }
        }
    }
    (out, labels)
}

/// How a frame sees a surface point: `observe(frame, point, normal, at)` is `None` when the
/// frame does not see `point` (normal `normal`), else the pixel of `at` (the point itself, or
/// where the reconstruction misplaces it) and the camera centre it is seen from (a moving
/// rolling-shutter camera, [`super::video`], sees each point in its own row).
pub type Observer<'a> = dyn ObserverFn + 'a;

/// The function behind an [`Observer`].
pub trait ObserverFn:
    Fn(usize, &Point3<f64>, &Vector3<f64>, &Point3<f64>) -> Option<(Vector2<f64>, Point3<f64>)> + Sync
{
}

impl<F> ObserverFn for F where
    F: Fn(usize, &Point3<f64>, &Vector3<f64>, &Point3<f64>) -> Option<(Vector2<f64>, Point3<f64>)>
        + Sync
{
}

/// The dense observations of surface points `samples` (point, outward normal, label: an index
/// into `labels`): each in every frame `observe` sees it in, at most `config.max_views` spread
/// over them, with pixel noise; points seen in fewer than `config.min_views` dropped. With a
/// 3D error ([`DenseConfig::point_noise_m`], outliers) the kept views observe the misplaced
/// point (its visibility stays the surface point's); the reference view of a ray error is
/// one of the kept views, drawn.
#[must_use]
pub fn observe_samples(
    samples: &[Sample],
    labels: Vec<String>,
    observe: &Observer<'_>,
    frame_names: &[String],
    config: &DenseConfig,
    seed: u64,
) -> DenseObservations {
    let points: Vec<DensePoint> = samples
        .par_iter()
        .enumerate()
        .filter_map(|(k, (p, n, label))| {
            let seen: Vec<(usize, Vector2<f64>)> = (0..frame_names.len())
                .filter_map(|f| observe(f, p, n, p).map(|(uv, _)| (f, uv)))
                .collect();
            if seen.len() < config.min_views {
                return None;
            }
            // Keep at most max_views frames spread evenly over those that see the point.
            let keep: Vec<(usize, Vector2<f64>)> = if seen.len() <= config.max_views {
                seen
            } else {
                (0..config.max_views)
                    .map(|i| seen[i * (seen.len() - 1) / (config.max_views - 1).max(1)])
                    .collect()
            };
            let mut rng =
                ChaCha8Rng::seed_from_u64(seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let keep = match misplaced(p, n, &keep, observe, config, &mut rng) {
                Some(at) => keep
                    .iter()
                    .filter_map(|&(f, _)| observe(f, p, n, &at).map(|(uv, _)| (f, uv)))
                    .collect(),
                None => keep,
            };
            if keep.len() < config.min_views {
                return None;
            }
            let observations = keep
                .into_iter()
                .map(|(f, uv)| PixelObservation {
                    frame: f as u32,
                    uv: uv + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * config.noise_px,
                })
                .collect();
            Some(DensePoint {
                id: k as u64 + 1,
                label: *label,
                position: *p,
                observations,
            })
        })
        .collect();
    DenseObservations {
        frames: frame_names.to_vec(),
        labels,
        points,
    }
}

/// Where the reconstruction places the surface point `p` (normal `n`, seen in the views
/// `keep`): `None` when it is exact (no 3D error configured); otherwise off by the point noise
/// along the normal or the reference view's ray, or, for an outlier, by a depth error along
/// that ray. Draws from `rng` in a fixed order.
fn misplaced(
    p: &Point3<f64>,
    n: &Vector3<f64>,
    keep: &[(usize, Vector2<f64>)],
    observe: &Observer<'_>,
    config: &DenseConfig,
    rng: &mut ChaCha8Rng,
) -> Option<Point3<f64>> {
    use rand::Rng;
    if config.point_noise_m <= 0.0 && config.outlier_fraction <= 0.0 {
        return None;
    }
    let reference = keep[rng.random_range(0..keep.len())].0;
    let (_, eye) = observe(reference, p, n, p)?;
    let ray = (p - eye).normalize();
    let outlier = rng.random::<f64>() < config.outlier_fraction;
    let e = gaussian(rng) * config.point_noise_m;
    if outlier {
        let depth = (p - eye).norm();
        let off = rng.random_range(-1.0..1.0) * OUTLIER_DEPTH_FRACTION * depth;
        return Some(p + ray * off);
    }
    Some(match config.point_noise_along {
        NoiseDirection::Normal => p + n * e,
        NoiseDirection::Ray => p + ray * e,
    })
}

/// Triangulates every dense point through `camera` at `poses` (any frame, e.g. the SfM
/// model's; `None` for frames without a pose, whose observations are skipped): the dense
/// cloud, and per cloud point the frames (indices into `observations.frames`) it was
/// triangulated from — what COLMAP's `fused.ply.vis` records. Points left with fewer than two
/// views or that do not triangulate in front of their cameras are dropped.
#[must_use]
pub fn fuse(
    observations: &DenseObservations,
    camera: &BrownCamera,
    poses: &[Option<Rigid3>],
) -> (PointCloud, Vec<Vec<u32>>) {
    fuse_with(observations, camera, &|frame, _| {
        poses.get(frame as usize).copied().flatten()
    })
}

/// [`fuse`] with each observation's camera pose given by `pose(frame, pixel)` (e.g. the pose
/// of the row the pixel lies in, for a rolling-shutter frame); `None` skips the observation.
#[must_use]
pub fn fuse_with(
    observations: &DenseObservations,
    camera: &BrownCamera,
    pose: &(dyn Fn(u32, &Vector2<f64>) -> Option<Rigid3> + Sync),
) -> (PointCloud, Vec<Vec<u32>>) {
    let fused: Vec<(Point3<f64>, u8, Vec<u32>)> = observations
        .points
        .par_iter()
        .filter_map(|p| {
            let (obs, frames): (Vec<Observation>, Vec<u32>) = p
                .observations
                .iter()
                .filter_map(|o| {
                    let xy = camera.intrinsics.ideal_from_pixel(&o.uv).ok()?;
                    Some((Observation::normalized(&pose(o.frame, &o.uv)?, xy), o.frame))
                })
                .unzip();
            if obs.len() < 2 {
                return None;
            }
            triangulate(&obs).map(|x| (x, p.label, frames))
        })
        .collect();
    let grey = |label: u8| {
        if label >= 2 {
            [150, 150, 160]
        } else {
            [120, 115, 110]
        }
    };
    let cloud = PointCloud {
        points: fused.iter().map(|f| f.0).collect(),
        colors: Some(fused.iter().map(|f| grey(f.1)).collect()),
        ..Default::default()
    };
    (cloud, fused.into_iter().map(|f| f.2).collect())
}

/// The TLS scan: one station, a regular angular grid over the wall region behind the pipes,
/// range noise along each ray; intensity is the surface albedo. Coordinates include the offset.
#[must_use]
pub fn tls_scan(scene: &Scene, config: &TlsConfig, seed: u64) -> PointCloud {
    let station = Point3::from(config.station);
    // Azimuth toward the wall (−y) ± the angle covering x ∈ [−1.6, 1.6]; elevation covering
    // z ∈ [0, 2.7] at the wall.
    let dy = station.y;
    let az_half = (1.6 / dy).atan() + 0.1;
    let el_lo = ((0.0 - station.z) / dy).atan();
    let el_hi = ((2.7 - station.z) / dy).atan();
    let n_az = (2.0 * az_half / config.step_rad).ceil() as usize;
    let n_el = ((el_hi - el_lo) / config.step_rad).ceil() as usize;
    let offset = Vector3::from(config.offset);
    let rows: Vec<Vec<(Point3<f64>, f32)>> = (0..n_el)
        .into_par_iter()
        .map(|i| {
            let mut rng = ChaCha8Rng::seed_from_u64(
                seed ^ 0x715 ^ (i as u64).wrapping_mul(0xD1B5_4A32_D192_ED03),
            );
            let el = el_lo + (i as f64 + 0.5) * (el_hi - el_lo) / n_el as f64;
            (0..n_az)
                .filter_map(|j| {
                    let az = -az_half + (j as f64 + 0.5) * 2.0 * az_half / n_az as f64;
                    let dir = Vector3::new(az.sin() * el.cos(), -az.cos() * el.cos(), el.sin());
                    let hit = scene.intersect(&station, &dir)?;
                    let range = hit.t + gaussian(&mut rng) * config.range_noise_m;
                    Some((station + dir * range + offset, hit.albedo as f32))
                })
                .collect()
        })
        .collect();
    let all: Vec<(Point3<f64>, f32)> = rows.into_iter().flatten().collect();
    PointCloud {
        points: all.iter().map(|p| p.0).collect(),
        intensity: Some(all.iter().map(|p| p.1).collect()),
        ..Default::default()
    }
}

/// The TLS target coordinates: true centres plus per-axis noise and the offset, `(id, x, y, z)`.
#[must_use]
pub fn tls_targets(scene: &Scene, config: &TlsConfig, seed: u64) -> Vec<(u32, [f64; 3])> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7A6);
    scene
        .targets
        .iter()
        .map(|t| {
            let mut p = t.centre;
            for (k, v) in p.iter_mut().enumerate() {
                *v += gaussian(&mut rng) * config.target_noise_m + config.offset[k];
            }
            (t.id, p)
        })
        .collect()
}
