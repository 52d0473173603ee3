//! Undistortion of whole frames to a pinhole camera (docs/math.md §8.1).
//!
//! A [`RemapTable`] is computed once per camera and output view: for output pixel centres
//! `(u', v')` it knows where the ray `((u' − cx)/fx, (v' − cy)/fy)` lands in the source frame
//! through the forward `brown` model (no inversion per pixel). [`RemapTable::apply`] then
//! resamples any number of frames with Keys' bicubic kernel (a = −0.5) or bilinear
//! interpolation, sub-pixel offsets quantised to 1/256 px (≤ 0.002 px rounding), in fixed point
//! and SIMD for 8-bit frames, in parallel over rows. Output pixels whose ray lands outside the
//! source are black.

use image::{DynamicImage, ImageBuffer, Pixel};
use nalgebra::Vector2;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use wide::{i16x8, i32x4, u8x16};

use super::brown::{BrownCamera, UndistortError};

/// A distortion-free camera (COLMAP's PINHOLE: pixel centres at half-integers).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PinholeCamera {
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// Focal length along u (px).
    pub fx: f64,
    /// Focal length along v (px).
    pub fy: f64,
    /// Principal point u (px).
    pub cx: f64,
    /// Principal point v (px).
    pub cy: f64,
}

impl PinholeCamera {
    /// Ideal normalised coordinates of a pixel.
    #[must_use]
    pub fn ideal_from_pixel(&self, uv: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy)
    }

    /// Pixel of ideal normalised coordinates.
    #[must_use]
    pub fn pixel_from_ideal(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(self.fx * xy.x + self.cx, self.fy * xy.y + self.cy)
    }
}

/// Which pinhole camera the undistorted frames use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OutputView {
    /// Same size, `fx = fy = c`, same principal point: pixels near the centre keep their place.
    #[default]
    Same,
    /// The largest view in which every output pixel has source data (no black border).
    Valid,
    /// The smallest zoom that keeps every source pixel (black corners).
    Full,
}

/// Interpolation kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    /// Keys' cubic convolution, a = −0.5 (4×4 taps).
    #[default]
    Bicubic,
    /// Bilinear (2×2 taps).
    Bilinear,
}

impl Interpolation {
    fn taps(self) -> usize {
        match self {
            Interpolation::Bicubic => 4,
            Interpolation::Bilinear => 2,
        }
    }
}

/// The output pinhole camera of a view.
///
/// # Errors
///
/// [`UndistortError`] when the border of the source frame cannot be undistorted (the model
/// folds inside the image), for [`OutputView::Valid`] and [`OutputView::Full`].
pub fn pinhole_for_view(
    cam: &BrownCamera,
    view: OutputView,
) -> Result<PinholeCamera, UndistortError> {
    let i = &cam.intrinsics;
    let (w, h) = (f64::from(cam.width), f64::from(cam.height));
    let same = PinholeCamera {
        width: cam.width,
        height: cam.height,
        fx: i.c,
        fy: i.c,
        cx: i.u0,
        cy: i.v0,
    };
    if view == OutputView::Same {
        return Ok(same);
    }
    // Undistort the source border (pixel edges) and find the inner (Valid) or outer (Full)
    // axis-aligned rectangle of the resulting curve, in normalised coordinates.
    const SAMPLES: usize = 256;
    let mut left = Vec::new();
    let mut right = Vec::new();
    let mut top = Vec::new();
    let mut bottom = Vec::new();
    for k in 0..=SAMPLES {
        let s = k as f64 / SAMPLES as f64;
        left.push(i.ideal_from_pixel(&Vector2::new(0.0, s * h))?);
        right.push(i.ideal_from_pixel(&Vector2::new(w, s * h))?);
        top.push(i.ideal_from_pixel(&Vector2::new(s * w, 0.0))?);
        bottom.push(i.ideal_from_pixel(&Vector2::new(s * w, h))?);
    }
    let fold = |v: &[Vector2<f64>], pick: fn(&Vector2<f64>) -> f64, max: bool| {
        v.iter().map(pick).fold(
            if max {
                f64::NEG_INFINITY
            } else {
                f64::INFINITY
            },
            |a, b| {
                if max { a.max(b) } else { a.min(b) }
            },
        )
    };
    let (x0, x1, y0, y1) = match view {
        OutputView::Valid => (
            fold(&left, |p| p.x, true),
            fold(&right, |p| p.x, false),
            fold(&top, |p| p.y, true),
            fold(&bottom, |p| p.y, false),
        ),
        _ => (
            fold(&left, |p| p.x, false),
            fold(&right, |p| p.x, true),
            fold(&top, |p| p.y, false),
            fold(&bottom, |p| p.y, true),
        ),
    };
    // One focal length for square pixels: Valid must fit inside on both axes (larger f), Full
    // must cover both (smaller f).
    let fx_needed = w / (x1 - x0);
    let fy_needed = h / (y1 - y0);
    let f = match view {
        OutputView::Valid => fx_needed.max(fy_needed),
        _ => fx_needed.min(fy_needed),
    };
    // Centre the rectangle in the output frame.
    let cx = w / 2.0 - f * (x0 + x1) / 2.0;
    let cy = h / 2.0 - f * (y0 + y1) / 2.0;
    let mut pin = PinholeCamera {
        width: cam.width,
        height: cam.height,
        fx: f,
        fy: f,
        cx,
        cy,
    };
    if view == OutputView::Valid {
        // The border curve was sampled; zoom in until every output border pixel centre maps
        // inside the source (a few iterations of 0.05 % at most).
        for _ in 0..100 {
            if output_border_inside(cam, &pin) {
                break;
            }
            pin.fx *= 1.0005;
            pin.fy *= 1.0005;
            pin.cx = w / 2.0 - pin.fx * (x0 + x1) / 2.0;
            pin.cy = h / 2.0 - pin.fy * (y0 + y1) / 2.0;
        }
    }
    Ok(pin)
}

/// Whether every output border pixel centre of `pin` maps inside the source frame.
fn output_border_inside(cam: &BrownCamera, pin: &PinholeCamera) -> bool {
    let (w, h) = (pin.width, pin.height);
    let inside = |col: u32, row: u32| {
        let uv = Vector2::new(f64::from(col) + 0.5, f64::from(row) + 0.5);
        let src = cam.intrinsics.pixel_from_ideal(&pin.ideal_from_pixel(&uv));
        cam.contains(&src, 0.0)
    };
    (0..w).all(|c| inside(c, 0) && inside(c, h - 1))
        && (0..h).all(|r| inside(0, r) && inside(w - 1, r))
}

/// Sub-pixel resolution of the interpolation weights: 1/256 px (≤ 0.002 px rounding).
const FRAC_BITS: u32 = 8;
const FRAC_ONE: usize = 1 << FRAC_BITS;
/// Fixed-point scale of the kernel weights (2^11): products of 8-bit samples stay in i32 and
/// the vertical weights fit i16 for `pmaddwd`.
const WEIGHT_BITS: u32 = 11;
/// Largest spacing of the position grid (output pixels).
const MAX_GRID_STEP: usize = 16;
/// Largest allowed error of the interpolated source positions (px). The grid spacing halves
/// until the check points meet it.
const MAX_GRID_ERROR_PX: f64 = 0.002;
/// The SIMD bicubic kernel reads 16 bytes per tap row: a pixel is on the fast path when its
/// first tap column is at most `width − FAST_READ_PIXELS` (so even 1-channel rows hold 16 bytes).
const FAST_READ_PIXELS: i64 = 16;

/// Keys' cubic convolution kernel weights for taps at offsets −1, 0, 1, 2 from `floor(x)`.
fn cubic_weights(t: f64) -> [f64; 4] {
    const A: f64 = -0.5;
    let w = |d: f64| {
        let d = d.abs();
        if d <= 1.0 {
            ((A + 2.0) * d - (A + 3.0)) * d * d + 1.0
        } else if d < 2.0 {
            ((A * d - 5.0 * A) * d + 8.0 * A) * d - 4.0 * A
        } else {
            0.0
        }
    };
    [w(1.0 + t), w(t), w(1.0 - t), w(2.0 - t)]
}

fn kernel_weights(interp: Interpolation, t: f64) -> [f64; 4] {
    match interp {
        Interpolation::Bicubic => cubic_weights(t),
        Interpolation::Bilinear => [1.0 - t, t, 0.0, 0.0],
    }
}

/// Where one output pixel samples the source: the pixel index of its first tap and the
/// sub-pixel offsets (x in the low byte, y in the high byte, 1/256 px).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Tap {
    base: u32,
    frac: u16,
}

impl Tap {
    /// The ray leaves the source frame: black.
    const OUTSIDE: Tap = Tap {
        base: u32::MAX,
        frac: 0,
    };
    /// The taps cross the frame border: sampled exactly with clamping.
    const BORDER: Tap = Tap {
        base: u32::MAX - 1,
        frac: 0,
    };

    fn is_fast(self) -> bool {
        self.base < Tap::BORDER.base
    }
}

/// An output pixel sampled exactly: output index and source array coordinates.
#[derive(Clone, Copy, Debug)]
struct BorderPixel {
    index: u32,
    ax: f64,
    ay: f64,
}

/// A precomputed resampling from a distorted frame to a pinhole camera.
///
/// Source positions are computed exactly at the nodes of a grid over the output image and
/// bilinearly interpolated in between (the mapping is smooth; the grid spacing, 16 px or less,
/// is chosen so that the error stays below 0.002 px at every cell centre and edge midpoint),
/// then stored per output pixel as the first tap and the offsets quantised to 1/256 px
/// (8 bytes per pixel). Pixels whose taps cross the frame border are listed apart and sampled
/// exactly with clamping.
#[derive(Clone, Debug)]
pub struct RemapTable {
    src_width: u32,
    src_height: u32,
    target: PinholeCamera,
    interpolation: Interpolation,
    /// Largest interpolation error of the position grid at its check points (px).
    grid_error_px: f64,
    /// Per output pixel, row-major.
    taps: Vec<Tap>,
    /// Border pixels, sorted by output index, and where each output row's start in it.
    border: Vec<BorderPixel>,
    border_rows: Vec<usize>,
    /// Fixed-point weights per quantised offset.
    weights: Vec<[i32; 4]>,
    /// Vertical bicubic weights per quantised offset, as `pmaddwd` operands: (w0, w1)×4 and
    /// (w2, w3)×4.
    weight_pairs: Vec<[i16x8; 2]>,
}

/// Exact source positions at the nodes of a grid with spacing `step` over the output image,
/// and the largest interpolation error found at cell centres and edge midpoints.
fn position_grid(
    source: &(impl Fn(f64, f64) -> [f64; 2] + Sync),
    width: usize,
    height: usize,
    step: usize,
) -> (usize, Vec<[f64; 2]>, f64) {
    let cols = width.div_ceil(step) + 1;
    let rows = height.div_ceil(step) + 1;
    let grid: Vec<[f64; 2]> = (0..rows)
        .into_par_iter()
        .flat_map_iter(|r| (0..cols).map(move |c| ((c * step) as f64, (r * step) as f64)))
        .map(|(c, r)| source(c, r))
        .collect();
    let error = (0..rows - 1)
        .into_par_iter()
        .map(|r| {
            let mut worst: f64 = 0.0;
            for c in 0..cols - 1 {
                for (fc, fr) in [(0.5, 0.5), (0.5, 0.0), (0.0, 0.5)] {
                    let (x, y) = ((c as f64 + fc) * step as f64, (r as f64 + fr) * step as f64);
                    let exact = source(x, y);
                    let approx = interpolate_grid(&grid, cols, step, x, y);
                    let e = (exact[0] - approx[0]).hypot(exact[1] - approx[1]);
                    worst = worst.max(if e.is_finite() { e } else { f64::INFINITY });
                }
            }
            worst
        })
        .reduce(|| 0.0, f64::max);
    (cols, grid, error)
}

impl RemapTable {
    /// Builds the table mapping `cam`'s frames onto `target`.
    #[must_use]
    pub fn new(cam: &BrownCamera, target: PinholeCamera, interpolation: Interpolation) -> Self {
        let source = |col: f64, row: f64| {
            let uv = Vector2::new(col + 0.5, row + 0.5);
            let src = cam
                .intrinsics
                .pixel_from_ideal(&target.ideal_from_pixel(&uv));
            [src.x - 0.5, src.y - 0.5]
        };
        let (dw, dh) = (target.width as usize, target.height as usize);
        let mut step = MAX_GRID_STEP;
        let (cols, grid, grid_error_px) = loop {
            let built = position_grid(&source, dw, dh, step);
            if built.2 <= MAX_GRID_ERROR_PX || step == 1 {
                break built;
            }
            step /= 2;
        };
        let layout = TapLayout {
            src_width: i64::from(cam.width),
            src_height: i64::from(cam.height),
            taps: interpolation.taps() as i64,
            lead: if interpolation == Interpolation::Bicubic {
                1
            } else {
                0
            },
        };
        let rows: Vec<(Vec<Tap>, Vec<BorderPixel>)> = (0..dh)
            .into_par_iter()
            .map(|row| layout.row(&grid, cols, step, dw, row))
            .collect();
        let mut taps = Vec::with_capacity(dw * dh);
        let mut border = Vec::new();
        let mut border_rows = Vec::with_capacity(dh + 1);
        for (t, b) in rows {
            border_rows.push(border.len());
            taps.extend(t);
            border.extend(b);
        }
        border_rows.push(border.len());
        let scale = f64::from(1u32 << WEIGHT_BITS);
        let weights: Vec<[i32; 4]> = (0..=FRAC_ONE)
            .map(|q| {
                let w = kernel_weights(interpolation, q as f64 / FRAC_ONE as f64);
                let mut fixed = w.map(|v| (v * scale).round() as i32);
                // The fixed weights sum exactly to the scale so that flat areas stay exact.
                let sum: i32 = fixed.iter().sum();
                let largest = (0..4).max_by_key(|&k| fixed[k]).unwrap_or(1);
                fixed[largest] += (1 << WEIGHT_BITS) - sum;
                fixed
            })
            .collect();
        let weight_pairs = weights
            .iter()
            .map(|w| {
                let pair = |a: i32, b: i32| {
                    let (a, b) = (a as i16, b as i16);
                    i16x8::from([a, b, a, b, a, b, a, b])
                };
                [pair(w[0], w[1]), pair(w[2], w[3])]
            })
            .collect();
        RemapTable {
            src_width: cam.width,
            src_height: cam.height,
            target,
            interpolation,
            grid_error_px,
            taps,
            border,
            border_rows,
            weights,
            weight_pairs,
        }
    }

    /// The pinhole camera of the output frames.
    #[must_use]
    pub fn target(&self) -> &PinholeCamera {
        &self.target
    }

    /// Source frame size `(width, height)` the table expects.
    #[must_use]
    pub fn source_size(&self) -> (u32, u32) {
        (self.src_width, self.src_height)
    }

    /// The largest error of the interpolated source positions at the grid's check points (px).
    #[must_use]
    pub fn position_error_px(&self) -> f64 {
        self.grid_error_px
    }

    /// Resamples one frame. 8-bit frames keep their format; 16-bit frames stay 16-bit; float
    /// frames are converted to 16-bit RGB(A).
    ///
    /// # Errors
    ///
    /// [`SizeMismatch`] when the frame's size differs from the table's source size.
    pub fn apply(&self, frame: &DynamicImage) -> Result<DynamicImage, SizeMismatch> {
        if (frame.width(), frame.height()) != (self.src_width, self.src_height) {
            return Err(SizeMismatch {
                expected: (self.src_width, self.src_height),
                got: (frame.width(), frame.height()),
            });
        }
        Ok(match frame {
            DynamicImage::ImageLuma8(f) => DynamicImage::ImageLuma8(self.remap::<_, 1>(f)),
            DynamicImage::ImageLumaA8(f) => DynamicImage::ImageLumaA8(self.remap::<_, 2>(f)),
            DynamicImage::ImageRgb8(f) => DynamicImage::ImageRgb8(self.remap::<_, 3>(f)),
            DynamicImage::ImageRgba8(f) => DynamicImage::ImageRgba8(self.remap::<_, 4>(f)),
            DynamicImage::ImageLuma16(f) => DynamicImage::ImageLuma16(self.remap::<_, 1>(f)),
            DynamicImage::ImageLumaA16(f) => DynamicImage::ImageLumaA16(self.remap::<_, 2>(f)),
            DynamicImage::ImageRgb16(f) => DynamicImage::ImageRgb16(self.remap::<_, 3>(f)),
            DynamicImage::ImageRgba16(f) => DynamicImage::ImageRgba16(self.remap::<_, 4>(f)),
            other if other.color().has_alpha() => {
                DynamicImage::ImageRgba16(self.remap::<_, 4>(&other.to_rgba16()))
            }
            other => DynamicImage::ImageRgb16(self.remap::<_, 3>(&other.to_rgb16())),
        })
    }

    fn remap<P, const C: usize>(
        &self,
        src: &ImageBuffer<P, Vec<P::Subpixel>>,
    ) -> ImageBuffer<P, Vec<P::Subpixel>>
    where
        P: Pixel,
        P::Subpixel: Sample,
    {
        let data: &[P::Subpixel] = src.as_raw();
        let dw = self.target.width as usize;
        let stride = self.src_width as usize * C;
        let mut out = vec![P::Subpixel::ZERO; dw * self.target.height as usize * C];
        out.par_chunks_mut(dw * C)
            .enumerate()
            .for_each(|(row, line)| {
                let taps = &self.taps[row * dw..(row + 1) * dw];
                for (px, &tap) in line.chunks_exact_mut(C).zip(taps) {
                    if tap.is_fast() {
                        px.copy_from_slice(&P::Subpixel::fast::<C>(self, data, stride, tap));
                    }
                }
                for b in &self.border[self.border_rows[row]..self.border_rows[row + 1]] {
                    let col = b.index as usize - row * dw;
                    let value = self.sample_clamped::<C>(|i| data[i].to_f64(), b.ax, b.ay);
                    for (o, v) in line[col * C..(col + 1) * C].iter_mut().zip(value) {
                        *o = P::Subpixel::from_f64(v);
                    }
                }
            });
        ImageBuffer::from_raw(self.target.width, self.target.height, out)
            .unwrap_or_else(|| unreachable!("output buffer has width × height × channels samples"))
    }

    /// Floating-point sample at array position (ax, ay) with taps clamped to the frame.
    fn sample_clamped<const C: usize>(
        &self,
        at: impl Fn(usize) -> f64,
        ax: f64,
        ay: f64,
    ) -> [f64; C] {
        let (sw, sh) = (self.src_width as i64, self.src_height as i64);
        let (x0, y0) = (ax.floor(), ay.floor());
        let wx = kernel_weights(self.interpolation, ax - x0);
        let wy = kernel_weights(self.interpolation, ay - y0);
        let taps = self.interpolation.taps() as i64;
        let lead = if taps == 4 { 1 } else { 0 };
        let mut acc = [0.0; C];
        for j in 0..taps {
            let y = (y0 as i64 - lead + j).clamp(0, sh - 1) as usize;
            for i in 0..taps {
                let x = (x0 as i64 - lead + i).clamp(0, sw - 1) as usize;
                let w = wx[i as usize] * wy[j as usize];
                for (ch, a) in acc.iter_mut().enumerate() {
                    *a += w * at((y * sw as usize + x) * C + ch);
                }
            }
        }
        acc
    }

    /// The array position a fast tap samples (its quantised position).
    fn tap_position(&self, tap: Tap) -> (f64, f64) {
        let lead = if self.interpolation == Interpolation::Bicubic {
            1.0
        } else {
            0.0
        };
        let sw = self.src_width;
        let (x0, y0) = (tap.base % sw, tap.base / sw);
        let q = |b: u16| f64::from(b) / FRAC_ONE as f64;
        (
            f64::from(x0) + lead + q(tap.frac & 0xff),
            f64::from(y0) + lead + q(tap.frac >> 8),
        )
    }
}

/// The source geometry needed to turn positions into taps.
struct TapLayout {
    src_width: i64,
    src_height: i64,
    taps: i64,
    lead: i64,
}

impl TapLayout {
    /// The taps of one output row, and its border pixels.
    ///
    /// The grid nodes of the row are interpolated between grid rows, then the positions are
    /// stepped across the row in fixed point (1/2^32 px).
    fn row(
        &self,
        grid: &[[f64; 2]],
        cols: usize,
        step: usize,
        width: usize,
        row: usize,
    ) -> (Vec<Tap>, Vec<BorderPixel>) {
        const SHIFT: u32 = 32;
        let one = (1u64 << SHIFT) as f64;
        let fixed = |v: f64| (v * one).clamp(-1e18, 1e18) as i64;
        let (r0, t) = (row / step, (row % step) as f64 / step as f64);
        let (a, b) = (
            &grid[r0 * cols..(r0 + 1) * cols],
            &grid[(r0 + 1) * cols..(r0 + 2) * cols],
        );
        let inv = 1.0 / step as f64;
        // Inside the frame: array coordinates in [−0.5, size − 0.5] (pixel edges).
        let half = 1i64 << (SHIFT - 1);
        let (max_x, max_y) = (
            (self.src_width << SHIFT) - half,
            (self.src_height << SHIFT) - half,
        );
        let max_fast_x = self.src_width - FAST_READ_PIXELS;
        // Rounding to 1/256 px, then first tap and offset.
        let round = 1i64 << (SHIFT - FRAC_BITS - 1);
        let mut taps = Vec::with_capacity(width);
        let mut border = Vec::new();
        let mut left = lerp(a[0], b[0], t);
        for c0 in 0..cols - 1 {
            let right = lerp(a[c0 + 1], b[c0 + 1], t);
            let (mut x, mut y) = (fixed(left[0]), fixed(left[1]));
            let (dx, dy) = (
                fixed((right[0] - left[0]) * inv),
                fixed((right[1] - left[1]) * inv),
            );
            for _ in 0..step.min(width - taps.len()) {
                let tap = if x < -half || y < -half || x > max_x || y > max_y {
                    Tap::OUTSIDE
                } else {
                    let qx = (x + round) >> (SHIFT - FRAC_BITS);
                    let qy = (y + round) >> (SHIFT - FRAC_BITS);
                    let (x0, y0) = ((qx >> FRAC_BITS) - self.lead, (qy >> FRAC_BITS) - self.lead);
                    if x0 >= 0 && y0 >= 0 && x0 <= max_fast_x && y0 + self.taps <= self.src_height {
                        let frac = (qx & 0xff) | ((qy & 0xff) << 8);
                        Tap {
                            base: (y0 * self.src_width + x0) as u32,
                            frac: frac as u16,
                        }
                    } else {
                        let index = (row * width + taps.len()) as u32;
                        border.push(BorderPixel {
                            index,
                            ax: x as f64 / one,
                            ay: y as f64 / one,
                        });
                        Tap::BORDER
                    }
                };
                taps.push(tap);
                x += dx;
                y += dy;
            }
            if taps.len() == width {
                break;
            }
            left = right;
        }
        (taps, border)
    }
}

fn lerp(a: [f64; 2], b: [f64; 2], t: f64) -> [f64; 2] {
    [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
}

/// Source position at output pixel (x, y) interpolated from the grid.
fn interpolate_grid(grid: &[[f64; 2]], cols: usize, step: usize, x: f64, y: f64) -> [f64; 2] {
    let (gx, gy) = (x / step as f64, y / step as f64);
    let (c0, r0) = ((gx.floor() as usize).min(cols - 2), gy.floor() as usize);
    let (s, t) = (gx - c0 as f64, gy - r0 as f64);
    let at = |r: usize, c: usize| grid[r * cols + c];
    lerp(
        lerp(at(r0, c0), at(r0, c0 + 1), s),
        lerp(at(r0 + 1, c0), at(r0 + 1, c0 + 1), s),
        t,
    )
}

/// Sample types the remap handles: 8-bit in fixed point (SIMD for bicubic), 16-bit in f64.
trait Sample: Copy + Send + Sync + 'static {
    const ZERO: Self;
    fn to_f64(self) -> f64;
    fn from_f64(v: f64) -> Self;
    /// The kernel for a fast tap.
    fn fast<const C: usize>(
        table: &RemapTable,
        data: &[Self],
        stride: usize,
        tap: Tap,
    ) -> [Self; C];
}

impl Sample for u16 {
    const ZERO: Self = 0;
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    fn from_f64(v: f64) -> Self {
        v.round().clamp(0.0, 65535.0) as u16
    }
    fn fast<const C: usize>(table: &RemapTable, data: &[u16], _: usize, tap: Tap) -> [u16; C] {
        let (ax, ay) = table.tap_position(tap);
        table
            .sample_clamped::<C>(|i| f64::from(data[i]), ax, ay)
            .map(u16::from_f64)
    }
}

impl Sample for u8 {
    const ZERO: Self = 0;
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    fn from_f64(v: f64) -> Self {
        v.round().clamp(0.0, 255.0) as u8
    }
    #[inline(always)]
    fn fast<const C: usize>(table: &RemapTable, data: &[u8], stride: usize, tap: Tap) -> [u8; C] {
        let base = tap.base as usize * C;
        let f = tap.frac as usize;
        let wx = &table.weights[f & 0xff];
        if table.interpolation == Interpolation::Bicubic {
            bicubic_u8::<C>(data, stride, base, wx, &table.weight_pairs[f >> 8])
        } else {
            bilinear_u8::<C>(data, stride, base, wx, &table.weights[f >> 8])
        }
    }
}

/// Bicubic sample of an 8-bit frame: 4 tap rows of 4·C samples starting at `base`.
///
/// The vertical pass interleaves two tap rows and multiplies them with `pmaddwd`
/// (`wide::i16x8::dot`) over all 4·C samples at once; the horizontal pass combines the four
/// columns per channel (with lane-wise products for RGB).
#[inline(always)]
fn bicubic_u8<const C: usize>(
    data: &[u8],
    stride: usize,
    base: usize,
    wx: &[i32; 4],
    wy: &[i16x8; 2],
) -> [u8; C] {
    let load = |j: usize| {
        let s = base + j * stride;
        let mut a = [0u8; 16];
        a.copy_from_slice(&data[s..s + 16]);
        u8x16::from(a)
    };
    let mut v = [i32x4::splat(0); 4];
    for (pair, &w) in wy.iter().enumerate() {
        let (a, b) = (load(2 * pair), load(2 * pair + 1));
        let lo = u8x16::unpack_low(a, b);
        v[0] += i16x8::from_u8x16_low(lo).dot(w);
        if C > 1 {
            v[1] += i16x8::from_u8x16_high(lo).dot(w);
        }
        if C > 2 {
            let hi = u8x16::unpack_high(a, b);
            v[2] += i16x8::from_u8x16_low(hi).dot(w);
            if C > 3 {
                v[3] += i16x8::from_u8x16_high(hi).dot(w);
            }
        }
    }
    let half = 1 << (2 * WEIGHT_BITS - 1);
    let mut sums = [0i32; C];
    if C == 3 {
        // Lanes: [R0 G0 B0 R1] [G1 B1 R2 G2] [B2 R3 G3 B3].
        let wa = i32x4::from([wx[0], wx[0], wx[0], wx[1]]);
        let wb = i32x4::from([wx[1], wx[1], wx[2], wx[2]]);
        let wc = i32x4::from([wx[2], wx[3], wx[3], wx[3]]);
        let (a, b, c) = (
            (v[0] * wa).to_array(),
            (v[1] * wb).to_array(),
            (v[2] * wc).to_array(),
        );
        sums[0] = a[0] + a[3] + b[2] + c[1];
        sums[1] = a[1] + b[0] + b[3] + c[2];
        sums[2] = a[2] + b[1] + c[0] + c[3];
    } else {
        let lanes: [[i32; 4]; 4] = v.map(|x| x.to_array());
        let t = |k: usize| lanes[k / 4][k % 4];
        for (ch, s) in sums.iter_mut().enumerate() {
            *s = (wx[0] * t(ch) + wx[1] * t(C + ch))
                + (wx[2] * t(2 * C + ch) + wx[3] * t(3 * C + ch));
        }
    }
    sums.map(|s| clamp_u8((s + half) >> (2 * WEIGHT_BITS)))
}

/// Saturates to 0..=255 without branches.
#[inline(always)]
fn clamp_u8(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

/// Bilinear sample of an 8-bit frame in fixed point.
#[inline(always)]
fn bilinear_u8<const C: usize>(
    data: &[u8],
    stride: usize,
    base: usize,
    wx: &[i32; 4],
    wy: &[i32; 4],
) -> [u8; C] {
    let (r0, r1) = (
        &data[base..base + 2 * C],
        &data[base + stride..base + stride + 2 * C],
    );
    let half = 1 << (2 * WEIGHT_BITS - 1);
    let mut out = [0u8; C];
    for (ch, o) in out.iter_mut().enumerate() {
        let top = wx[0] * i32::from(r0[ch]) + wx[1] * i32::from(r0[C + ch]);
        let bottom = wx[0] * i32::from(r1[ch]) + wx[1] * i32::from(r1[C + ch]);
        *o = clamp_u8((wy[0] * top + wy[1] * bottom + half) >> (2 * WEIGHT_BITS));
    }
    out
}

/// A frame whose size differs from the camera's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("frame is {}x{} but the camera is {}x{}", .got.0, .got.1, .expected.0, .expected.1)]
pub struct SizeMismatch {
    /// The camera's size.
    pub expected: (u32, u32),
    /// The frame's size.
    pub got: (u32, u32),
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use image::{Luma, Rgb};

    fn cam() -> BrownCamera {
        BrownCamera {
            width: 480,
            height: 270,
            intrinsics: Intrinsics {
                c: 380.0,
                u0: 243.1,
                v0: 133.4,
                k1: 0.06,
                k2: -0.04,
                k3: 0.0,
                p1: 4e-4,
                p2: -3e-4,
                b1: 0.3,
                b2: 0.0,
            },
        }
    }

    #[test]
    fn cubic_weights_sum_to_one_and_interpolate() {
        for k in 0..=16 {
            let t = f64::from(k) / 16.0;
            let w = cubic_weights(t);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            // Keys' kernel reproduces linear functions: Σ w_i·(i − 1) = t.
            let lin: f64 = w
                .iter()
                .enumerate()
                .map(|(i, wi)| wi * (i as f64 - 1.0))
                .sum();
            assert!((lin - t).abs() < 1e-12);
        }
        assert_eq!(cubic_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn flat_frame_stays_flat_inside_and_black_outside() {
        let c = cam();
        let pin = pinhole_for_view(&c, OutputView::Full).unwrap();
        let table = RemapTable::new(&c, pin, Interpolation::Bicubic);
        let frame = DynamicImage::ImageRgb8(ImageBuffer::from_pixel(480, 270, Rgb([200, 100, 7])));
        let out = table.apply(&frame).unwrap().to_rgb8();
        let mut inside = 0;
        for (x, y, p) in out.enumerate_pixels() {
            let uv = Vector2::new(f64::from(x) + 0.5, f64::from(y) + 0.5);
            let src = c.intrinsics.pixel_from_ideal(&pin.ideal_from_pixel(&uv));
            if c.contains(&src, 0.0) {
                assert_eq!(p.0, [200, 100, 7], "at {x},{y}");
                inside += 1;
            } else if !c.contains(&src, -1.0) {
                assert_eq!(p.0, [0, 0, 0], "at {x},{y}");
            }
        }
        assert!(inside > 400 * 200);
    }

    #[test]
    fn valid_view_has_no_black_pixels_and_full_view_keeps_the_corners() {
        let c = cam();
        let valid = pinhole_for_view(&c, OutputView::Valid).unwrap();
        assert!(output_border_inside(&c, &valid));
        let full = pinhole_for_view(&c, OutputView::Full).unwrap();
        assert!(full.fx < valid.fx);
        // Every source corner is seen by the Full view.
        for uv in [
            Vector2::new(0.5, 0.5),
            Vector2::new(479.5, 0.5),
            Vector2::new(0.5, 269.5),
            Vector2::new(479.5, 269.5),
        ] {
            let p = full.pixel_from_ideal(&c.intrinsics.ideal_from_pixel(&uv).unwrap());
            assert!(
                p.x >= -1e-6 && p.y >= -1e-6 && p.x <= 480.0 + 1e-6 && p.y <= 270.0 + 1e-6,
                "{p:?}"
            );
        }
    }

    #[test]
    fn position_grid_error_is_below_the_bound_and_matches_exact_positions() {
        let c = cam();
        let pin = pinhole_for_view(&c, OutputView::Same).unwrap();
        let table = RemapTable::new(&c, pin, Interpolation::Bicubic);
        assert!(table.position_error_px() <= MAX_GRID_ERROR_PX);
        // Every fast tap is the exact position rounded to 1/256 px, up to the grid error.
        let mut worst: f64 = 0.0;
        for (k, tap) in table.taps.iter().enumerate() {
            if !tap.is_fast() {
                continue;
            }
            let (col, row) = ((k % 480) as f64, (k / 480) as f64);
            let src = c
                .intrinsics
                .pixel_from_ideal(&pin.ideal_from_pixel(&Vector2::new(col + 0.5, row + 0.5)));
            let (ax, ay) = table.tap_position(*tap);
            worst = worst.max((src.x - 0.5 - ax).abs().max((src.y - 0.5 - ay).abs()));
        }
        // 1/512 px rounding plus the grid error.
        assert!(
            worst <= 0.5 / 256.0 + MAX_GRID_ERROR_PX + 1e-12,
            "worst {worst} px"
        );
    }

    #[test]
    fn wrong_size_frame_is_an_error() {
        let c = cam();
        let table = RemapTable::new(
            &c,
            pinhole_for_view(&c, OutputView::Same).unwrap(),
            Interpolation::Bilinear,
        );
        let frame = DynamicImage::ImageLuma8(ImageBuffer::new(10, 10));
        assert_eq!(
            table.apply(&frame).unwrap_err(),
            SizeMismatch {
                expected: (480, 270),
                got: (10, 10)
            }
        );
    }

    #[test]
    fn sixteen_bit_and_eight_bit_paths_agree() {
        // A smooth ramp: the u16 path (float) and the u8 path (fixed point) must agree to within
        // one 8-bit level after scaling.
        let c = cam();
        let table = RemapTable::new(
            &c,
            pinhole_for_view(&c, OutputView::Same).unwrap(),
            Interpolation::Bicubic,
        );
        let f8 = ImageBuffer::from_fn(480, 270, |x, y| Luma([((x + y) % 256) as u8 / 2 + 40]));
        let f16 = ImageBuffer::from_fn(480, 270, |x, y| {
            Luma([u16::from(f8.get_pixel(x, y).0[0]) * 257])
        });
        let o8 = table
            .apply(&DynamicImage::ImageLuma8(f8))
            .unwrap()
            .to_luma8();
        let o16 = table
            .apply(&DynamicImage::ImageLuma16(f16))
            .unwrap()
            .to_luma16();
        for (a, b) in o8.pixels().zip(o16.pixels()) {
            let b8 = f64::from(b.0[0]) / 257.0;
            assert!(
                (f64::from(a.0[0]) - b8).abs() <= 1.0,
                "{} vs {}",
                a.0[0],
                b8
            );
        }
    }
}
