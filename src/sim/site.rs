//! The pipe site of the paper's Fig. 6: professionally installed mock pipes of standard outside
//! diameters in front of a textured wall carrying circular targets, a floor, and a camera path
//! around the pipe of interest (half the frames in portrait, half in landscape).
//!
//! World frame: the wall is the plane y = 0 (the room at y > 0), the floor z = 0; the pipes run
//! along x.

use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::lab::Station;
use super::scene::{Cylinder, Light, Polarity, Rect, Scene};
use super::texture::{Texture, TextureStyle};
use super::truth::{Orientation, PipeTruth};

/// Outside radius of 2" schedule pipe (OD 60.3 mm).
pub const PIPE_2IN_RADIUS_M: f64 = 0.060_3 / 2.0;
/// Outside radius of 4" schedule pipe (OD 114.3 mm).
pub const PIPE_4IN_RADIUS_M: f64 = 0.114_3 / 2.0;
/// Outside radius of 6" schedule pipe (OD 168.3 mm).
pub const PIPE_6IN_RADIUS_M: f64 = 0.168_3 / 2.0;

/// One pipe of the site: horizontal along x.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PipeSpec {
    /// Name (`pipe_4in`).
    pub name: String,
    /// Outside radius (m).
    pub radius_m: f64,
    /// Distance of the axis from the wall (m).
    pub wall_distance_m: f64,
    /// Height of the axis above the floor (m).
    pub height_m: f64,
    /// Length (m), centred on `centre_x_m`; `None`: the whole wall's width (both ends beyond
    /// the part of the scene that is sampled and scanned).
    #[serde(default)]
    pub length_m: Option<f64>,
    /// Where along x the middle of a pipe of finite length lies (m).
    #[serde(default)]
    pub centre_x_m: f64,
    /// Flat end caps on a pipe of finite length (a capped pipe, as a pressure test or an
    /// independent renderer's scene has them): discs that occlude, are rendered, sampled in
    /// the dense cloud and scanned.
    #[serde(default)]
    pub capped: bool,
}

impl PipeSpec {
    /// A pipe running the wall's whole width (no ends in view).
    #[must_use]
    pub fn full_width(name: &str, radius_m: f64, wall_distance_m: f64, height_m: f64) -> Self {
        PipeSpec {
            name: name.into(),
            radius_m,
            wall_distance_m,
            height_m,
            length_m: None,
            centre_x_m: 0.0,
            capped: false,
        }
    }

    /// The pipe's axis: its start (smaller x), unit direction (+x) and length.
    #[must_use]
    pub fn axis(&self) -> (Point3<f64>, Vector3<f64>, f64) {
        let length = self.length_m.unwrap_or(2.0 * HALF_WIDTH_M);
        (
            Point3::new(
                self.centre_x_m - 0.5 * length,
                self.wall_distance_m,
                self.height_m,
            ),
            Vector3::x(),
            length,
        )
    }
}

/// Site content.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SiteConfig {
    /// The pipes, default 6", 4" and 2" schedule pipe.
    pub pipes: Vec<PipeSpec>,
    /// Index of the pipe of interest, default 1 (the 4" pipe).
    pub pipe_of_interest: usize,
    /// Number of wall targets (6–12), default 8.
    pub targets: usize,
    /// Frames around the pipe (half portrait, half landscape), default 60.
    pub frames: usize,
    /// Distance of the camera path from the pipe of interest (m), default 1.5.
    pub path_radius_m: f64,
    /// How far the path's distance swings either side of `path_radius_m` over the path (m),
    /// default 0.
    pub path_radius_spread_m: f64,
}

impl Default for SiteConfig {
    fn default() -> Self {
        SiteConfig {
            pipes: vec![
                PipeSpec::full_width("pipe_6in", PIPE_6IN_RADIUS_M, 0.55, 0.9),
                PipeSpec::full_width("pipe_4in", PIPE_4IN_RADIUS_M, 0.45, 1.45),
                PipeSpec::full_width("pipe_2in", PIPE_2IN_RADIUS_M, 0.35, 1.95),
            ],
            pipe_of_interest: 1,
            targets: 8,
            frames: 60,
            path_radius_m: 1.5,
            path_radius_spread_m: 0.0,
        }
    }
}

/// Half the length of the wall and the pipes along x (m).
const HALF_WIDTH_M: f64 = 2.5;
/// Wall height (m).
const WALL_HEIGHT_M: f64 = 3.0;
/// Floor depth from the wall (m).
const FLOOR_DEPTH_M: f64 = 3.5;

/// Why a site cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("site option `{field}`: {reason}")]
pub struct SiteConfigError {
    /// The option.
    pub field: &'static str,
    /// What is wrong.
    pub reason: String,
}

/// The two-pipe layout ([`SiteConfig::two_pipes`]): the 2" pipe's axis from the wall (m).
const TWO_PIPES_FRONT_WALL_M: f64 = 0.52;
/// How much further back (toward the wall) the 6" pipe's axis lies (m).
const TWO_PIPES_DEPTH_STEP_M: f64 = 0.14;

impl SiteConfig {
    /// A site unlike the default one, as an independent renderer's scene was: two capped
    /// pipes, a 2" one (1.16 m long) in front of a 6" one (1.6 m long) whose axis lies 0.14 m
    /// further back and 4 cm lower, so the front pipe hides a strip of the back one in most
    /// frames; 20 frames on an arc around the 2" pipe at 1.35–1.9 m. The 2" pipe is the pipe
    /// of interest.
    #[must_use]
    pub fn two_pipes() -> Self {
        let front = PipeSpec {
            length_m: Some(1.16),
            centre_x_m: 0.05,
            capped: true,
            ..PipeSpec::full_width("pipe_2in", PIPE_2IN_RADIUS_M, TWO_PIPES_FRONT_WALL_M, 1.3)
        };
        let back = PipeSpec {
            length_m: Some(1.6),
            centre_x_m: -0.1,
            capped: true,
            ..PipeSpec::full_width(
                "pipe_6in",
                PIPE_6IN_RADIUS_M,
                TWO_PIPES_FRONT_WALL_M - TWO_PIPES_DEPTH_STEP_M,
                1.26,
            )
        };
        SiteConfig {
            pipes: vec![front, back],
            pipe_of_interest: 0,
            targets: 10,
            frames: 20,
            path_radius_m: 1.625,
            path_radius_spread_m: 0.275,
        }
    }

    /// Checks the values.
    ///
    /// # Errors
    ///
    /// [`SiteConfigError`] naming the first bad option.
    pub fn validate(&self) -> Result<(), SiteConfigError> {
        let bad = |field, reason: &str| {
            Err(SiteConfigError {
                field,
                reason: reason.into(),
            })
        };
        if self.pipes.is_empty() || self.pipe_of_interest >= self.pipes.len() {
            return bad("pipe_of_interest", "must index one of the pipes");
        }
        for p in &self.pipes {
            if !(0.005..=0.5).contains(&p.radius_m)
                || p.wall_distance_m <= p.radius_m
                || p.height_m <= p.radius_m
            {
                return bad(
                    "pipes",
                    "each pipe needs a radius of 5–500 mm, clear of the wall and floor",
                );
            }
            let (start, _, length) = p.axis();
            if !(length > 0.0 && start.x >= -HALF_WIDTH_M && start.x + length <= HALF_WIDTH_M) {
                return bad(
                    "pipes",
                    "a pipe's length must be positive and lie within the wall's 5 m width",
                );
            }
            if p.capped && p.length_m.is_none() {
                return bad("pipes", "only a pipe of finite length can be capped");
            }
        }
        if !(2..=40).contains(&self.targets) {
            return bad("targets", "must be between 2 and 40");
        }
        if self.frames < 2 {
            return bad("frames", "needs at least 2 frames");
        }
        if !(0.5..=6.0).contains(&self.path_radius_m) {
            return bad("path_radius_m", "must be between 0.5 and 6 m");
        }
        if !(0.0..=0.5 * self.path_radius_m).contains(&self.path_radius_spread_m) {
            return bad(
                "path_radius_spread_m",
                "must be between 0 and half the path's radius",
            );
        }
        Ok(())
    }

    /// The pipe of interest.
    #[must_use]
    pub fn interest(&self) -> &PipeSpec {
        &self.pipes[self.pipe_of_interest]
    }

    /// The pipes as truth records.
    #[must_use]
    pub fn pipe_truth(&self) -> Vec<PipeTruth> {
        self.pipes
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let (start, dir, length) = p.axis();
                PipeTruth {
                    name: p.name.clone(),
                    radius: p.radius_m,
                    axis_point: (start + dir * (0.5 * length)).into(),
                    axis_direction: dir.into(),
                    length,
                    of_interest: k == self.pipe_of_interest,
                }
            })
            .collect()
    }
}

/// Builds the site scene.
#[must_use]
pub fn build_scene(config: &SiteConfig, texel_m: f64, seed: u64) -> Scene {
    let w = 2.0 * HALF_WIDTH_M;
    let rects = vec![
        // Wall: plane y = 0, u = −x, v = +z (normal +y).
        Rect::new(
            "wall",
            Point3::new(HALF_WIDTH_M, 0.0, 0.0),
            -Vector3::x(),
            Vector3::z(),
            (w, WALL_HEIGHT_M),
            Texture::bake(
                (w, WALL_HEIGHT_M),
                texel_m * 1.5,
                TextureStyle::WALL,
                seed ^ 0x51,
            ),
        ),
        // Floor: plane z = 0, u = +x, v = +y (normal +z).
        Rect::new(
            "floor",
            Point3::new(-HALF_WIDTH_M, 0.0, 0.0),
            Vector3::x(),
            Vector3::y(),
            (w, FLOOR_DEPTH_M),
            Texture::bake(
                (w, FLOOR_DEPTH_M),
                texel_m * 2.0,
                TextureStyle::FLOOR,
                seed ^ 0x52,
            ),
        ),
    ];
    let cylinders = config
        .pipes
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let circumference = std::f64::consts::TAU * p.radius_m;
            let (start, dir, length) = p.axis();
            Cylinder::new(
                &p.name,
                start,
                dir,
                length,
                p.radius_m,
                Texture::bake_periodic(
                    (circumference, length),
                    texel_m,
                    TextureStyle::PIPE,
                    seed ^ (0x60 + k as u64),
                ),
            )
        })
        .collect();
    let mut scene = Scene {
        rects,
        cylinders,
        lights: vec![
            Light {
                position: Point3::new(-1.0, 2.5, 2.8),
                intensity: 3.0,
            },
            Light {
                position: Point3::new(1.3, 2.0, 2.8),
                intensity: 3.0,
            },
        ],
        ambient: 0.35,
        solids: caps(config),
        ..Default::default()
    };
    // Targets around and behind the pipes: a jittered ring of positions on the wall in the
    // region the path sees. Wall plane coordinates: a = HALF_WIDTH − x, b = z.
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7A);
    let n = config.targets;
    let mut placed = Vec::new();
    for k in 0..n {
        let angle = std::f64::consts::TAU * (k as f64 + 0.5) / n as f64;
        let x = 0.95 * angle.cos() + rng.random_range(-0.08..0.08);
        let z = 1.45 + 0.75 * angle.sin() + rng.random_range(-0.06..0.06);
        let radius = if k % 2 == 0 { 0.04 } else { 0.025 };
        let polarity = if k % 3 == 0 {
            Polarity::WhiteOnBlack
        } else {
            Polarity::BlackOnWhite
        };
        placed.push((HALF_WIDTH_M - x, z, radius, 1.3 * radius, polarity));
    }
    scene.place_targets(0, placed);
    scene
}

/// Thickness of a pipe's end cap (m): a plate welded on, as on a pressure-test spool.
const CAP_THICKNESS_M: f64 = 0.004;
/// Albedo of the end caps (painted steel, a little darker than the pipes' mean).
const CAP_ALBEDO: f64 = 0.45;

/// The capped pipes' end caps as solids: a disc of the pipe's radius, [`CAP_THICKNESS_M`]
/// thick, closing each end (its outer face at the pipe's end). `None` without capped pipes.
fn caps(config: &SiteConfig) -> Option<std::sync::Arc<super::scene::Solids>> {
    use parry3d_f64::shape::SharedShape;
    let shapes: Vec<_> = config
        .pipes
        .iter()
        .filter(|p| p.capped)
        .flat_map(|p| {
            let (start, dir, length) = p.axis();
            let ends = [
                (start.coords, start.coords + dir * CAP_THICKNESS_M),
                (
                    start.coords + dir * (length - CAP_THICKNESS_M),
                    start.coords + dir * length,
                ),
            ];
            ends.map(|(a, b)| {
                let (pose, cylinder) = crate::geometry::solid::cylinder_between(&a, &b, p.radius_m);
                (pose, SharedShape::new(cylinder))
            })
        })
        .collect();
    if shapes.is_empty() {
        return None;
    }
    let albedo = vec![CAP_ALBEDO; shapes.len()];
    Some(std::sync::Arc::new(super::scene::Solids {
        compound: parry3d_f64::shape::Compound::new(shapes),
        albedo,
    }))
}

/// The reference irradiance for the exposure: the wall behind the pipe of interest.
#[must_use]
pub fn reference_irradiance(scene: &Scene) -> f64 {
    scene.irradiance(&Point3::new(0.0, 0.0, 1.45), &Vector3::y())
}

/// The camera path: an arc of ±55° around the pipe of interest at `path_radius_m`, left to
/// right in portrait then back in landscape, height swaying between 1.15 and 1.75 m, aimed at
/// points along the pipe.
#[must_use]
pub fn path(config: &SiteConfig, seed: u64) -> Vec<Station> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9B7);
    let p = config.interest();
    let centre = Point3::new(p.centre_x_m, p.wall_distance_m, p.height_m);
    let n = config.frames;
    let n_first = n.div_ceil(2);
    (0..n)
        .map(|k| {
            let (phase, orientation) = if k < n_first {
                (
                    k as f64 / (n_first.max(2) - 1) as f64,
                    Orientation::Portrait,
                )
            } else {
                (
                    1.0 - (k - n_first) as f64 / ((n - n_first).max(2) - 1) as f64,
                    Orientation::Landscape,
                )
            };
            let theta = (-55.0 + 110.0 * phase).to_radians();
            // The distance swings once in and out over each pass.
            let radius = config.path_radius_m
                + config.path_radius_spread_m * (std::f64::consts::TAU * phase).cos();
            let height = 1.45
                + 0.3
                    * (std::f64::consts::TAU * phase
                        + if orientation == Orientation::Portrait {
                            0.0
                        } else {
                            1.3
                        })
                    .sin();
            let eye = Point3::new(
                centre.x + radius * theta.sin() + rng.random_range(-0.03..0.03),
                p.wall_distance_m + radius * theta.cos() + rng.random_range(-0.03..0.03),
                height,
            );
            let target = centre
                + Vector3::new(
                    0.25 * theta.sin() + rng.random_range(-0.05..0.05),
                    0.0,
                    rng.random_range(-0.05..0.05),
                );
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

    #[test]
    fn default_site_has_three_standard_pipes_and_eight_targets() {
        let cfg = SiteConfig::default();
        cfg.validate().unwrap();
        let scene = build_scene(&cfg, 0.01, 1);
        assert_eq!(scene.cylinders.len(), 3);
        assert_eq!(scene.targets.len(), 8);
        assert_eq!(cfg.interest().radius_m, 0.057_15);
        let truth = cfg.pipe_truth();
        assert!(truth[1].of_interest && !truth[0].of_interest);
        // A ray from the path toward the pipe of interest's centre hits it at its radius.
        let stations = path(&cfg, 1);
        assert_eq!(stations.len(), 60);
        let eye = crate::geometry::pose::camera_centre(&stations[10].cam_from_world);
        let axis = Point3::new(eye.x, 0.45, 1.45);
        let hit = scene.intersect(&eye, &(axis - eye)).unwrap();
        let p = eye + (axis - eye) * hit.t;
        let d = ((p.y - 0.45).powi(2) + (p.z - 1.45).powi(2)).sqrt();
        assert!(
            (d - 0.057_15).abs() < 1e-12,
            "hit at distance {d} from the axis"
        );
    }
}
