//! Procedural surface textures: multi-scale (fractal value noise over several octaves),
//! non-repeating (hashed lattice, seeded), baked once per surface into a raster so that rendering
//! costs one bilinear lookup per ray. They give SIFT-style features to COLMAP and to the
//! simulated dense matching.

use rayon::prelude::*;

/// A grey albedo raster over a rectangle `size_m.0 × size_m.1` (metres), bilinearly sampled.
#[derive(Clone, Debug)]
pub struct Texture {
    cols: usize,
    rows: usize,
    texel_m: f64,
    /// Albedo × 255.
    data: Vec<u8>,
    /// Set for constant textures (exact albedo).
    constant: Option<f64>,
}

/// How a texture looks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureStyle {
    /// Mean albedo (0–1).
    pub mean: f64,
    /// Albedo amplitude of the coarsest octave.
    pub contrast: f64,
    /// Wavelength of the coarsest octave (m).
    pub coarsest_m: f64,
    /// Amplitude ratio between successive octaves (wavelength halves each time).
    pub persistence: f64,
}

impl TextureStyle {
    /// Painted plaster with stains and speckle: the calibration lab's walls.
    pub const WALL: TextureStyle = TextureStyle {
        mean: 0.55,
        contrast: 0.34,
        coarsest_m: 0.6,
        persistence: 0.8,
    };
    /// Concrete floor.
    pub const FLOOR: TextureStyle = TextureStyle {
        mean: 0.45,
        contrast: 0.3,
        coarsest_m: 0.4,
        persistence: 0.75,
    };
    /// Ceiling: bright and faint.
    pub const CEILING: TextureStyle = TextureStyle {
        mean: 0.75,
        contrast: 0.12,
        coarsest_m: 0.5,
        persistence: 0.75,
    };
    /// Painted steel pipe: weaker texture.
    pub const PIPE: TextureStyle = TextureStyle {
        mean: 0.6,
        contrast: 0.22,
        coarsest_m: 0.15,
        persistence: 0.75,
    };
}

/// Random blobs painted over a texture ([`Texture::bake_speckled`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Speckle {
    /// Blobs per square metre.
    pub per_m2: f64,
    /// Smallest blob radius (m).
    pub min_radius_m: f64,
    /// Largest blob radius (m).
    pub max_radius_m: f64,
    /// Largest albedo shift of a blob (its sign and 40–100 % of it drawn per blob).
    pub contrast: f64,
    /// Largest relative deviation of a blob's outline from a circle.
    pub irregularity: f64,
}

impl Speckle {
    /// A wall sprayed and stamped for SfM: blobs of 3–40 mm radius — the targets' sizes —,
    /// a dozen per square decimetre, of either sign, from nearly round to lumpy.
    pub const WALL: Speckle = Speckle {
        per_m2: 1200.0,
        min_radius_m: 0.003,
        max_radius_m: 0.04,
        contrast: 0.35,
        irregularity: 0.3,
    };
}

/// A 64-bit mix (SplitMix64's finaliser) of the seed and lattice coordinates.
fn hash(seed: u64, x: i64, y: i64) -> u64 {
    let mut z = seed
        ^ (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Lattice value in [−1, 1].
fn lattice(seed: u64, x: i64, y: i64) -> f64 {
    (hash(seed, x, y) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

/// Quintic fade (C2-continuous value noise).
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Smooth value noise in [−1, 1] at (x, y) in lattice units; with `period > 0` the lattice
/// wraps in x every `period` cells (seamless around a pipe).
fn value_noise(seed: u64, x: f64, y: f64, period: i64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (ix, iy) = (x0 as i64, y0 as i64);
    let (fx, fy) = (fade(x - x0), fade(y - y0));
    let wrap = |i: i64| if period > 0 { i.rem_euclid(period) } else { i };
    let v00 = lattice(seed, wrap(ix), iy);
    let v10 = lattice(seed, wrap(ix + 1), iy);
    let v01 = lattice(seed, wrap(ix), iy + 1);
    let v11 = lattice(seed, wrap(ix + 1), iy + 1);
    let top = v00 + fx * (v10 - v00);
    let bottom = v01 + fx * (v11 - v01);
    top + fy * (bottom - top)
}

impl Texture {
    /// Bakes a texture of `size_m` with texels of `texel_m`, octaves from `style.coarsest_m`
    /// down to two texels, seeded.
    #[must_use]
    pub fn bake(size_m: (f64, f64), texel_m: f64, style: TextureStyle, seed: u64) -> Self {
        Self::bake_with(size_m, texel_m, style, seed, false)
    }

    /// As [`Texture::bake`], but seamless across `a = 0 ≡ size_m.0` (for wrapping around a
    /// cylinder): each octave's wavelength is adjusted so that a whole number of cells spans the
    /// width.
    #[must_use]
    pub fn bake_periodic(size_m: (f64, f64), texel_m: f64, style: TextureStyle, seed: u64) -> Self {
        Self::bake_with(size_m, texel_m, style, seed, true)
    }

    fn bake_with(
        size_m: (f64, f64),
        texel_m: f64,
        style: TextureStyle,
        seed: u64,
        periodic: bool,
    ) -> Self {
        let cols = (size_m.0 / texel_m).ceil() as usize + 2;
        let rows = (size_m.1 / texel_m).ceil() as usize + 2;
        let mut octaves = Vec::new();
        let (mut wavelength, mut amp) = (style.coarsest_m, style.contrast);
        let mut k = 0u64;
        while wavelength >= 2.0 * texel_m {
            let (w, period) = if periodic {
                let cells = (size_m.0 / wavelength).round().max(1.0);
                (size_m.0 / cells, cells as i64)
            } else {
                (wavelength, 0)
            };
            octaves.push((w, amp, hash(seed, k as i64, 7), period));
            wavelength /= 2.0;
            amp *= style.persistence;
            k += 1;
        }
        // Normalise so that the summed amplitude equals the contrast.
        let total: f64 = octaves.iter().map(|o| o.1).sum::<f64>().max(1e-12);
        let norm = style.contrast / total;
        let mut data = vec![0u8; cols * rows];
        data.par_chunks_mut(cols).enumerate().for_each(|(r, line)| {
            for (c, t) in line.iter_mut().enumerate() {
                let (x, y) = (c as f64 * texel_m, r as f64 * texel_m);
                let mut v = 0.0;
                for &(w, a, s, period) in &octaves {
                    v += a * value_noise(s, x / w, y / w, period);
                }
                *t = ((style.mean + norm * v).clamp(0.03, 0.97) * 255.0).round() as u8;
            }
        });
        Texture {
            cols,
            rows,
            texel_m,
            data,
            constant: None,
        }
    }

    /// As [`Texture::bake`], with `speckle`'s blobs painted over the plaster: the random dark
    /// and light blotches people paint or stick on blank walls so that SfM finds features,
    /// and that a target detector must not take for targets.
    #[must_use]
    pub fn bake_speckled(
        size_m: (f64, f64),
        texel_m: f64,
        style: TextureStyle,
        speckle: Speckle,
        seed: u64,
    ) -> Self {
        let mut t = Self::bake_with(size_m, texel_m, style, seed, false);
        t.paint_blobs(size_m, speckle, seed ^ 0x5BEC);
        t
    }

    /// Paints `speckle`'s blobs into the raster. Each blob: a radius drawn log-uniformly,
    /// an outline `r(φ) = r0 (1 + Σ_k a_k cos(kφ + φ_k))` — harmonics 2–5 whose total
    /// amplitude is drawn between a third of `speckle.irregularity` and all of it (a blotch of
    /// paint is lumpy, never a circle to a few per cent), plus a rough fringe of harmonics 6–16
    /// a fifth as strong —, a soft edge a tenth of the radius wide, and an albedo shift of
    /// either sign that varies by ±30 % across the blob at a quarter of its radius (sponged
    /// paint is not flat), added to the plaster beneath (its texture runs on through the blob),
    /// so blobs overlap and shade one another.
    fn paint_blobs(&mut self, size_m: (f64, f64), speckle: Speckle, seed: u64) {
        let count = (speckle.per_m2 * size_m.0 * size_m.1).round() as u64;
        let uniform = |k: u64, j: i64| 0.5 * (lattice(seed, k as i64, j) + 1.0);
        let mut shift = vec![0.0f32; self.cols * self.rows];
        for k in 0..count {
            let (x, y) = (uniform(k, 0) * size_m.0, uniform(k, 1) * size_m.1);
            let r0 = speckle.min_radius_m
                * (speckle.max_radius_m / speckle.min_radius_m).powf(uniform(k, 2));
            let amplitude = speckle.irregularity * (1.0 + 2.0 * uniform(k, 3)) / 3.0;
            // (harmonic, relative weight, phase): the lumps, then a fringe a fifth as strong.
            let harmonics: Vec<(f64, f64, f64)> = (2..=16)
                .map(|h| {
                    let w = uniform(k, 10 + h) * if h <= 5 { 1.0 } else { 0.2 / 11.0 * 4.0 };
                    (h as f64, w, std::f64::consts::TAU * uniform(k, 40 + h))
                })
                .collect();
            let weights: f64 = harmonics
                .iter()
                .filter(|h| h.0 <= 5.0)
                .map(|h| h.1)
                .sum::<f64>()
                .max(1e-9);
            let mottle_seed = hash(seed, k as i64, 99);
            let delta = speckle.contrast
                * (0.4 + 0.6 * uniform(k, 4))
                * if uniform(k, 5) < 0.5 { -1.0 } else { 1.0 };
            let edge = 0.1 * r0;
            let reach = r0 * (1.0 + 1.2 * amplitude) + edge;
            let c0 = ((x - reach) / self.texel_m).floor().max(0.0) as usize;
            let c1 = (((x + reach) / self.texel_m).ceil() as usize).min(self.cols - 1);
            let r0i = ((y - reach) / self.texel_m).floor().max(0.0) as usize;
            let r1i = (((y + reach) / self.texel_m).ceil() as usize).min(self.rows - 1);
            for row in r0i..=r1i {
                for col in c0..=c1 {
                    let (dx, dy) = (col as f64 * self.texel_m - x, row as f64 * self.texel_m - y);
                    let rho = dx.hypot(dy);
                    if rho > reach {
                        continue;
                    }
                    let phi = dy.atan2(dx);
                    let outline = r0
                        * (1.0
                            + amplitude / weights
                                * harmonics
                                    .iter()
                                    .map(|&(h, w, p)| w * (h * phi + p).cos())
                                    .sum::<f64>());
                    // Smoothstep from inside (1) to outside (0) across the soft edge.
                    let t = ((outline + 0.5 * edge - rho) / edge).clamp(0.0, 1.0);
                    let cover = t * t * (3.0 - 2.0 * t);
                    let mottle =
                        1.0 + 0.3 * value_noise(mottle_seed, 4.0 * dx / r0, 4.0 * dy / r0, 0);
                    shift[row * self.cols + col] += (delta * mottle * cover) as f32;
                }
            }
        }
        for (v, s) in self.data.iter_mut().zip(&shift) {
            let albedo = f64::from(*v) / 255.0 + f64::from(*s);
            *v = (albedo.clamp(0.03, 0.97) * 255.0).round() as u8;
        }
    }

    /// A texture of one constant albedo.
    #[must_use]
    pub fn constant(albedo: f64) -> Self {
        Texture {
            cols: 1,
            rows: 1,
            texel_m: 1.0,
            data: Vec::new(),
            constant: Some(albedo),
        }
    }

    /// Albedo at (a, b) metres from the rectangle's origin (clamped at the edges).
    #[must_use]
    pub fn albedo(&self, a: f64, b: f64) -> f64 {
        if let Some(albedo) = self.constant {
            return albedo;
        }
        let x = (a / self.texel_m).clamp(0.0, (self.cols - 2) as f64);
        let y = (b / self.texel_m).clamp(0.0, (self.rows - 2) as f64);
        let (x0, y0) = (x as usize, y as usize);
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let i = y0 * self.cols + x0;
        let v = |k: usize| f64::from(self.data[k]);
        let top = v(i) + fx * (v(i + 1) - v(i));
        let bottom = v(i + self.cols) + fx * (v(i + self.cols + 1) - v(i + self.cols));
        (top + fy * (bottom - top)) / 255.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_is_seeded_bounded_and_varies_at_every_scale() {
        let a = Texture::bake((1.0, 1.0), 0.002, TextureStyle::WALL, 5);
        let b = Texture::bake((1.0, 1.0), 0.002, TextureStyle::WALL, 5);
        let c = Texture::bake((1.0, 1.0), 0.002, TextureStyle::WALL, 6);
        assert_eq!(a.data, b.data);
        assert_ne!(a.data, c.data);
        assert!(a.data.iter().all(|v| (7..=248).contains(v)));
        // Fine-scale variation: neighbouring texels 4 mm apart differ noticeably on average.
        let diffs: f64 = (0..400)
            .map(|k| {
                (a.albedo(0.3 + k as f64 * 0.001, 0.5) - a.albedo(0.304 + k as f64 * 0.001, 0.5))
                    .abs()
            })
            .sum::<f64>()
            / 400.0;
        assert!(diffs > 0.004, "mean 4 mm difference {diffs}");
        // Not periodic at the coarsest wavelength.
        assert!((a.albedo(0.1, 0.1) - a.albedo(0.7, 0.1)).abs() > 1e-6);
    }

    /// The speckle paints blobs of both signs over the plaster: the same seed gives the same
    /// wall, and texels differ from the plain plaster's by up to the blobs' contrast, darker
    /// and lighter alike.
    #[test]
    fn speckled_texture_paints_seeded_blobs_of_both_signs() {
        let plain = Texture::bake((0.5, 0.5), 0.001, TextureStyle::WALL, 5);
        let a = Texture::bake_speckled((0.5, 0.5), 0.001, TextureStyle::WALL, Speckle::WALL, 5);
        let b = Texture::bake_speckled((0.5, 0.5), 0.001, TextureStyle::WALL, Speckle::WALL, 5);
        assert_eq!(a.data, b.data);
        let shifts: Vec<i32> = a
            .data
            .iter()
            .zip(&plain.data)
            .map(|(x, y)| i32::from(*x) - i32::from(*y))
            .collect();
        let darker = shifts.iter().filter(|&&d| d < -20).count();
        let lighter = shifts.iter().filter(|&&d| d > 20).count();
        // 300 blobs of mean area about 1e-3 m² over 0.25 m²: most of the wall is covered at
        // least in part, each sign about half of it.
        assert!(darker > shifts.len() / 10, "{darker} darker texels");
        assert!(lighter > shifts.len() / 10, "{lighter} lighter texels");
        assert!(shifts.iter().all(|d| d.abs() <= 240));
    }

    #[test]
    fn periodic_texture_is_seamless_across_the_wrap() {
        let w = 0.359;
        let t = Texture::bake_periodic((w, 1.0), 0.001, TextureStyle::PIPE, 3);
        // Just before the wrap and just after (at 0) are as close as neighbouring texels.
        let mut worst: f64 = 0.0;
        for k in 0..100 {
            let b = 0.1 + k as f64 * 0.008;
            worst = worst.max((t.albedo(w - 0.0005, b) - t.albedo(0.0005, b)).abs());
        }
        assert!(worst < 0.03, "seam step {worst}");
    }
}
