//! Edge pixels: Sobel gradients, a noise estimate for adaptive thresholds, non-maximum
//! suppression along the gradient and hysteresis (Canny 1986), and linking into chains of
//! edge pixels whose gradients agree.

use rayon::prelude::*;

use super::image::GrayImage;

/// Sobel gradients and their L1 magnitude.
#[derive(Clone, Debug)]
pub struct Gradients {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// ∂I/∂u (Sobel, ×8 the slope of a ramp).
    pub gx: Vec<i16>,
    /// ∂I/∂v.
    pub gy: Vec<i16>,
    /// |gx| + |gy|.
    pub mag: Vec<u16>,
}

impl Gradients {
    /// Empty buffers, to be filled by [`sobel_into`].
    #[must_use]
    pub fn empty() -> Self {
        Gradients {
            width: 0,
            height: 0,
            gx: Vec::new(),
            gy: Vec::new(),
            mag: Vec::new(),
        }
    }
}

/// Sobel gradients (border pixels 0), rows in parallel.
#[must_use]
pub fn sobel(img: &GrayImage) -> Gradients {
    let mut g = Gradients::empty();
    sobel_into(img, &mut g);
    g
}

/// [`sobel`] into reused buffers (no page faults on repeated frames of one size).
pub fn sobel_into(img: &GrayImage, g: &mut Gradients) {
    let (w, h) = (img.width, img.height);
    g.width = w;
    g.height = h;
    for v in [&mut g.gx, &mut g.gy] {
        v.resize(w * h, 0);
    }
    g.mag.resize(w * h, 0);
    if w < 3 || h < 3 {
        g.gx.fill(0);
        g.gy.fill(0);
        g.mag.fill(0);
        return;
    }
    g.gx.par_chunks_mut(w)
        .zip(g.gy.par_chunks_mut(w))
        .zip(g.mag.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, ((gx, gy), mag))| {
            if y == 0 || y == h - 1 {
                gx.fill(0);
                gy.fill(0);
                mag.fill(0);
                return;
            }
            let r0 = &img.data[(y - 1) * w..y * w];
            let r1 = &img.data[y * w..(y + 1) * w];
            let r2 = &img.data[(y + 1) * w..(y + 2) * w];
            for x in 1..w - 1 {
                let p = |r: &[u8], k: usize| i16::from(r[k]);
                let dx = (p(r0, x + 1) - p(r0, x - 1))
                    + 2 * (p(r1, x + 1) - p(r1, x - 1))
                    + (p(r2, x + 1) - p(r2, x - 1));
                let dy = (p(r2, x - 1) + 2 * p(r2, x) + p(r2, x + 1))
                    - (p(r0, x - 1) + 2 * p(r0, x) + p(r0, x + 1));
                gx[x] = dx;
                gy[x] = dy;
                mag[x] = dx.unsigned_abs() + dy.unsigned_abs();
            }
            for k in [0, w - 1] {
                gx[k] = 0;
                gy[k] = 0;
                mag[k] = 0;
            }
        });
}

/// Noise σ of the image (grey levels) by Immerkær's method (1996): the mean absolute response
/// to the Laplacian difference mask `[1 −2 1; −2 4 −2; 1 −2 1]`, which cancels smooth
/// structure, on every eighth row.
#[must_use]
pub fn noise_sigma(img: &GrayImage) -> f64 {
    let (w, h) = (img.width, img.height);
    if w < 3 || h < 3 {
        return 0.0;
    }
    let mut sum = 0u64;
    let mut n = 0u64;
    for y in (1..h - 1).step_by(8) {
        let (r0, r1, r2) = (
            &img.data[(y - 1) * w..],
            &img.data[y * w..],
            &img.data[(y + 1) * w..],
        );
        for x in 1..w - 1 {
            let p = |r: &[u8], k: usize| i32::from(r[k]);
            let v = p(r0, x - 1) - 2 * p(r0, x) + p(r0, x + 1)
                - 2 * (p(r1, x - 1) - 2 * p(r1, x) + p(r1, x + 1))
                + p(r2, x - 1)
                - 2 * p(r2, x)
                + p(r2, x + 1);
            sum += v.unsigned_abs() as u64;
            n += 1;
        }
    }
    (std::f64::consts::PI / 2.0).sqrt() * sum as f64 / (6.0 * n as f64)
}

/// Edge flags after non-maximum suppression and thresholds (0 none, 1 weak, 2 strong), and the
/// strong pixels in raster order.
#[must_use]
pub fn suppress(g: &Gradients, low: u16, high: u16) -> (Vec<u8>, Vec<u32>) {
    let mut flags = Vec::new();
    let strong = suppress_into(g, low, high, &mut flags);
    (flags, strong)
}

/// [`suppress`] into a reused flag buffer; returns the strong pixels.
pub fn suppress_into(g: &Gradients, low: u16, high: u16, flags: &mut Vec<u8>) -> Vec<u32> {
    let (w, h) = (g.width, g.height);
    flags.clear();
    flags.resize(w * h, 0);
    if w < 3 || h < 3 {
        return Vec::new();
    }
    let strong: Vec<Vec<u32>> = flags
        .par_chunks_mut(w)
        .enumerate()
        .skip(1)
        .take(h - 2)
        .map(|(y, row)| {
            let mut strong = Vec::new();
            let (up, mid, down) = (
                &g.mag[(y - 1) * w..y * w],
                &g.mag[y * w..(y + 1) * w],
                &g.mag[(y + 1) * w..(y + 2) * w],
            );
            let (gx, gy) = (&g.gx[y * w..(y + 1) * w], &g.gy[y * w..(y + 1) * w]);
            for x in 1..w - 1 {
                let m = mid[x];
                if m < low {
                    continue;
                }
                let (dx, dy) = (i32::from(gx[x]), i32::from(gy[x]));
                // Quantise the gradient direction: tan(22.5°) ≈ 0.4142 ≈ 53/128.
                let (adx, ady) = (dx.abs(), dy.abs());
                let (a, b) = if ady * 128 <= 53 * adx {
                    (mid[x - 1], mid[x + 1])
                } else if adx * 128 <= 53 * ady {
                    (up[x], down[x])
                } else if (dx > 0) == (dy > 0) {
                    (up[x - 1], down[x + 1])
                } else {
                    (up[x + 1], down[x - 1])
                };
                if m > a && m >= b {
                    if m >= high {
                        row[x] = 2;
                        strong.push((y * w + x) as u32);
                    } else {
                        row[x] = 1;
                    }
                }
            }
            strong
        })
        .collect();
    strong.concat()
}

/// Whether two gradients point within 60° of each other.
fn compatible(g: &Gradients, i: usize, j: usize) -> bool {
    let (ax, ay) = (f64::from(g.gx[i]), f64::from(g.gy[i]));
    let (bx, by) = (f64::from(g.gx[j]), f64::from(g.gy[j]));
    let dot = ax * bx + ay * by;
    dot > 0.0 && dot * dot >= 0.25 * (ax * ax + ay * ay) * (bx * bx + by * by)
}

/// Links edge pixels into chains: from each unvisited strong pixel (`strong`, raster order),
/// follow edge pixels (weak or strong) with compatible gradients, each step to the neighbour
/// best aligned with the edge tangent, in both directions. Chains shorter than `min_len` pixels
/// are dropped.
#[must_use]
///
/// Marks visited pixels in `flags` (bit 0x80).
pub fn link(g: &Gradients, flags: &mut [u8], strong: &[u32], min_len: usize) -> Vec<Vec<u32>> {
    const VISITED: u8 = 0x80;
    let (w, h) = (g.width, g.height);
    let mut chains = Vec::new();
    const OFFSETS: [(isize, isize); 8] = [
        (1, 0),
        (1, 1),
        (0, 1),
        (-1, 1),
        (-1, 0),
        (-1, -1),
        (0, -1),
        (1, -1),
    ];
    let step = |flags: &mut [u8], from: usize, sign: f64| -> Option<usize> {
        let (x, y) = ((from % w) as isize, (from / w) as isize);
        // Tangent: the gradient rotated by +90°, times sign.
        let (tx, ty) = (-f64::from(g.gy[from]) * sign, f64::from(g.gx[from]) * sign);
        let mut best: Option<(f64, usize)> = None;
        for (dx, dy) in OFFSETS {
            let (nx, ny) = (x + dx, y + dy);
            if nx < 1 || ny < 1 || nx >= w as isize - 1 || ny >= h as isize - 1 {
                continue;
            }
            let j = ny as usize * w + nx as usize;
            if flags[j] == 0 || flags[j] & VISITED != 0 || !compatible(g, from, j) {
                continue;
            }
            let score = (tx * dx as f64 + ty * dy as f64) / ((dx * dx + dy * dy) as f64).sqrt();
            if score > 0.0 && best.is_none_or(|(s, _)| score > s) {
                best = Some((score, j));
            }
        }
        let next = best.map(|(_, j)| j)?;
        flags[next] |= VISITED;
        Some(next)
    };
    for &start in strong {
        let start = start as usize;
        if flags[start] & VISITED != 0 {
            continue;
        }
        flags[start] |= VISITED;
        let mut forward = vec![start as u32];
        let mut cur = start;
        while let Some(n) = step(flags, cur, 1.0) {
            forward.push(n as u32);
            cur = n;
        }
        let mut backward = Vec::new();
        cur = start;
        while let Some(n) = step(flags, cur, -1.0) {
            backward.push(n as u32);
            cur = n;
        }
        if forward.len() + backward.len() >= min_len {
            backward.reverse();
            backward.extend(forward);
            chains.push(backward);
        }
    }
    chains
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc(w: usize, h: usize, cx: f64, cy: f64, r: f64) -> GrayImage {
        // 4×4 supersampled dark disc on a bright background.
        let mut data = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut inside = 0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let (u, v) = (
                            x as f64 + (sx as f64 + 0.5) / 4.0,
                            y as f64 + (sy as f64 + 0.5) / 4.0,
                        );
                        if (u - cx).powi(2) + (v - cy).powi(2) <= r * r {
                            inside += 1;
                        }
                    }
                }
                data[y * w + x] = (200 - inside * 150 / 16) as u8;
            }
        }
        GrayImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn a_disc_gives_one_closed_chain() {
        let img = disc(80, 60, 40.3, 30.7, 15.0);
        let g = sobel(&img);
        let (mut flags, strong) = suppress(&g, 40, 80);
        let chains = link(&g, &mut flags, &strong, 8);
        assert_eq!(chains.len(), 1, "{} chains", chains.len());
        let c = &chains[0];
        // About the circumference (2π·15 ≈ 94 px), and the chain closes on itself.
        assert!((80..=110).contains(&c.len()), "{} pixels", c.len());
        let (a, b) = (c[0] as usize, c[c.len() - 1] as usize);
        let d = ((a % 80) as i64 - (b % 80) as i64)
            .abs()
            .max((a / 80) as i64 - (b / 80) as i64);
        assert!(d <= 2, "ends {a} {b}");
    }

    #[test]
    fn noise_sigma_of_a_flat_noisy_image() {
        // Uniform noise in ±k has σ = k/√3: 0..=12 around 100 → σ = √((13² − 1)/12) = 3.74.
        let mut seed = 7u64;
        let data = (0..200 * 200)
            .map(|_| {
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (94 + (seed >> 33) % 13) as u8
            })
            .collect();
        let s = noise_sigma(&GrayImage {
            width: 200,
            height: 200,
            data,
        });
        // Immerkær's estimator assumes Gaussian noise; for uniform noise it reads ~8 % low.
        assert!((s - 3.74).abs() < 0.45, "σ {s}");
        assert_eq!(
            noise_sigma(&GrayImage {
                width: 2,
                height: 2,
                data: vec![0; 4]
            }),
            0.0
        );
    }
}
