//! Rendering a frame from a moving camera: every row at its own time (rolling shutter) and,
//! with an exposure, the radiance averaged over the row's exposure (motion blur), through a
//! coarse grid of the image motion between the row's times.

use nalgebra::{Point3, Vector2, Vector3};
use rayon::prelude::*;

use super::develop::bilinear;
use super::{BAND_ROWS, RayGrid, RenderConfig, mix};
use crate::camera::BrownCamera;
use crate::sim::scene::Scene;
use crate::sim::shutter::{PoseTable, Shutter};

/// A frame of a moving camera: what [`render_radiance_moving`] needs besides the scene.
#[derive(Clone, Copy, Debug)]
pub struct MovingView<'a> {
    /// The frame's true camera (under focus breathing, its principal distance for this
    /// frame).
    pub camera: &'a BrownCamera,
    /// Pixel → ray grid of a camera equal to `camera` but with c, b1 and b2 multiplied by
    /// `ray_scale` (one grid serves every frame of a breathing sequence).
    pub rays: &'a RayGrid,
    /// See `rays`; exactly 1 when the grid is `camera`'s own.
    pub ray_scale: f64,
    /// The camera's poses over the frame's exposure.
    pub poses: &'a PoseTable,
    /// Row timing: rolling-shutter readout and exposure.
    pub shutter: Shutter,
}

impl MovingView<'_> {
    /// Ideal normalised coordinates of pixel position (u, v) of `camera`: the pixel offsets
    /// from the principal point scale with c (and b1, b2), the normalised distortion does not.
    fn ideal(&self, u: f64, v: f64) -> Vector2<f64> {
        if self.ray_scale == 1.0 {
            return self.rays.ideal(u, v);
        }
        let i = &self.camera.intrinsics;
        self.rays.ideal(
            i.u0 + (u - i.u0) * self.ray_scale,
            i.v0 + (v - i.v0) * self.ray_scale,
        )
    }

    /// The ray (origin, direction in the world) of pixel position (u, v) at time t.
    fn ray(&self, u: f64, v: f64, t: f64) -> (Point3<f64>, Vector3<f64>) {
        let xy = self.ideal(u, v);
        let (origin, world_from_cam) = self.poses.at(t);
        (origin, world_from_cam * Vector3::new(xy.x, xy.y, 1.0))
    }
}

/// Spacing of the nodes where the moving renderer measures the motion blur's displacement
/// (px).
const DISPLACEMENT_GRID_PX: usize = 32;
/// Region id marking a pixel whose probes disagree (never a scene region: those are built
/// from small surface and target indices).
const NOT_UNIFORM: u64 = u64::MAX;

/// A SplitMix64 stream (Steele, Lea & Flood, "Fast splittable pseudorandom number
/// generators", OOPSLA 2014): per-pixel sample jitter without seeding a ChaCha generator.
struct SplitMix(u64);

impl SplitMix {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Renders the noise-free radiance image of a moving rolling-shutter camera, row-major.
///
/// Every sample at pixel position (u, v) is taken at its row's time `t(v)` (see
/// [`crate::sim::shutter`]) plus an offset within the exposure, through the pose at that time. The
/// adaptive rule of [`super::render_radiance`] is kept correct under motion blur:
///
/// 1. the five probes of each pixel are taken at the middle of its rows' exposures;
/// 2. on a grid of nodes every 32 px, the scene point seen at mid-exposure is projected at the
///    start and the end of the exposure: the blur displacement `d` (px), interpolated
///    bilinearly between nodes;
/// 3. a pixel is smooth only when every pixel within `⌈max|d_u|/2⌉ + 1` columns and
///    `⌈max|d_v|/2⌉ + 1` rows of it (the largest displacements of the four surrounding nodes
///    along u and v, plus the interpolation's support) has uniform probes of the same region:
///    no edge reaches it during the exposure. Its value is the mid-exposure image averaged
///    along the segment `±d/2`, sampled at most 1 px apart (the motion blur of a smooth
///    region, to first order in the exposure); with no exposure it is exactly the five-probe
///    value;
/// 4. every other pixel — an edge is in it at some time of the exposure — takes
///    `samples × samples` rays at the stratified positions of [`super::render_radiance`], each at a
///    time from its own stratum of the exposure (the strata shuffled per pixel, jittered
///    within; seeded by `(seed, frame, pixel)`).
///
/// With a fixed pose table and no readout or exposure the output is bit for bit that of
/// [`super::render_radiance`].
///
/// Kept whole (one function over 150 lines): the hot loop over row bands, whose closures share
/// the displacement grid, the pose table and the band buffers; a split would pass them all
/// through.
#[must_use]
pub fn render_radiance_moving(
    scene: &Scene,
    view: &MovingView<'_>,
    config: &RenderConfig,
    seed: u64,
    frame: u64,
) -> Vec<f32> {
    let camera = view.camera;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let shutter = view.shutter;
    let row_time = |v: f64| shutter.row_time(v, camera.height);
    // 1. Mid-exposure probes: the five-probe value and the region of uniform pixels.
    let mut base = vec![0f32; w * h];
    let mut ids = vec![NOT_UNIFORM; w * h];
    if config.adaptive {
        base.par_chunks_mut(w * BAND_ROWS)
            .zip(ids.par_chunks_mut(w * BAND_ROWS))
            .enumerate()
            .for_each(|(band, (rows, row_ids))| {
                let row0 = band * BAND_ROWS;
                let nrows = rows.len() / w;
                let probe_row = |v: f64, offset: f64, count: usize| {
                    let (origin, world_from_cam) = view.poses.at(row_time(v));
                    (0..count)
                        .map(|c| {
                            let xy = view.ideal(c as f64 + offset, v);
                            let dir = world_from_cam * Vector3::new(xy.x, xy.y, 1.0);
                            let (l, region) = scene.radiance(&origin, &dir);
                            (l as f32, region)
                        })
                        .collect::<Vec<_>>()
                };
                let corners: Vec<Vec<(f32, u64)>> = (0..=nrows)
                    .map(|r| probe_row((row0 + r) as f64, 0.0, w + 1))
                    .collect();
                let centres: Vec<Vec<(f32, u64)>> = (0..nrows)
                    .map(|r| probe_row((row0 + r) as f64 + 0.5, 0.5, w))
                    .collect();
                for r in 0..nrows {
                    for c in 0..w {
                        let corner = |dr: usize, dc: usize| corners[r + dr][c + dc];
                        let (centre, region) = centres[r][c];
                        if [corner(0, 0), corner(0, 1), corner(1, 0), corner(1, 1)]
                            .iter()
                            .all(|p| p.1 == region)
                        {
                            rows[r * w + c] =
                                (corner(0, 0).0 + corner(0, 1).0 + corner(1, 0).0 + corner(1, 1).0)
                                    / 8.0
                                    + centre / 2.0;
                            row_ids[r * w + c] = region;
                        }
                    }
                }
            });
    }
    // 2. Blur displacement over the exposure at grid nodes.
    let g = DISPLACEMENT_GRID_PX;
    let (gx, gy) = (w.div_ceil(g) + 1, h.div_ceil(g) + 1);
    let node = |i: usize, j: usize| ((i * g).min(w) as f64, (j * g).min(h) as f64);
    let displacement: Vec<Vector2<f64>> = if shutter.exposure_s > 0.0 {
        (0..gx * gy)
            .into_par_iter()
            .map(|k| {
                let (u, v) = node(k % gx, k / gx);
                let t = row_time(v);
                let (origin, dir) = view.ray(u, v, t);
                let depth = scene.intersect(&origin, &dir).map_or(1e3, |hit| hit.t);
                let p = origin + dir * depth;
                let at = |dt: f64| {
                    let (o, world_from_cam) = view.poses.at(t + dt);
                    camera
                        .intrinsics
                        .project(&(world_from_cam.inverse() * (p - o)))
                };
                match (at(-shutter.exposure_s / 2.0), at(shutter.exposure_s / 2.0)) {
                    (Some(a), Some(b)) => b - a,
                    // Behind the camera at one end: treat as an edge everywhere around.
                    _ => Vector2::new(f64::from(u16::MAX), 0.0),
                }
            })
            .collect()
    } else {
        vec![Vector2::zeros(); gx * gy]
    };
    // Runs of equal regions along each row, for the neighbourhood test of step 3.
    let mut runs = vec![(0u16, 0u16); w * h];
    runs.par_chunks_mut(w)
        .zip(ids.par_chunks(w))
        .for_each(|(run, id)| {
            for c in 1..w {
                if id[c] == id[c - 1] {
                    run[c].0 = run[c - 1].0.saturating_add(1);
                }
            }
            for c in (0..w - 1).rev() {
                if id[c] == id[c + 1] {
                    run[c].1 = run[c + 1].1.saturating_add(1);
                }
            }
        });
    // 3 and 4. The neighbourhood a pixel's exposure reaches, per grid cell: half the largest
    // displacement of the cell's nodes along u and along v, plus the bilinear support.
    let reach = |d: f64| {
        if d > 0.0 {
            (d / 2.0).ceil() as usize + 1
        } else {
            0
        }
    };
    let cells: Vec<(usize, usize)> = (0..(gx - 1) * (gy - 1))
        .map(|k| {
            let (i, j) = (k % (gx - 1), k / (gx - 1));
            let corners = [
                displacement[j * gx + i],
                displacement[j * gx + i + 1],
                displacement[(j + 1) * gx + i],
                displacement[(j + 1) * gx + i + 1],
            ];
            let du = corners.iter().map(|d| d.x.abs()).fold(0.0, f64::max);
            let dv = corners.iter().map(|d| d.y.abs()).fold(0.0, f64::max);
            (reach(du), reach(dv))
        })
        .collect();
    let n = config.samples as usize;
    let nn = n * n;
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(r, line)| {
        let v_centre = r as f64 + 0.5;
        let (j, fy) = {
            let y = v_centre / g as f64;
            let j = (y as usize).min(gy - 2);
            (j, y - j as f64)
        };
        for (c, value) in line.iter_mut().enumerate() {
            let u_centre = c as f64 + 0.5;
            let x = u_centre / g as f64;
            let i = (x as usize).min(gx - 2);
            let (reach_u, reach_v) = cells[j * (gx - 1) + i];
            let id = ids[r * w + c];
            if id != NOT_UNIFORM && reach_u == 0 && reach_v == 0 {
                // No blur here: the five-probe value.
                *value = base[r * w + c];
                continue;
            }
            let smooth = id != NOT_UNIFORM && {
                let (left, right) = (reach_u.min(c), reach_u.min(w - 1 - c));
                (r.saturating_sub(reach_v)..=(r + reach_v).min(h - 1)).all(|rr| {
                    let k = rr * w + c;
                    ids[k] == id
                        && usize::from(runs[k].0) >= left
                        && usize::from(runs[k].1) >= right
                })
            };
            let fx = x - i as f64;
            let at = |di: usize, dj: usize| displacement[(j + dj) * gx + i + di];
            let d = (at(0, 0) * (1.0 - fx) + at(1, 0) * fx) * (1.0 - fy)
                + (at(0, 1) * (1.0 - fx) + at(1, 1) * fx) * fy;
            *value = if smooth {
                // The mid-exposure image averaged along ±d/2 (midpoint rule, samples at most
                // 1 px apart: the texture is already smoothed by the 0.7 px optical blur).
                let count = (d.norm().ceil() as usize).max(1);
                let mut s = 0f32;
                for k in 0..count {
                    let p = d * ((k as f64 + 0.5) / count as f64 - 0.5);
                    s += bilinear(&base, w, h, c as f64 + p.x, r as f64 + p.y);
                }
                s / count as f32
            } else {
                let mut rng = SplitMix(mix(seed ^ 0x5EED_B1A5, frame, (r * w + c) as u64));
                let mut strata = [0u16; 256];
                for (k, s) in strata.iter_mut().enumerate().take(nn) {
                    *s = k as u16;
                }
                for k in (1..nn).rev() {
                    let other = (rng.next_u64() % (k as u64 + 1)) as usize;
                    strata.swap(k, other);
                }
                let mut s = 0.0;
                for sy in 0..n {
                    for sx in 0..n {
                        let u = c as f64 + (sx as f64 + 0.5) / n as f64;
                        let v = r as f64 + (sy as f64 + 0.5) / n as f64;
                        let tau = (f64::from(strata[sy * n + sx]) + rng.next_f64()) / nn as f64;
                        let t = row_time(v) + shutter.exposure_s * (tau - 0.5);
                        let (origin, dir) = view.ray(u, v, t);
                        s += scene.radiance(&origin, &dir).0;
                    }
                }
                (s / nn as f64) as f32
            };
        }
    });
    out
}
