//! The calibration lab of the paper's Fig. 1: one corner of a room, two perpendicular textured
//! walls carrying black-and-white circular targets of three radii, an optional floor, two
//! ceiling lights, and the camera path of the paper's data collection: convergent views from
//! the bottom of a ladder looking up to its top looking down in portrait, then rolled 90° about
//! the optical axis and back down in landscape. A faintly textured ceiling closes the room.
//!
//! World frame: the corner line is the z axis (up); wall A lies in the plane y = 0 along +x,
//! wall B in the plane x = 0 along +y, the floor is z = 0; the room is x, y > 0.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::scene::{Light, Polarity, Rect, Scene};
use super::texture::{Speckle, Texture, TextureStyle};
use super::truth::Orientation;
use crate::geometry::Rigid3;

/// Lab dimensions and content.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LabConfig {
    /// Width of wall A along x (m), default 3.6.
    pub wall_a_m: f64,
    /// Width of wall B along y (m), default 3.4.
    pub wall_b_m: f64,
    /// Wall height (m), default 2.9.
    pub height_m: f64,
    /// Number of targets (approximately; a jittered grid per wall), default 200.
    pub targets: usize,
    /// Target radii (m) used in turn, default 10, 20 and 40 mm.
    pub radii_m: Vec<f64>,
    /// Include the floor, default true.
    pub floor: bool,
    /// Frames along the path, default 90 (the paper: 90 frames at 1 fps).
    pub frames: usize,
    /// What the walls look like between the targets, default plaster.
    pub wall_texture: WallTexture,
}

/// The walls' texture between the targets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WallTexture {
    /// Painted plaster with stains and speckle at every scale ([`TextureStyle::WALL`]).
    #[default]
    Plaster,
    /// The plaster with blobs of the targets' sizes sprayed over it, dark and light, from
    /// nearly round to lumpy ([`Speckle::WALL`]): what a target detector must not take for a
    /// target.
    Speckled,
}

impl Default for LabConfig {
    fn default() -> Self {
        LabConfig {
            wall_a_m: 3.6,
            wall_b_m: 3.4,
            height_m: 2.9,
            targets: 200,
            radii_m: vec![0.010, 0.020, 0.040],
            floor: true,
            frames: 90,
            wall_texture: WallTexture::Plaster,
        }
    }
}

/// Why a lab cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("lab option `{field}`: {reason}")]
pub struct LabConfigError {
    /// The option.
    pub field: &'static str,
    /// What is wrong.
    pub reason: String,
}

impl LabConfig {
    /// Checks the values.
    ///
    /// # Errors
    ///
    /// [`LabConfigError`] naming the first bad option.
    pub fn validate(&self) -> Result<(), LabConfigError> {
        let bad = |field, reason: &str| {
            Err(LabConfigError {
                field,
                reason: reason.into(),
            })
        };
        for (field, v) in [
            ("wall_a_m", self.wall_a_m),
            ("wall_b_m", self.wall_b_m),
            ("height_m", self.height_m),
        ] {
            if !(v.is_finite() && (1.5..=10.0).contains(&v)) {
                return bad(field, "must be between 1.5 and 10 m");
            }
        }
        if !(2..=2000).contains(&self.targets) {
            return bad("targets", "must be between 2 and 2000");
        }
        if self.radii_m.is_empty() || self.radii_m.iter().any(|r| !(0.002..=0.2).contains(r)) {
            return bad("radii_m", "needs radii between 2 mm and 200 mm");
        }
        if self.frames < 2 {
            return bad("frames", "needs at least 2 frames");
        }
        Ok(())
    }
}

/// A camera position on the path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Station {
    /// `cam_from_world`.
    pub cam_from_world: Rigid3,
    /// How the phone is held.
    pub orientation: Orientation,
}

impl Station {
    /// A phone at `eye` looking at `target` with world Z up, held in `orientation` (portrait is
    /// a quarter turn about the optical axis) and rolled by a further `roll_jitter` (rad).
    #[must_use]
    pub fn held(
        eye: &Point3<f64>,
        target: &Point3<f64>,
        orientation: Orientation,
        roll_jitter: f64,
    ) -> Self {
        let roll = match orientation {
            Orientation::Portrait => std::f64::consts::FRAC_PI_2,
            Orientation::Landscape => 0.0,
        } + roll_jitter;
        Station {
            cam_from_world: look_at(eye, target, &Vector3::z(), roll),
            orientation,
        }
    }
}

/// `cam_from_world` of a camera at `eye` looking at `target`, image up along world `up`,
/// rolled by `roll` about the optical axis (camera X right, Y down, Z forward).
#[must_use]
pub fn look_at(eye: &Point3<f64>, target: &Point3<f64>, up: &Vector3<f64>, roll: f64) -> Rigid3 {
    let z = (target - eye).normalize();
    let x = z.cross(up).normalize();
    let y = z.cross(&x);
    let (s, c) = roll.sin_cos();
    let (xr, yr) = (x * c + y * s, y * c - x * s);
    let rot = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[xr, yr, z]));
    let world_from_cam = Isometry3::from_parts(
        Translation3::from(eye.coords),
        UnitQuaternion::from_rotation_matrix(&rot),
    );
    world_from_cam.inverse()
}

/// Builds the lab scene; `texel_m` sets the texture resolution (choose about half a pixel at
/// the nearest viewing distance).
#[must_use]
pub fn build_scene(config: &LabConfig, texel_m: f64, seed: u64) -> Scene {
    let (wa, wb, h) = (config.wall_a_m, config.wall_b_m, config.height_m);
    let wall = |size: (f64, f64), seed: u64| match config.wall_texture {
        WallTexture::Plaster => Texture::bake(size, texel_m, TextureStyle::WALL, seed),
        WallTexture::Speckled => {
            Texture::bake_speckled(size, texel_m, TextureStyle::WALL, Speckle::WALL, seed)
        }
    };
    let mut rects = vec![
        // Wall A: plane y = 0, u = −x, v = +z (normal +y, into the room).
        Rect::new(
            "wall_a",
            Point3::new(wa, 0.0, 0.0),
            -Vector3::x(),
            Vector3::z(),
            (wa, h),
            wall((wa, h), seed ^ 0xA),
        ),
        // Wall B: plane x = 0, u = +y, v = +z (normal +x).
        Rect::new(
            "wall_b",
            Point3::origin(),
            Vector3::y(),
            Vector3::z(),
            (wb, h),
            wall((wb, h), seed ^ 0xB),
        ),
    ];
    if config.floor {
        rects.push(Rect::new(
            "floor",
            Point3::origin(),
            Vector3::x(),
            Vector3::y(),
            (wa, wb),
            Texture::bake((wa, wb), texel_m * 1.5, TextureStyle::FLOOR, seed ^ 0xF),
        ));
    }
    // Ceiling: plane z = h, u = +y, v = +x (normal −z).
    rects.push(Rect::new(
        "ceiling",
        Point3::new(0.0, 0.0, h),
        Vector3::y(),
        Vector3::x(),
        (wb, wa),
        Texture::bake((wb, wa), texel_m * 3.0, TextureStyle::CEILING, seed ^ 0xC),
    ));
    let mut scene = Scene {
        rects,
        lights: vec![
            Light {
                position: Point3::new(2.4, 1.4, h - 0.1),
                intensity: 3.0,
            },
            Light {
                position: Point3::new(1.3, 2.5, h - 0.1),
                intensity: 3.0,
            },
        ],
        ambient: 0.35,
        ..Default::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7A26);
    let per_wall = [config.targets / 2, config.targets - config.targets / 2];
    let mut k = 0usize;
    for (wall, &count) in per_wall.iter().enumerate() {
        let (w, hh) = scene.rects[wall].size();
        let margin = 0.18;
        let cols = ((count as f64 * (w - 2.0 * margin) / (hh - 2.0 * margin))
            .sqrt()
            .round() as usize)
            .max(1);
        let rows = count.div_ceil(cols);
        let (da, db) = (
            (w - 2.0 * margin) / cols as f64,
            (hh - 2.0 * margin) / rows as f64,
        );
        let mut placed = Vec::new();
        'grid: for r in 0..rows {
            for c in 0..cols {
                if placed.len() == count {
                    break 'grid;
                }
                let radius = config.radii_m[(k * 7 + r) % config.radii_m.len()];
                let plate_half = 1.3 * radius;
                // Jitter keeps plates apart: at most a quarter of the free space per side.
                let free_a = (da - 2.0 * plate_half).max(0.0) / 4.0;
                let free_b = (db - 2.0 * plate_half).max(0.0) / 4.0;
                let a = margin + (c as f64 + 0.5) * da + rng.random_range(-1.0..=1.0) * free_a;
                let b = margin + (r as f64 + 0.5) * db + rng.random_range(-1.0..=1.0) * free_b;
                let polarity = if (k + r).is_multiple_of(2) {
                    Polarity::BlackOnWhite
                } else {
                    Polarity::WhiteOnBlack
                };
                placed.push((a, b, radius, plate_half, polarity));
                k += 1;
            }
        }
        scene.place_targets(wall, placed);
    }
    scene
}

/// The reference irradiance for the exposure: the middle of wall A.
#[must_use]
pub fn reference_irradiance(scene: &Scene, config: &LabConfig) -> f64 {
    scene.irradiance(
        &Point3::new(config.wall_a_m / 2.0, 0.0, config.height_m / 2.0),
        &Vector3::y(),
    )
}

/// The camera path: half the frames in portrait climbing the ladder (looking up at the bottom,
/// down at the top), the rest in landscape coming back down; the ladder stands on the room's
/// diagonal about 2.7 m from the corner and the camera sways sideways, so the views converge
/// on the corner from varied directions. Seeded jitter of a few centimetres and degrees.
#[must_use]
pub fn path(config: &LabConfig, seed: u64) -> Vec<Station> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9A7);
    let n = config.frames;
    let n_up = n.div_ceil(2);
    let n_down = n - n_up;
    let diag = Vector3::new(1.0, 1.0, 0.0).normalize();
    let side = Vector3::new(1.0, -1.0, 0.0).normalize();
    let scale = (config.wall_a_m.min(config.wall_b_m) / 3.4).min(config.height_m / 2.9);
    (0..n)
        .map(|k| {
            let (phase, orientation) = if k < n_up {
                (k as f64 / (n_up.max(2) - 1) as f64, Orientation::Portrait)
            } else {
                let j = k - n_up;
                (
                    1.0 - j as f64 / (n_down.max(2) - 1) as f64,
                    Orientation::Landscape,
                )
            };
            let offset = if orientation == Orientation::Portrait {
                0.0
            } else {
                1.1
            };
            let height = scale * (0.45 + 2.1 * phase);
            let distance = scale * (2.7 + 0.25 * (std::f64::consts::TAU * phase).cos());
            let sway = scale * 0.6 * (std::f64::consts::TAU * 1.5 * phase + offset).sin();
            let jitter = |rng: &mut ChaCha8Rng, s: f64| {
                Vector3::new(
                    rng.random_range(-s..s),
                    rng.random_range(-s..s),
                    rng.random_range(-s..s),
                )
            };
            let eye = Point3::from(
                diag * distance
                    + side * sway
                    + Vector3::z() * height
                    + jitter(&mut rng, 0.03 * scale),
            );
            // Pitch from +28° at the bottom to −28° at the top; aim near the corner with a
            // sideways offset so that the walls are seen at varied angles.
            let pitch = 28f64.to_radians() * (1.0 - 2.0 * phase);
            let aim_side = -0.5 * sway;
            let corner = Point3::from(
                diag * 0.35 * scale
                    + side * aim_side
                    + Vector3::z() * (height + pitch.tan() * distance),
            );
            let target = corner + jitter(&mut rng, 0.05 * scale);
            Station::held(
                &eye,
                &target,
                orientation,
                rng.random_range(-2f64..2.0).to_radians(),
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose::camera_centre;

    #[test]
    fn look_at_points_the_optical_axis_at_the_target() {
        let eye = Point3::new(2.0, 2.0, 1.0);
        let target = Point3::new(0.0, 0.0, 1.5);
        let pose = look_at(&eye, &target, &Vector3::z(), 0.3);
        let t = pose * target;
        assert!(t.x.abs() < 1e-12 && t.y.abs() < 1e-12 && t.z > 0.0);
        assert!((camera_centre(&pose) - eye).norm() < 1e-12);
        // Without roll, world up projects to image up (−Y).
        let level = look_at(&eye, &target, &Vector3::z(), 0.0);
        let up = level.rotation * Vector3::z();
        assert!(up.y < 0.0 && up.x.abs() < 1e-12);
    }

    #[test]
    fn scene_has_the_configured_targets_of_every_radius_and_both_polarities() {
        let cfg = LabConfig::default();
        let scene = build_scene(&cfg, 0.01, 1);
        assert_eq!(scene.targets.len(), 200);
        for r in &cfg.radii_m {
            assert!(scene.targets.iter().filter(|t| t.radius == *r).count() > 30);
        }
        assert!(
            scene
                .targets
                .iter()
                .any(|t| t.polarity == Polarity::WhiteOnBlack)
        );
        assert!(
            scene
                .targets
                .iter()
                .any(|t| t.polarity == Polarity::BlackOnWhite)
        );
        // No two plates overlap (same wall, Chebyshev distance > sum of half sides).
        for (i, a) in scene.targets.iter().enumerate() {
            for b in &scene.targets[i + 1..] {
                if a.normal != b.normal {
                    continue;
                }
                let d = (0..3)
                    .map(|k| (a.centre[k] - b.centre[k]).abs())
                    .fold(0.0, f64::max);
                assert!(
                    d > a.plate_half + b.plate_half,
                    "targets {} and {} overlap",
                    a.id,
                    b.id
                );
            }
        }
    }

    #[test]
    fn path_goes_up_in_portrait_and_down_in_landscape() {
        let cfg = LabConfig::default();
        let p = path(&cfg, 1);
        assert_eq!(p.len(), 90);
        let h = |s: &Station| camera_centre(&s.cam_from_world).z;
        assert!(
            p[..45]
                .iter()
                .all(|s| s.orientation == Orientation::Portrait)
        );
        assert!(
            p[45..]
                .iter()
                .all(|s| s.orientation == Orientation::Landscape)
        );
        assert!(h(&p[0]) < 0.6 && h(&p[44]) > 2.4 && h(&p[45]) > 2.4 && h(&p[89]) < 0.6);
        // Looking up at the bottom, down at the top: the optical axis' world z component.
        let axis_z = |s: &Station| (s.cam_from_world.rotation.inverse() * Vector3::z()).z;
        assert!(axis_z(&p[0]) > 0.3 && axis_z(&p[44]) < -0.3);
    }
}
