//! Developing radiance into a frame: exposure, vignetting, blur (defocus), sensor noise and
//! quantisation, as a phone's camera pipeline does.

use image::{DynamicImage, RgbImage};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::{Frame, RenderConfig, mix};
use crate::camera::BrownCamera;

/// Bilinear interpolation of a row-major image at (x, y) in pixel-index units (pixel k's
/// centre at k), clamped to the image.
pub(super) fn bilinear(img: &[f32], w: usize, h: usize, x: f64, y: f64) -> f32 {
    let x = x.clamp(0.0, (w - 1) as f64);
    let y = y.clamp(0.0, (h - 1) as f64);
    // At an integer position the weight of the next pixel is exactly 0: the pixel's own value
    // comes back unchanged.
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let at = |xx: usize, yy: usize| img[yy * w + xx];
    let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * fx;
    let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * fx;
    top + (bottom - top) * fy
}

/// Separable Gaussian blur with clamped borders.
fn blur(img: &mut [f32], w: usize, h: usize, sigma: f64) {
    if sigma <= 0.0 {
        return;
    }
    let radius = (3.0 * sigma).ceil() as usize;
    let kernel: Vec<f32> = {
        let k: Vec<f64> = (0..=2 * radius)
            .map(|i| (-((i as f64 - radius as f64).powi(2)) / (2.0 * sigma * sigma)).exp())
            .collect();
        let s: f64 = k.iter().sum();
        k.iter().map(|v| (v / s) as f32).collect()
    };
    let mut tmp = vec![0f32; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(r, line)| {
        let src = &img[r * w..(r + 1) * w];
        for (c, o) in line.iter_mut().enumerate() {
            let mut s = 0.0;
            for (k, kv) in kernel.iter().enumerate() {
                let x = (c + k).saturating_sub(radius).min(w - 1);
                s += kv * src[x];
            }
            *o = s;
        }
    });
    img.par_chunks_mut(w).enumerate().for_each(|(r, line)| {
        for (c, o) in line.iter_mut().enumerate() {
            let mut s = 0.0;
            for (k, kv) in kernel.iter().enumerate() {
                let y = (r + k).saturating_sub(radius).min(h - 1);
                s += kv * tmp[y * w + c];
            }
            *o = s;
        }
    });
}

/// Turns radiance into a frame: exposure (`gain` DN per unit radiance), vignetting, blur,
/// per-channel signal-dependent and read noise (seeded by `(seed, frame, row)`), 8-bit
/// quantisation and optional JPEG.
///
/// # Errors
///
/// An image encoding error when JPEG is on (never expected for in-memory buffers).
pub fn develop(
    radiance: Vec<f32>,
    camera: &BrownCamera,
    gain: f64,
    config: &RenderConfig,
    seed: u64,
    frame: u64,
) -> Result<Frame, image::ImageError> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut dn = radiance;
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    let r2_corner = cx * cx + cy * cy;
    dn.par_chunks_mut(w).enumerate().for_each(|(r, line)| {
        let dy = r as f64 + 0.5 - cy;
        for (c, v) in line.iter_mut().enumerate() {
            let dx = c as f64 + 0.5 - cx;
            let vig = 1.0 - config.vignetting * (dx * dx + dy * dy) / r2_corner;
            *v = (f64::from(*v) * gain * vig) as f32;
        }
    });
    blur(&mut dn, w, h, config.blur_sigma_px);
    let mut data = vec![0u8; w * h * 3];
    data.par_chunks_mut(w * 3)
        .enumerate()
        .for_each(|(r, line)| {
            let mut rng = ChaCha8Rng::seed_from_u64(mix(seed, frame, r as u64));
            let mut spare: Option<f64> = None;
            for (c, px) in line.chunks_exact_mut(3).enumerate() {
                let signal = f64::from(dn[r * w + c]).max(0.0);
                let sigma = (config.read_noise_dn.powi(2) + config.shot_noise * signal).sqrt();
                for p in px.iter_mut() {
                    let noisy = if sigma > 0.0 {
                        let z = spare.take().unwrap_or_else(|| {
                            let (a, b) = crate::robust::standard_normal_pair(&mut rng);
                            spare = Some(b);
                            a
                        });
                        signal + sigma * z
                    } else {
                        signal
                    };
                    *p = noisy.round().clamp(0.0, 255.0) as u8;
                }
            }
        });
    let image = RgbImage::from_raw(camera.width, camera.height, data)
        .unwrap_or_else(|| unreachable!("buffer has width × height × 3 samples"));
    match config.jpeg_quality {
        None => Ok(Frame { image, jpeg: None }),
        Some(q) => {
            let mut bytes = Vec::new();
            let encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, q);
            DynamicImage::ImageRgb8(image).write_with_encoder(encoder)?;
            let decoded =
                image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)?.to_rgb8();
            Ok(Frame {
                image: decoded,
                jpeg: Some(bytes),
            })
        }
    }
}
