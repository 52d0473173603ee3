//! The renderer: exact lens geometry per sample, adaptive supersampling, shading, then optical
//! blur, vignetting, sensor noise, 8-bit quantisation and optional JPEG.
//!
//! Every sample's pixel position is mapped to its ray through the *inverse* of the true camera
//! model (the ideal normalised coordinates of the pixel), so lens distortion is exact rather than
//! an image warp. The inverse is evaluated exactly (Newton) on a grid over the image and
//! interpolated between grid nodes; the grid spacing halves until the interpolation error at
//! cell centres is below [`MAX_RAY_ERROR_PX`].
//!
//! Adaptive sampling: radiance and a region id are computed at every pixel corner (shared
//! between neighbours) and centre. A pixel whose five probes all lie in one smooth region (same
//! surface, same target zone) takes their weighted mean (corners 1/8, centre 1/2); any other
//! pixel — an edge of a target, plate, pipe or wall passes through it — is integrated with
//! `samples × samples` stratified rays. An edge can slip past the five probes only by bulging
//! into a pixel through one side and out again: for a disc of radius R px the missed area is at
//! most the sagitta 1/(8R) times the chord, under 2 % of a pixel for R ≥ 5 px.
//!
//! Video frames ([`render_radiance_moving`]): every sample is taken through the pose of a
//! moving camera at its row's time within the exposure (rolling shutter, motion blur), with the
//! adaptive rule widened by the blur's displacement; without motion it is the still renderer
//! bit for bit.

use image::{DynamicImage, RgbImage};
use nalgebra::{Point3, Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::scene::Scene;
use crate::camera::BrownCamera;
use crate::geometry::Rigid3;
use crate::geometry::pose::camera_centre;

mod develop;
mod moving;

pub use develop::develop;
pub use moving::{MovingView, render_radiance_moving};

/// Largest interpolation error of pixel → ray allowed, in pixels.
pub const MAX_RAY_ERROR_PX: f64 = 1e-4;

/// Rendering options. Each effect can be switched off (0 or `None`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderConfig {
    /// Stratified samples per axis for pixels with an edge (default 4: 4×4).
    pub samples: u32,
    /// Adaptive sampling (default true); false supersamples every pixel.
    pub adaptive: bool,
    /// σ of the Gaussian point spread function in pixels (default 0.7; 0 = none).
    pub blur_sigma_px: f64,
    /// Read noise σ in 8-bit levels (DN) (default 1.0).
    pub read_noise_dn: f64,
    /// Shot noise: variance per DN of signal (default 0.02, σ ≈ 2.1 DN on white).
    pub shot_noise: f64,
    /// Relative brightness loss at the image corners, `1 − vignetting·(r/r_corner)²`
    /// (default 0.25).
    pub vignetting: f64,
    /// JPEG quality 1–100 for the written frames; `None` (default) writes lossless PNG.
    pub jpeg_quality: Option<u8>,
    /// Grey level (DN) of a white target lit by the reference irradiance (default 215).
    pub white_dn: f64,
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig {
            samples: 4,
            adaptive: true,
            blur_sigma_px: 0.7,
            read_noise_dn: 1.0,
            shot_noise: 0.02,
            vignetting: 0.25,
            jpeg_quality: None,
            white_dn: 215.0,
        }
    }
}

/// Why a render configuration is unusable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("render option `{field}`: {reason}")]
pub struct RenderConfigError {
    /// The option.
    pub field: &'static str,
    /// What is wrong.
    pub reason: String,
}

impl RenderConfig {
    /// Checks the values.
    ///
    /// # Errors
    ///
    /// [`RenderConfigError`] naming the first bad option.
    pub fn validate(&self) -> Result<(), RenderConfigError> {
        let bad = |field, reason: &str| {
            Err(RenderConfigError {
                field,
                reason: reason.into(),
            })
        };
        if !(1..=16).contains(&self.samples) {
            return bad("samples", "must be between 1 and 16");
        }
        for (field, v) in [
            ("blur_sigma_px", self.blur_sigma_px),
            ("read_noise_dn", self.read_noise_dn),
            ("shot_noise", self.shot_noise),
            ("vignetting", self.vignetting),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(field, "must be a finite value ≥ 0");
            }
        }
        if self.blur_sigma_px > 10.0 {
            return bad("blur_sigma_px", "must be at most 10 px");
        }
        if self.vignetting >= 1.0 {
            return bad("vignetting", "must be below 1");
        }
        if let Some(q) = self.jpeg_quality
            && !(1..=100).contains(&q)
        {
            return bad("jpeg_quality", "must be between 1 and 100");
        }
        if !(self.white_dn > 0.0 && self.white_dn <= 255.0) {
            return bad("white_dn", "must be in (0, 255]");
        }
        Ok(())
    }
}

/// Pixel → ideal normalised coordinates for one camera: exact at grid nodes, bilinear between.
#[derive(Clone, Debug)]
pub struct RayGrid {
    step: f64,
    cols: usize,
    grid: Vec<Vector2<f64>>,
    /// Largest interpolation error found at cell centres (px).
    pub error_px: f64,
}

impl RayGrid {
    /// Builds the grid for `camera`, covering the image and one grid cell beyond it.
    ///
    /// # Panics
    ///
    /// If the camera's distortion cannot be inverted over the image (the presets and any
    /// calibrated phone can).
    #[must_use]
    pub fn new(camera: &BrownCamera) -> Self {
        let c = camera.intrinsics.c;
        let exact = |u: f64, v: f64| {
            camera
                .intrinsics
                .ideal_from_pixel(&Vector2::new(u, v))
                .unwrap_or_else(|e| panic!("camera not invertible over the image: {e}"))
        };
        let mut step = 16.0;
        loop {
            let cols = (f64::from(camera.width) / step).ceil() as usize + 2;
            let rows = (f64::from(camera.height) / step).ceil() as usize + 2;
            let grid: Vec<Vector2<f64>> = (0..rows)
                .into_par_iter()
                .flat_map_iter(|r| (0..cols).map(move |col| (col, r)))
                .map(|(col, r)| exact(col as f64 * step, r as f64 * step))
                .collect();
            let g = RayGrid {
                step,
                cols,
                grid,
                error_px: 0.0,
            };
            let error_px = (0..rows - 1)
                .into_par_iter()
                .map(|r| {
                    (0..cols - 1)
                        .map(|col| {
                            let (u, v) = ((col as f64 + 0.5) * step, (r as f64 + 0.5) * step);
                            (g.ideal(u, v) - exact(u, v)).norm() * c
                        })
                        .fold(0.0, f64::max)
                })
                .reduce(|| 0.0, f64::max);
            if error_px <= MAX_RAY_ERROR_PX || step <= 0.25 {
                return RayGrid { error_px, ..g };
            }
            step /= 2.0;
        }
    }

    /// Ideal normalised coordinates of pixel position (u, v).
    #[must_use]
    pub fn ideal(&self, u: f64, v: f64) -> Vector2<f64> {
        let (gx, gy) = (u / self.step, v / self.step);
        let (c0, r0) = (gx.max(0.0) as usize, gy.max(0.0) as usize);
        let (c0, r0) = (
            c0.min(self.cols - 2),
            r0.min(self.grid.len() / self.cols - 2),
        );
        let (s, t) = (gx - c0 as f64, gy - r0 as f64);
        let at = |r: usize, c: usize| self.grid[r * self.cols + c];
        let top = at(r0, c0) + (at(r0, c0 + 1) - at(r0, c0)) * s;
        let bottom = at(r0 + 1, c0) + (at(r0 + 1, c0 + 1) - at(r0 + 1, c0)) * s;
        top + (bottom - top) * t
    }
}

/// A rendered frame: the 8-bit image as written, and the noise-free radiance (for tests).
#[derive(Clone, Debug)]
pub struct Frame {
    /// The frame as it is written (after JPEG round trip when JPEG is on).
    pub image: RgbImage,
    /// The encoded JPEG bytes, when JPEG is on.
    pub jpeg: Option<Vec<u8>>,
}

impl Frame {
    /// Writes the frame to `path` atomically: its JPEG bytes when JPEG is on, else a PNG.
    ///
    /// # Errors
    ///
    /// The file cannot be written.
    pub fn write(self, path: &std::path::Path) -> Result<(), crate::io::WriteError> {
        match &self.jpeg {
            Some(bytes) => crate::io::atomic::write_bytes_atomic(path, bytes),
            None => crate::io::frames::write_png(path, &DynamicImage::ImageRgb8(self.image)),
        }
    }
}

/// Mixes seed, frame and row into an RNG seed (SplitMix64 finaliser).
fn mix(a: u64, b: u64, c: u64) -> u64 {
    let mut z = a ^ b.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ c.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Rows of pixels rendered per parallel task.
const BAND_ROWS: usize = 8;

/// Renders the noise-free radiance image (before blur and noise), row-major.
#[must_use]
pub fn render_radiance(
    scene: &Scene,
    camera: &BrownCamera,
    rays: &RayGrid,
    cam_from_world: &Rigid3,
    config: &RenderConfig,
) -> Vec<f32> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let origin = camera_centre(cam_from_world);
    let world_from_cam = cam_from_world.rotation.inverse();
    let ray = |u: f64, v: f64| {
        let xy = rays.ideal(u, v);
        world_from_cam * Vector3::new(xy.x, xy.y, 1.0)
    };
    let n = config.samples as usize;
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w * BAND_ROWS)
        .enumerate()
        .for_each(|(band, rows)| {
            let row0 = band * BAND_ROWS;
            let nrows = rows.len() / w;
            // Probes at the pixel corners ((nrows + 1) × (w + 1)) and centres (nrows × w).
            let (mut corners, mut centres) = (Vec::new(), Vec::new());
            if config.adaptive {
                corners = (0..=nrows)
                    .flat_map(|r| (0..=w).map(move |c| (c, r)))
                    .map(|(c, r)| {
                        let (l, region) =
                            scene.radiance(&origin, &ray(c as f64, (row0 + r) as f64));
                        (l as f32, region)
                    })
                    .collect::<Vec<_>>();
                centres = (0..nrows)
                    .flat_map(|r| (0..w).map(move |c| (c, r)))
                    .map(|(c, r)| {
                        let (l, region) =
                            scene.radiance(&origin, &ray(c as f64 + 0.5, (row0 + r) as f64 + 0.5));
                        (l as f32, region)
                    })
                    .collect::<Vec<_>>();
            }
            for r in 0..nrows {
                for c in 0..w {
                    let uniform = config.adaptive && {
                        let region = centres[r * w + c].1;
                        let corner = |dr: usize, dc: usize| corners[(r + dr) * (w + 1) + c + dc].1;
                        corner(0, 0) == region
                            && corner(0, 1) == region
                            && corner(1, 0) == region
                            && corner(1, 1) == region
                    };
                    rows[r * w + c] = if uniform {
                        // Smooth region: the corners (1/8 each) and the centre (1/2).
                        let corner = |dr: usize, dc: usize| corners[(r + dr) * (w + 1) + c + dc].0;
                        (corner(0, 0) + corner(0, 1) + corner(1, 0) + corner(1, 1)) / 8.0
                            + centres[r * w + c].0 / 2.0
                    } else {
                        let mut s = 0.0;
                        for sy in 0..n {
                            for sx in 0..n {
                                let u = c as f64 + (sx as f64 + 0.5) / n as f64;
                                let v = (row0 + r) as f64 + (sy as f64 + 0.5) / n as f64;
                                s += scene.radiance(&origin, &ray(u, v)).0;
                            }
                        }
                        (s / (n * n) as f64) as f32
                    };
                }
            }
        });
    out
}

/// The exposure gain mapping a white target at irradiance `reference_irradiance` to
/// `config.white_dn`.
#[must_use]
pub fn exposure_gain(config: &RenderConfig, reference_irradiance: f64) -> f64 {
    config.white_dn / (super::scene::WHITE_ALBEDO * reference_irradiance)
}

/// Renders one frame end to end.
///
/// # Errors
///
/// As [`develop`].
pub fn render_frame(
    scene: &Scene,
    camera: &BrownCamera,
    rays: &RayGrid,
    cam_from_world: &Rigid3,
    gain: f64,
    config: &RenderConfig,
    seed: u64,
    frame: u64,
) -> Result<Frame, image::ImageError> {
    let radiance = render_radiance(scene, camera, rays, cam_from_world, config);
    develop(radiance, camera, gain, config, seed, frame)
}

/// Renders one frame of a moving camera end to end ([`render_radiance_moving`], then
/// [`develop`]).
///
/// # Errors
///
/// As [`develop`].
pub fn render_frame_moving(
    scene: &Scene,
    view: &MovingView<'_>,
    gain: f64,
    config: &RenderConfig,
    seed: u64,
    frame: u64,
) -> Result<Frame, image::ImageError> {
    let radiance = render_radiance_moving(scene, view, config, seed, frame);
    develop(radiance, view.camera, gain, config, seed, frame)
}

/// The world point where the ray through pixel `uv` meets the scene (for tests and truth).
#[must_use]
pub fn surface_point(
    scene: &Scene,
    camera: &BrownCamera,
    cam_from_world: &Rigid3,
    uv: &Vector2<f64>,
) -> Option<Point3<f64>> {
    let xy = camera.intrinsics.ideal_from_pixel(uv).ok()?;
    let origin = camera_centre(cam_from_world);
    let dir = cam_from_world.rotation.inverse() * Vector3::new(xy.x, xy.y, 1.0);
    scene.intersect(&origin, &dir).map(|h| origin + dir * h.t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use crate::sim::scene::{Polarity, Rect};
    use crate::sim::shutter::{PoseTable, Shutter};
    use crate::sim::texture::Texture;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn setup() -> (Scene, BrownCamera, Rigid3) {
        let mut scene = Scene {
            rects: vec![Rect::new(
                "wall",
                Point3::new(-2.0, 0.0, -2.0),
                Vector3::x(),
                Vector3::z(),
                (4.0, 4.0),
                Texture::constant(0.5),
            )],
            ambient: 1.0,
            ..Default::default()
        };
        scene.place_targets(0, vec![(2.0, 2.0, 0.1, 0.2, Polarity::BlackOnWhite)]);
        let camera = BrownCamera {
            width: 160,
            height: 120,
            intrinsics: Intrinsics {
                k1: 0.05,
                ..Intrinsics::pinhole(150.0, 81.0, 59.5)
            },
        };
        // Camera 2 m in front of the wall (y = −2) looking along +y with image y down = −z.
        let world_from_cam = Isometry3::from_parts(
            Translation3::new(0.0, -2.0, 0.0),
            UnitQuaternion::from_basis_unchecked(&[Vector3::x(), -Vector3::z(), Vector3::y()]),
        );
        (scene, camera, world_from_cam.inverse())
    }

    #[test]
    fn ray_grid_meets_its_error_bound() {
        let (_, camera, _) = setup();
        let g = RayGrid::new(&camera);
        assert!(g.error_px <= MAX_RAY_ERROR_PX);
        let exact = camera
            .intrinsics
            .ideal_from_pixel(&Vector2::new(33.3, 77.7))
            .unwrap();
        assert!((g.ideal(33.3, 77.7) - exact).norm() * 150.0 < 1e-3);
    }

    #[test]
    fn adaptive_and_full_supersampling_agree() {
        let (scene, camera, pose) = setup();
        let rays = RayGrid::new(&camera);
        let adaptive = render_radiance(&scene, &camera, &rays, &pose, &RenderConfig::default());
        let full = render_radiance(
            &scene,
            &camera,
            &rays,
            &pose,
            &RenderConfig {
                adaptive: false,
                ..Default::default()
            },
        );
        // Uniform regions are constant here (constant albedo, ambient light): identical up to
        // f32 rounding; edge pixels are rendered the same way in both.
        let worst = adaptive
            .iter()
            .zip(&full)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "worst difference {worst}");
        // The disc (albedo 0.04) covers the centre; the plate (0.88) surrounds it.
        assert!((adaptive[60 * 160 + 81] - 0.04).abs() < 1e-6);
    }

    #[test]
    fn noise_is_seeded_and_frames_are_deterministic() {
        let (scene, camera, pose) = setup();
        let rays = RayGrid::new(&camera);
        let cfg = RenderConfig::default();
        let a = render_frame(&scene, &camera, &rays, &pose, 200.0, &cfg, 1, 3).unwrap();
        let b = render_frame(&scene, &camera, &rays, &pose, 200.0, &cfg, 1, 3).unwrap();
        let c = render_frame(&scene, &camera, &rays, &pose, 200.0, &cfg, 2, 3).unwrap();
        assert_eq!(a.image, b.image);
        assert_ne!(a.image, c.image);
        // Noise level on the flat plate: σ² = 1 + 0.02·DN.
        let cfg_nb = RenderConfig {
            blur_sigma_px: 0.0,
            vignetting: 0.0,
            ..cfg
        };
        let f = render_frame(&scene, &camera, &rays, &pose, 200.0, &cfg_nb, 9, 0).unwrap();
        let vals: Vec<f64> = (5..25)
            .flat_map(|y| (5..40).map(move |x| (x, y)))
            .map(|(x, y)| f64::from(f.image.get_pixel(x, y).0[0]))
            .collect();
        let mean = vals.iter().sum::<f64>() / vals.len() as f64;
        let sd =
            (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (vals.len() - 1) as f64).sqrt();
        let expected = (1.0 + 0.02 * 100.0f64).sqrt(); // wall albedo 0.5 × gain 200 = 100 DN
        assert!((mean - 100.0).abs() < 0.5, "mean {mean}");
        assert!((sd / expected - 1.0).abs() < 0.15, "σ {sd} vs {expected}");
    }

    #[test]
    fn moving_renderer_without_motion_is_the_still_renderer_bit_for_bit() {
        let (scene, camera, pose) = setup();
        let rays = RayGrid::new(&camera);
        let poses = PoseTable::fixed(&pose);
        let view = MovingView {
            camera: &camera,
            rays: &rays,
            ray_scale: 1.0,
            poses: &poses,
            shutter: Shutter::global(3.0),
        };
        for adaptive in [true, false] {
            let cfg = RenderConfig {
                adaptive,
                ..Default::default()
            };
            let still = render_radiance(&scene, &camera, &rays, &pose, &cfg);
            let moving = render_radiance_moving(&scene, &view, &cfg, 1, 2);
            assert!(still == moving, "adaptive {adaptive}: the renderers differ");
        }
    }

    /// A disc of radius 0.5 m, 2 m in front of a pinhole camera (c = 300 px, 320×240; the
    /// disc 75 px in radius, its plate 1.5× wider), seen while the camera turns about its y
    /// axis at `omega` rad/s (a pan): the pose at time t.
    fn panning(omega: f64) -> (Scene, BrownCamera, impl Fn(f64) -> Rigid3) {
        let mut scene = Scene {
            rects: vec![Rect::new(
                "wall",
                Point3::new(-3.0, 0.0, -3.0),
                Vector3::x(),
                Vector3::z(),
                (6.0, 6.0),
                Texture::constant(0.5),
            )],
            ambient: 1.0,
            ..Default::default()
        };
        scene.place_targets(0, vec![(3.0, 3.0, 0.5, 0.75, Polarity::BlackOnWhite)]);
        let camera = BrownCamera {
            width: 320,
            height: 240,
            intrinsics: Intrinsics::pinhole(300.0, 160.0, 120.0),
        };
        let centre = Vector3::new(0.0, -2.0, 0.0);
        let r0 = UnitQuaternion::from_basis_unchecked(&[Vector3::x(), -Vector3::z(), Vector3::y()])
            .inverse();
        let pose = move |t: f64| {
            let rotation = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, omega * t, 0.0)) * r0;
            Rigid3::from_parts(Translation3::from(-(rotation * centre)), rotation)
        };
        (scene, camera, pose)
    }

    /// Area fraction of the disc in each pixel of row r (radiance 0.88 on the plate, 0.04 on
    /// the disc, lit by the ambient light only).
    fn disc_fraction(img: &[f32], w: usize, r: usize) -> Vec<f64> {
        img[r * w..(r + 1) * w]
            .iter()
            .map(|&l| ((0.88 - f64::from(l)) / (0.88 - 0.04)).clamp(0.0, 1.0))
            .collect()
    }

    /// Where the exact image of the disc at `pose` (a conic of the pinhole camera) crosses the
    /// row at height v: (left, right).
    fn conic_row(camera: &BrownCamera, pose: &Rigid3, v: f64) -> (f64, f64) {
        let k = camera.intrinsics.pinhole_matrix();
        let c = crate::geometry::conic::conic_of_circle(
            &k,
            pose,
            &Vector3::zeros(),
            &-Vector3::y(),
            0.5,
        )
        .unwrap();
        let (a, b, cc) = (
            c[(0, 0)],
            2.0 * (c[(0, 1)] * v + c[(0, 2)]),
            c[(1, 1)] * v * v + 2.0 * c[(1, 2)] * v + c[(2, 2)],
        );
        let d = (b * b - 4.0 * a * cc).sqrt();
        let (x1, x2) = ((-b - d) / (2.0 * a), (-b + d) / (2.0 * a));
        (x1.min(x2), x1.max(x2))
    }

    #[test]
    fn rolling_shutter_shears_a_disc_as_the_row_timing_predicts() {
        let omega = 2.0;
        let (scene, camera, pose) = panning(omega);
        let rays = RayGrid::new(&camera);
        let shutter = Shutter {
            time_s: 0.0,
            readout_s: 0.03,
            exposure_s: 0.0,
        };
        let (t0, t1) = shutter.span();
        let poses = PoseTable::new(&pose, t0, t1);
        let view = MovingView {
            camera: &camera,
            rays: &rays,
            ray_scale: 1.0,
            poses: &poses,
            shutter,
        };
        // 16×16 samples per edge pixel: the area fraction of a pixel to 1/256.
        let cfg = RenderConfig {
            samples: 16,
            ..Default::default()
        };
        let img = render_radiance_moving(&scene, &view, &cfg, 1, 0);
        let (w, mid) = (320usize, 160usize);
        let (mut rs_sq, mut gs_sq, mut rows) = (0.0, 0.0, 0);
        // Rows within 0.8 of the disc's radius of its centre row (120): the edge is steep there.
        for r in 60..180 {
            let f = disc_fraction(&img, w, r);
            // Left edge: the disc fills [u_left, mid) of the plate's columns left of the
            // middle (the plate spans 48–272 px, ±9 px with the shear; the wall beyond it).
            let left = mid as f64 - f[mid - 100..mid].iter().sum::<f64>();
            let right = mid as f64 + f[mid..mid + 100].iter().sum::<f64>();
            let v = r as f64 + 0.5;
            let at_row = conic_row(&camera, &pose(shutter.row_time(v, 240)), v);
            let at_frame = conic_row(&camera, &pose(0.0), v);
            for (m, e, g) in [(left, at_row.0, at_frame.0), (right, at_row.1, at_frame.1)] {
                rs_sq += (m - e).powi(2);
                gs_sq += (m - g).powi(2);
            }
            rows += 2;
        }
        let (rs, gs) = (
            (rs_sq / f64::from(rows)).sqrt(),
            (gs_sq / f64::from(rows)).sqrt(),
        );
        // The pan moves the image by ω·c ≈ 600 px/s; the rows 60 px from the middle are read
        // 7.5 ms from the frame time: ±4.5 px of shear.
        println!(
            "edges vs rolling-shutter prediction {rs:.5} px RMS, vs frame-time disc {gs:.3} px"
        );
        assert!(gs > 2.0, "shear against the frame-time disc {gs} px RMS");
        // Edge positions are area fractions over the row, sampled to 1/256 px·px: a few
        // thousandths of a pixel, plus the curvature of the edge within the row (< 0.004 px).
        assert!(
            rs < 0.01,
            "edges against the rolling-shutter prediction {rs} px RMS"
        );
    }

    #[test]
    fn motion_blur_widens_an_edge_by_the_image_speed_times_the_exposure() {
        let omega = 1.0;
        let (scene, camera, pose) = panning(omega);
        let rays = RayGrid::new(&camera);
        let cfg = RenderConfig {
            samples: 16,
            ..Default::default()
        };
        let width_25_75 = |exposure_s: f64| {
            let shutter = Shutter {
                time_s: 0.0,
                readout_s: 0.0,
                exposure_s,
            };
            let (t0, t1) = shutter.span();
            let poses = PoseTable::new(&pose, t0, t1);
            let view = MovingView {
                camera: &camera,
                rays: &rays,
                ray_scale: 1.0,
                poses: &poses,
                shutter,
            };
            let img = render_radiance_moving(&scene, &view, &cfg, 3, 0);
            let mut widths = Vec::new();
            for r in 115..125 {
                let f = disc_fraction(&img, 320, r);
                // Crossing of level `q` along the left edge, between pixel centres.
                let cross = |q: f64| {
                    let c = (60..160).find(|&c| f[c] >= q).unwrap();
                    c as f64 - 1.0 + (q - f[c - 1]) / (f[c] - f[c - 1]) + 0.5
                };
                widths.push(cross(0.75) - cross(0.25));
            }
            widths.iter().sum::<f64>() / widths.len() as f64
        };
        // The edge point seen at mid-exposure, projected at the start and the end.
        let exposure = 0.02;
        let edge = Vector3::new(-0.5, 0.0, 0.0);
        let smear = (camera.project_world(&pose(exposure / 2.0), &edge).unwrap()
            - camera.project_world(&pose(-exposure / 2.0), &edge).unwrap())
        .norm();
        assert!((6.0..7.0).contains(&smear), "smear {smear} px");
        // A box of `smear` px convolved with the 1 px pixel: a trapezoid whose 25–75 % width
        // is smear/2 (smear ≥ 2 px).
        let blurred = width_25_75(exposure);
        println!(
            "smear {smear:.4} px: 25-75 % width {blurred:.4} px (expected {:.4})",
            smear / 2.0
        );
        assert!(
            (blurred / (smear / 2.0) - 1.0).abs() < 0.03,
            "25–75 % width {blurred} px, expected {} px",
            smear / 2.0
        );
        let sharp = width_25_75(0.0);
        assert!(
            sharp < 0.6,
            "without exposure the edge is sharp: {sharp} px"
        );
    }

    #[test]
    fn adaptive_sampling_stays_exact_under_motion_blur() {
        // Constant albedo and ambient light: smooth regions are constant, so the adaptive and
        // the full rendering differ only where the adaptive rule took an edge pixel for smooth.
        let (scene, camera, pose) = panning(1.5);
        let rays = RayGrid::new(&camera);
        let shutter = Shutter {
            time_s: 0.0,
            readout_s: 0.03,
            exposure_s: 0.02,
        };
        let (t0, t1) = shutter.span();
        let poses = PoseTable::new(&pose, t0, t1);
        let view = MovingView {
            camera: &camera,
            rays: &rays,
            ray_scale: 1.0,
            poses: &poses,
            shutter,
        };
        let adaptive = render_radiance_moving(&scene, &view, &RenderConfig::default(), 1, 0);
        let full = render_radiance_moving(
            &scene,
            &view,
            &RenderConfig {
                adaptive: false,
                ..Default::default()
            },
            1,
            0,
        );
        let worst = adaptive
            .iter()
            .zip(&full)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        println!("adaptive vs full under blur: worst {worst}");
        assert!(worst < 1e-5, "worst difference {worst}");
        // The smear (9 px) is real: many pixels inside the plate are partly disc.
        let partial = (40..200)
            .flat_map(|r| (70..250).map(move |c| r * 320 + c))
            .filter(|&k| full[k] > 0.05 && full[k] < 0.87)
            .count();
        assert!(partial > 1500, "{partial} blurred pixels");
    }

    #[test]
    fn focus_breathing_scales_the_image_about_the_principal_point() {
        // The same still camera with c 1 % longer, rendered through the grid of the shorter
        // camera (ray_scale), sees the disc 1 % larger about the principal point.
        let (scene, camera, pose) = panning(0.0);
        let longer = BrownCamera {
            intrinsics: Intrinsics {
                c: 303.0,
                ..camera.intrinsics
            },
            ..camera
        };
        let rays = RayGrid::new(&camera);
        let own = RayGrid::new(&longer);
        let poses = PoseTable::fixed(&pose(0.0));
        let cfg = RenderConfig {
            samples: 16,
            ..Default::default()
        };
        let scaled = render_radiance_moving(
            &scene,
            &MovingView {
                camera: &longer,
                rays: &rays,
                ray_scale: 300.0 / 303.0,
                poses: &poses,
                shutter: Shutter::global(0.0),
            },
            &cfg,
            1,
            0,
        );
        let direct = render_radiance(&scene, &longer, &own, &pose(0.0), &cfg);
        let worst = scaled
            .iter()
            .zip(&direct)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        // Same rays up to the grid's interpolation (≤ 1e-4 px): edge pixels differ by at most
        // a sample or two of 256 (0.84/256 each).
        assert!(worst < 0.008, "worst difference {worst}");
        let width = |img: &[f32]| -> f64 { disc_fraction(img, 320, 120)[60..260].iter().sum() };
        assert!(
            (width(&scaled) / 150.0 - 1.01).abs() < 1e-3,
            "disc width {} px",
            width(&scaled)
        );
    }

    #[test]
    fn config_validation_names_the_option() {
        let e = RenderConfig {
            samples: 0,
            ..Default::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(e.field, "samples");
        let e = RenderConfig {
            jpeg_quality: Some(0),
            ..Default::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(e.field, "jpeg_quality");
        assert!(RenderConfig::default().validate().is_ok());
    }
}
