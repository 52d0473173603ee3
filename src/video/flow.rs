//! Apparent motion and sharpness of video frames, for the frame choice:
//! sparse feature flow (Shi–Tomasi corners, one per grid cell, tracked by pyramidal
//! Lucas–Kanade with a forward–backward check; Bouguet 2001, "Pyramidal implementation of the
//! affine Lucas Kanade feature tracker") and the mean squared Laplacian (Pech-Pacheco et al.
//! 2000, "Diatom autofocusing in brightfield microscopy").

/// A grey image, row-major, intensities 0–255 as `f32`.
#[derive(Clone, Debug, PartialEq)]
pub struct Grey {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// `width·height` intensities.
    pub data: Vec<f32>,
}

impl Grey {
    /// From 8-bit samples; `None` when `bytes` is not `width·height` long.
    #[must_use]
    pub fn from_bytes(width: usize, height: usize, bytes: &[u8]) -> Option<Self> {
        (bytes.len() == width * height).then(|| Grey {
            width,
            height,
            data: bytes.iter().map(|&b| f32::from(b)).collect(),
        })
    }

    #[inline]
    fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Bilinear sample at `(x, y)` (pixel centres at integers), clamped to the border.
    #[inline]
    fn sample(&self, x: f32, y: f32) -> f32 {
        let xm = (self.width - 1) as f32;
        let ym = (self.height - 1) as f32;
        let x = x.clamp(0.0, xm);
        let y = y.clamp(0.0, ym);
        let x0 = x.floor();
        let y0 = y.floor();
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as usize, y0 as usize);
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x1, y0) * fx;
        let bottom = self.at(x0, y1) * (1.0 - fx) + self.at(x1, y1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Half size by 2×2 averaging.
    fn half(&self) -> Grey {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let s = self.at(2 * x, 2 * y)
                    + self.at(2 * x + 1, 2 * y)
                    + self.at(2 * x, 2 * y + 1)
                    + self.at(2 * x + 1, 2 * y + 1);
                data.push(0.25 * s);
            }
        }
        Grey {
            width: w,
            height: h,
            data,
        }
    }
}

/// Sharpness: the mean squared 4-neighbour Laplacian over the interior (grey levels²). Blur,
/// from motion or focus, lowers it; comparable between frames of one scene.
#[must_use]
pub fn sharpness(img: &Grey) -> f64 {
    if img.width < 3 || img.height < 3 {
        return 0.0;
    }
    let mut sum = 0.0_f64;
    for y in 1..img.height - 1 {
        for x in 1..img.width - 1 {
            let l = img.at(x - 1, y) + img.at(x + 1, y) + img.at(x, y - 1) + img.at(x, y + 1)
                - 4.0 * img.at(x, y);
            sum += f64::from(l * l);
        }
    }
    sum / ((img.width - 2) * (img.height - 2)) as f64
}

/// A Gaussian-free image pyramid: level 0 the image, each next level half the size, down to
/// about 40 px on the short side (at most 5 levels).
#[derive(Clone, Debug)]
pub struct Pyramid {
    levels: Vec<Grey>,
}

impl Pyramid {
    /// Builds the pyramid of `img`.
    #[must_use]
    pub fn new(img: Grey) -> Self {
        let mut levels = vec![img];
        while levels.len() < 5 {
            let last = &levels[levels.len() - 1];
            if last.width.min(last.height) < 80 {
                break;
            }
            let next = last.half();
            levels.push(next);
        }
        Pyramid { levels }
    }

    /// The full-resolution level.
    #[must_use]
    pub fn base(&self) -> &Grey {
        &self.levels[0]
    }
}

/// Half-size of the tracking window (px): 15×15 windows.
const HALF_WINDOW: i32 = 7;
/// Grid of cells for the corners (columns, rows).
const GRID: (usize, usize) = (12, 8);

/// Shi–Tomasi corners: in each cell of a 12×8 grid the pixel (on a stride-2 lattice) with the
/// largest smaller eigenvalue of the 7×7 structure tensor, kept when above 1 % of the best.
#[must_use]
pub fn corners(img: &Grey) -> Vec<(f32, f32)> {
    let margin = (HALF_WINDOW + 2) as usize;
    if img.width < 2 * margin + GRID.0 || img.height < 2 * margin + GRID.1 {
        return Vec::new();
    }
    let (gx, gy) = gradients(img);
    let w = img.width;
    let min_eigen = |x: usize, y: usize| -> f32 {
        let (mut a, mut b, mut c) = (0.0_f32, 0.0_f32, 0.0_f32);
        for yy in y - 3..=y + 3 {
            for xx in x - 3..=x + 3 {
                let (dx, dy) = (gx[yy * w + xx], gy[yy * w + xx]);
                a += dx * dx;
                b += dx * dy;
                c += dy * dy;
            }
        }
        0.5 * (a + c - ((a - c) * (a - c) + 4.0 * b * b).sqrt())
    };
    let cell_w = (img.width - 2 * margin) / GRID.0;
    let cell_h = (img.height - 2 * margin) / GRID.1;
    let mut best: Vec<(f32, f32, f32)> = Vec::with_capacity(GRID.0 * GRID.1);
    for cy in 0..GRID.1 {
        for cx in 0..GRID.0 {
            let mut top = (0.0_f32, 0.0_f32, 0.0_f32);
            let y_start = margin + cy * cell_h;
            let x_start = margin + cx * cell_w;
            for y in (y_start..y_start + cell_h).step_by(2) {
                for x in (x_start..x_start + cell_w).step_by(2) {
                    let e = min_eigen(x, y);
                    if e > top.2 {
                        top = (x as f32, y as f32, e);
                    }
                }
            }
            if top.2 > 0.0 {
                best.push(top);
            }
        }
    }
    let strongest = best.iter().map(|c| c.2).fold(0.0_f32, f32::max);
    best.into_iter()
        .filter(|c| c.2 > 0.01 * strongest)
        .map(|c| (c.0, c.1))
        .collect()
}

/// Central-difference gradients (zero on the border).
fn gradients(img: &Grey) -> (Vec<f32>, Vec<f32>) {
    let (w, h) = (img.width, img.height);
    let mut gx = vec![0.0_f32; w * h];
    let mut gy = vec![0.0_f32; w * h];
    for y in 1..h.saturating_sub(1) {
        for x in 1..w - 1 {
            gx[y * w + x] = 0.5 * (img.at(x + 1, y) - img.at(x - 1, y));
            gy[y * w + x] = 0.5 * (img.at(x, y + 1) - img.at(x, y - 1));
        }
    }
    (gx, gy)
}

/// Tracks `p` from `from` to `to` by pyramidal Lucas–Kanade (translation, 15×15 window, up to
/// 20 Gauss–Newton steps per level). `None` when the window's structure is degenerate or the
/// point leaves the image.
#[must_use]
pub fn track(from: &Pyramid, to: &Pyramid, p: (f32, f32)) -> Option<(f32, f32)> {
    let levels = from.levels.len().min(to.levels.len());
    let mut d = (0.0_f32, 0.0_f32);
    for level in (0..levels).rev() {
        let scale = (1u32 << level) as f32;
        let a = &from.levels[level];
        let b = &to.levels[level];
        let (px, py) = (p.0 / scale, p.1 / scale);
        d = (2.0 * d.0, 2.0 * d.1);
        if level == levels - 1 {
            d = (0.0, 0.0);
        }
        // The template's gradients and structure tensor.
        let mut g = (0.0_f32, 0.0_f32, 0.0_f32);
        let n = (2 * HALF_WINDOW + 1) as usize;
        let mut tmpl = [0.0_f32; 225];
        let mut grads = [(0.0_f32, 0.0_f32); 225];
        for (i, dy) in (-HALF_WINDOW..=HALF_WINDOW).enumerate() {
            for (j, dx) in (-HALF_WINDOW..=HALF_WINDOW).enumerate() {
                let (x, y) = (px + dx as f32, py + dy as f32);
                let ix = 0.5 * (a.sample(x + 1.0, y) - a.sample(x - 1.0, y));
                let iy = 0.5 * (a.sample(x, y + 1.0) - a.sample(x, y - 1.0));
                tmpl[i * n + j] = a.sample(x, y);
                grads[i * n + j] = (ix, iy);
                g.0 += ix * ix;
                g.1 += ix * iy;
                g.2 += iy * iy;
            }
        }
        let det = g.0 * g.2 - g.1 * g.1;
        if det <= 1e-3 * (g.0 + g.2).powi(2).max(1e-9) {
            return None;
        }
        for _ in 0..20 {
            let (mut bx, mut by) = (0.0_f32, 0.0_f32);
            for (i, dy) in (-HALF_WINDOW..=HALF_WINDOW).enumerate() {
                for (j, dx) in (-HALF_WINDOW..=HALF_WINDOW).enumerate() {
                    let e = tmpl[i * n + j] - b.sample(px + d.0 + dx as f32, py + d.1 + dy as f32);
                    let (ix, iy) = grads[i * n + j];
                    bx += e * ix;
                    by += e * iy;
                }
            }
            let step = ((g.2 * bx - g.1 * by) / det, (g.0 * by - g.1 * bx) / det);
            d = (d.0 + step.0, d.1 + step.1);
            if step.0 * step.0 + step.1 * step.1 < 1e-4 {
                break;
            }
        }
        if !(d.0.is_finite() && d.1.is_finite()) {
            return None;
        }
    }
    let q = (p.0 + d.0, p.1 + d.1);
    let base = &to.levels[0];
    let inside = q.0 >= 0.0 && q.1 >= 0.0 && q.0 < base.width as f32 && q.1 < base.height as f32;
    inside.then_some(q)
}

/// The apparent motion from `from` to `to`: the median displacement (px) of the corners of
/// `from` tracked into `to` and back to within 0.5 px (forward–backward check), and how many
/// passed. `None` with fewer than 5.
#[must_use]
pub fn apparent_motion(from: &Pyramid, to: &Pyramid) -> Option<(f64, usize)> {
    let mut moved: Vec<f64> = corners(from.base())
        .into_iter()
        .filter_map(|p| {
            let q = track(from, to, p)?;
            let back = track(to, from, q)?;
            let fb = (back.0 - p.0).hypot(back.1 - p.1);
            (fb < 0.5).then(|| f64::from((q.0 - p.0).hypot(q.1 - p.1)))
        })
        .collect();
    if moved.len() < 5 {
        return None;
    }
    moved.sort_by(f64::total_cmp);
    Some((moved[moved.len() / 2], moved.len()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth textured image (sum of sinusoids), shifted by `(sx, sy)`.
    fn texture(w: usize, h: usize, sx: f32, sy: f32) -> Grey {
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f32 - sx, y as f32 - sy);
                let val = 128.0
                    + 40.0 * (0.21 * u).sin() * (0.17 * v).cos()
                    + 30.0 * (0.13 * u + 0.11 * v).sin()
                    + 20.0 * (0.07 * u - 0.19 * v).cos();
                data.push(val);
            }
        }
        Grey {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn a_known_shift_is_measured() {
        for (sx, sy) in [(0.0, 0.0), (1.3, -0.4), (6.2, 3.1), (-11.5, 7.25)] {
            let a = Pyramid::new(texture(320, 240, 0.0, 0.0));
            let b = Pyramid::new(texture(320, 240, sx, sy));
            let (m, n) = apparent_motion(&a, &b).unwrap();
            let truth = f64::from((sx * sx + sy * sy).sqrt());
            assert!(n >= 40, "{n} corners tracked");
            assert!((m - truth).abs() < 0.05, "shift {truth}: measured {m}");
        }
    }

    #[test]
    fn blur_lowers_the_sharpness() {
        // Squares of 4 px: edges a 5-px box blur spreads.
        let sharp = Grey {
            width: 200,
            height: 150,
            data: (0..150 * 200)
                .map(|i| {
                    if ((i % 200) / 4 + (i / 200) / 4) % 2 == 0 {
                        60.0
                    } else {
                        190.0
                    }
                })
                .collect(),
        };
        let mut blurred = sharp.clone();
        for y in 0..150 {
            for x in 2..198 {
                let i = y * 200 + x;
                blurred.data[i] = (sharp.data[i - 2]
                    + sharp.data[i - 1]
                    + sharp.data[i]
                    + sharp.data[i + 1]
                    + sharp.data[i + 2])
                    / 5.0;
            }
        }
        assert!(sharpness(&blurred) < 0.5 * sharpness(&sharp));
    }

    #[test]
    fn a_flat_image_has_no_motion() {
        let flat = Grey {
            width: 100,
            height: 80,
            data: vec![7.0; 8000],
        };
        let p = Pyramid::new(flat);
        assert!(apparent_motion(&p, &p).is_none());
        assert!(Grey::from_bytes(10, 10, &[0; 99]).is_none());
    }
}
