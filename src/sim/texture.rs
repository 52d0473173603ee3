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
