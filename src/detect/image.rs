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
