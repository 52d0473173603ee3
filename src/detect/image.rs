//! The grey plane the detector works on: any frame (8- or 16-bit, grey, RGB, RGBA, palette)
//! converted to 8-bit luma, with interpolated sampling in the pixel convention of the crate
//! (pixel centres at half-integers).

use image::DynamicImage;

/// An 8-bit grey image, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct GrayImage {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// Samples.
    pub data: Vec<u8>,
}

impl GrayImage {
    /// Converts any frame to 8-bit luma (BT.601 weights, integer arithmetic for 8-bit RGB).
    #[must_use]
    pub fn from_dynamic(img: &DynamicImage) -> Self {
        let mut g = GrayImage {
            width: 0,
            height: 0,
            data: Vec::new(),
        };
        g.set_from(img);
        g
    }

    /// [`GrayImage::from_dynamic`] into this image's buffer (reused between frames).
    pub fn set_from(&mut self, img: &DynamicImage) {
        self.width = img.width() as usize;
        self.height = img.height() as usize;
        let luma = |r: u8, g: u8, b: u8| {
            ((77 * u32::from(r) + 150 * u32::from(g) + 29 * u32::from(b) + 128) >> 8) as u8
        };
        self.data.clear();
        match img {
            DynamicImage::ImageLuma8(g) => self.data.extend_from_slice(g.as_raw()),
            DynamicImage::ImageRgb8(rgb) => self
                .data
                .extend(rgb.as_raw().chunks_exact(3).map(|p| luma(p[0], p[1], p[2]))),
            DynamicImage::ImageRgba8(rgba) => self.data.extend(
                rgba.as_raw()
                    .chunks_exact(4)
                    .map(|p| luma(p[0], p[1], p[2])),
            ),
            other => self.data.extend_from_slice(other.to_luma8().as_raw()),
        }
    }

    /// This image at half resolution into `out`: each pixel the rounded mean of a 2×2 block
    /// (an odd last row or column is dropped), so that position `u` here is `u/2` there
    /// (pixel corners at the origin).
    pub fn half_into(&self, out: &mut GrayImage) {
        let (w, h) = (self.width / 2, self.height / 2);
        out.width = w;
        out.height = h;
        out.data.clear();
        out.data.reserve(w * h);
        for y in 0..h {
            let r0 = &self.data[2 * y * self.width..];
            let r1 = &self.data[(2 * y + 1) * self.width..];
            out.data.extend((0..w).map(|x| {
                let s = u16::from(r0[2 * x])
                    + u16::from(r0[2 * x + 1])
                    + u16::from(r1[2 * x])
                    + u16::from(r1[2 * x + 1]);
                ((s + 2) / 4) as u8
            }));
        }
    }

    /// The sample at integer array position (clamped to the image).
    #[must_use]
    pub fn at(&self, x: isize, y: isize) -> f64 {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        f64::from(self.data[y * self.width + x])
    }

    /// Bicubic (Keys, a = −0.5) interpolation at pixel position (u, v) (pixel centres at
    /// half-integers); `None` unless the 4×4 neighbourhood lies inside the image.
    #[must_use]
    pub fn bicubic(&self, u: f64, v: f64) -> Option<f64> {
        let (x, y) = (u - 0.5, v - 0.5);
        if !(x >= 1.0 && y >= 1.0 && x < self.width as f64 - 2.0 && y < self.height as f64 - 2.0) {
            return None;
        }
        let (x0, y0) = (x as usize, y as usize);
        let wx = keys(x - x0 as f64);
        let wy = keys(y - y0 as f64);
        let mut s = 0.0;
        for (j, wyj) in wy.iter().enumerate() {
            let row = &self.data[(y0 + j - 1) * self.width + x0 - 1..][..4];
            let h = wx[0] * f64::from(row[0])
                + wx[1] * f64::from(row[1])
                + wx[2] * f64::from(row[2])
                + wx[3] * f64::from(row[3]);
            s += wyj * h;
        }
        Some(s)
    }
}

/// Correlation of the bicubic interpolations of white pixel noise at two points `d` px apart,
/// averaged over the direction between them: `ρ(d) = ⟨ρ₁(d·cos α)·ρ₁(d·sin α)⟩_α` with `ρ₁` the
/// normalised autocorrelation of Keys' kernel. Tabulated once every 0.02 px; 0 beyond 4 px (the
/// kernel's support is 4 px wide).
#[must_use]
pub fn bicubic_noise_correlation(d: f64) -> f64 {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    const STEP: f64 = 0.02;
    let table = TABLE.get_or_init(|| {
        // ρ₁ by the midpoint rule over the kernel's support.
        let kernel = |x: f64| {
            let x = x.abs();
            const A: f64 = -0.5;
            if x < 1.0 {
                ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0
            } else if x < 2.0 {
                ((A * x - 5.0 * A) * x + 8.0 * A) * x - 4.0 * A
            } else {
                0.0
            }
        };
        let rho1 = |d: f64| {
            let n = 800;
            let h = 4.0 / n as f64;
            let (mut num, mut den) = (0.0, 0.0);
            for i in 0..n {
                let x = -2.0 + (i as f64 + 0.5) * h;
                num += kernel(x) * kernel(x + d);
                den += kernel(x) * kernel(x);
            }
            num / den
        };
        (0..=200)
            .map(|k| {
                let d = k as f64 * STEP;
                let m = 32;
                (0..m)
                    .map(|j| {
                        let a = std::f64::consts::FRAC_PI_2 * (j as f64 + 0.5) / m as f64;
                        rho1(d * a.cos()) * rho1(d * a.sin())
                    })
                    .sum::<f64>()
                    / m as f64
            })
            .collect()
    });
    let x = d.abs() / STEP;
    let k = x.floor() as usize;
    if k + 1 >= table.len() {
        return 0.0;
    }
    let f = x - k as f64;
    table[k] * (1.0 - f) + table[k + 1] * f
}

/// Keys' cubic convolution weights for taps at −1, 0, 1, 2 from the floor.
fn keys(t: f64) -> [f64; 4] {
    const A: f64 = -0.5;
    let near = |d: f64| ((A + 2.0) * d - (A + 3.0)) * d * d + 1.0;
    let far = |d: f64| ((A * d - 5.0 * A) * d + 8.0 * A) * d - 4.0 * A;
    [far(1.0 + t), near(t), near(1.0 - t), far(2.0 - t)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bicubic_reproduces_pixels_and_linear_ramps() {
        let img = GrayImage {
            width: 20,
            height: 10,
            data: (0..200).map(|k| ((k % 20) * 10) as u8).collect(),
        };
        // At a pixel centre it is the pixel.
        assert_eq!(img.bicubic(5.5, 4.5), Some(50.0));
        // Along a linear ramp it is linear.
        let v = img.bicubic(7.25, 5.0).unwrap();
        assert!((v - 67.5).abs() < 1e-9, "{v}");
        assert_eq!(img.bicubic(0.5, 0.5), None);
    }

    #[test]
    fn conversions_of_every_format() {
        let rgb = DynamicImage::ImageRgb8(image::RgbImage::from_pixel(
            3,
            2,
            image::Rgb([200, 100, 50]),
        ));
        let g = GrayImage::from_dynamic(&rgb);
        assert_eq!(
            g.data,
            vec![((77 * 200 + 150 * 100 + 29 * 50 + 128) >> 8) as u8; 6]
        );
        let g16 = DynamicImage::ImageLuma16(image::ImageBuffer::from_pixel(
            2,
            2,
            image::Luma([65535u16]),
        ));
        assert_eq!(GrayImage::from_dynamic(&g16).data, vec![255; 4]);
        let rgba16 = DynamicImage::ImageRgba16(image::ImageBuffer::from_pixel(
            1,
            1,
            image::Rgba([0u16, 0, 0, 65535]),
        ));
        assert_eq!(GrayImage::from_dynamic(&rgba16).data, vec![0]);
    }
}
