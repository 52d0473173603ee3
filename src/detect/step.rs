//! The grey-level model of a disc target around its fitted ellipse, and the appearance tests
//! that tell a printed disc from other round things.
//!
//! A printed disc seen by a camera is a step between two flat grey levels blurred by the lens,
//! the motion and the pixels: across its edge the grey level follows
//!
//! ```text
//! I(t) = L_out + (L_in − L_out)·Φ(−(t − δ)/w)
//! ```
//!
//! with `t` the signed distance along the outward normal of the fitted ellipse, `Φ` the standard
//! normal distribution function, `w` the edge width (the σ of a Gaussian blur) and `δ` where the
//! step lies relative to the fitted edge. This is the blurred-step edge model of subpixel edge
//! estimation (Ye, Fu & Poudel 2005, "High-accuracy edge detection with blurred edge model",
//! Image and Vision Computing 23: 453–467); for a disc of radius R blurred by σ it fits the exact
//! profile (a Rice integral) to better than 1 % of the contrast down to R/σ ≈ 2.
//!
//! The model is fitted (Levenberg–Marquardt, four parameters) to the median of the grey
//! profiles along the normals, which ignores a neighbour that intrudes on a few of them. Then:
//!
//! * the **step residual** — RMS of the median profile about the model, relative to the contrast —
//!   is small for a disc and large for a shaded dome (a screw head, a rivet: no flat interior, a
//!   highlight or a rim) or anything whose profile is not one step;
//! * the **surround spread** — how the surround's level varies around the disc, in a ring from
//!   two edge widths beyond the edge, about a plane (a lighting gradient), where the surround
//!   shows (things of the disc's own polarity — a neighbour of a dense grid, a coded target's
//!   ring, a plate's border — are left out) — is small on the paper around a printed disc and
//!   large on textured ground or beside a shadow;
//! * the **interior spread** — RMS of the grey levels deeper than two edge widths and 1.5 px,
//!   less the surround's lighting gradient scaled by the ratio of the two levels (the same light
//!   on a different reflectance), relative to the contrast — is small for a uniform disc and
//!   large where the "interior" holds something else (the centre dot inside an arc of a coded
//!   target's ring, a dome's shading and highlight);
//! * the **edge width** `w` sets the sub-pixel search's window and tells an unresolved spot
//!   (semi-minor axis under two edge widths) from a disc.

use nalgebra::{Matrix3, Matrix4, Vector2, Vector3, Vector4};

use super::image::GrayImage;
use crate::geometry::conic::Ellipse;

/// Step of the samples along each normal (px).
const STEP_PX: f64 = 0.5;
/// Samples beyond the edge's two widths that make the outer plateau of the fitted window (px).
const PLATEAU_PX: f64 = 1.0;
/// Width of the ring outside the edge whose uniformity is measured: half the semi-minor axis,
/// 1 to 3 px.
fn ring_width(e: &Ellipse) -> f64 {
    (0.5 * e.b).clamp(1.0, 3.0)
}
/// How much deeper than two edge widths the interior's samples begin (px). The ringing of
/// sharpening and of JPEG/H.264 blocks inside a small dark dot reaches about 2 px past the
/// edge's blur.
const INTERIOR_MARGIN_PX: f64 = 1.5;
/// Smallest and largest edge width the fit may take (px).
const WIDTH_RANGE: (f64, f64) = (0.15, 25.0);

/// Complementary error function, by the Chebyshev-based fit `erfcc` of Press et al., *Numerical
/// Recipes in C* (2nd ed., 1992), §6.2: fractional error below 1.2·10⁻⁷ everywhere.
#[must_use]
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let r = t * poly.exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

/// The standard normal distribution function Φ(x) = erfc(−x/√2)/2.
#[must_use]
pub fn normal_cdf(x: f64) -> f64 {
    0.5 * erfc(-x * std::f64::consts::FRAC_1_SQRT_2)
}

/// The standard normal density φ(x).
fn normal_pdf(x: f64) -> f64 {
    (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

/// The blurred step fitted across the edge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepFit {
    /// Grey level inside the disc.
    pub inside: f64,
    /// Grey level outside.
    pub outside: f64,
    /// Edge width: σ of the Gaussian blur across the edge (px).
    pub width_px: f64,
    /// Position of the step along the outward normal, relative to the fitted ellipse (px).
    pub offset_px: f64,
    /// RMS of the median profile about the model over the fitted window, relative to the
    /// contrast.
    pub residual: f64,
}

impl StepFit {
    /// Grey-level difference outside − inside (positive for a dark disc).
    #[must_use]
    pub fn contrast(&self) -> f64 {
        self.outside - self.inside
    }

    /// The model's grey level at `t` px along the outward normal.
    #[must_use]
    pub fn level(&self, t: f64) -> f64 {
        self.outside
            + (self.inside - self.outside) * normal_cdf(-(t - self.offset_px) / self.width_px)
    }
}

/// What the grey levels around a fitted ellipse look like.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Appearance {
    /// The blurred step across the edge.
    pub step: StepFit,
    /// RMS of the interior (deeper than two edge widths and 1.5 px) less the lighting gradient,
    /// relative to the contrast; `None` when the disc is too small or too blurred to have such
    /// an interior.
    pub interior_spread: Option<f64>,
    /// Spread of the surround's level (from two edge widths beyond the edge, half the
    /// semi-minor axis wide, 1–3 px) about a plane, where the surround shows, relative to the
    /// contrast.
    pub ring_spread: f64,
}

/// Grey profiles along the normals of an ellipse: `values[k][j]` at normal `k` and offset
/// `t0 + j·STEP_PX` (`NaN` where the image ends).
struct Profiles {
    t0: f64,
    points: Vec<Vector2<f64>>,
    normals: Vec<Vector2<f64>>,
    values: Vec<Vec<f64>>,
}

impl Profiles {
    fn t(&self, j: usize) -> f64 {
        self.t0 + j as f64 * STEP_PX
    }
}

/// Samples `count` normal profiles of `e` over `[t_lo, t_hi]`.
fn sample(img: &GrayImage, e: &Ellipse, count: usize, t_lo: f64, t_hi: f64) -> Profiles {
    let n = ((t_hi - t_lo) / STEP_PX).floor() as usize + 1;
    let (s, c) = e.theta.sin_cos();
    let mut out = Profiles {
        t0: t_lo,
        points: Vec::with_capacity(count),
        normals: Vec::with_capacity(count),
        values: Vec::with_capacity(count),
    };
    for k in 0..count {
        let phi = std::f64::consts::TAU * (k as f64 + 0.5) / count as f64;
        let (nx, ny) = (e.b * phi.cos(), e.a * phi.sin());
        let nn = (nx * nx + ny * ny).sqrt().max(1e-300);
        let nrm = Vector2::new(c * nx - s * ny, s * nx + c * ny) / nn;
        let p = e.point(phi);
        let row = (0..n)
            .map(|j| {
                let q = p + nrm * (t_lo + j as f64 * STEP_PX);
                img.bicubic(q.x, q.y).unwrap_or(f64::NAN)
            })
            .collect();
        out.points.push(p);
        out.normals.push(nrm);
        out.values.push(row);
    }
    out
}

/// Median of the finite values, `None` if fewer than half of `total` are finite.
fn median_finite(v: &mut Vec<f64>, total: usize) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.len() * 2 < total || v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    })
}

/// Levenberg–Marquardt fit of the blurred step to `(t, y)` samples from `start`.
fn fit_step(t: &[f64], y: &[f64], start: StepFit) -> Option<StepFit> {
    let residuals = |p: &Vector4<f64>| -> (f64, Matrix4<f64>, Vector4<f64>) {
        let (mut ss, mut n, mut g) = (0.0, Matrix4::zeros(), Vector4::zeros());
        for (&ti, &yi) in t.iter().zip(y) {
            let z = (ti - p[3]) / p[2];
            let f = normal_cdf(-z);
            let d = p[0] - p[1];
            let r = p[1] + d * f - yi;
            let pdf = normal_pdf(z);
            let j = Vector4::new(f, 1.0 - f, d * pdf * z / p[2], d * pdf / p[2]);
            ss += r * r;
            n += j * j.transpose();
            g += j * r;
        }
        (ss, n, g)
    };
    let mut p = Vector4::new(start.inside, start.outside, start.width_px, start.offset_px);
    let (mut ss, mut n, mut g) = residuals(&p);
    let mut lambda = 1e-3;
    for _ in 0..30 {
        let mut damped = n;
        for k in 0..4 {
            damped[(k, k)] += lambda * n[(k, k)].max(1e-12);
        }
        let Some(inv) = damped.try_inverse() else {
            lambda *= 10.0;
            continue;
        };
        let mut next = p - inv * g;
        next[2] = next[2].clamp(WIDTH_RANGE.0, WIDTH_RANGE.1);
        next[3] = next[3].clamp(-4.0 * next[2] - 2.0, 4.0 * next[2] + 2.0);
        let (ss2, n2, g2) = residuals(&next);
        if ss2 <= ss {
            let done = ss - ss2 <= 1e-10 * ss.max(1e-12);
            (p, ss, n, g) = (next, ss2, n2, g2);
            lambda = (lambda * 0.3).max(1e-9);
            if done {
                break;
            }
        } else {
            lambda *= 10.0;
            if lambda > 1e8 {
                break;
            }
        }
    }
    let contrast = (p[1] - p[0]).abs();
    if !(contrast > 0.0 && p.iter().all(|v| v.is_finite())) {
        return None;
    }
    Some(StepFit {
        inside: p[0],
        outside: p[1],
        width_px: p[2],
        offset_px: p[3],
        residual: (ss / t.len() as f64).sqrt() / contrast,
    })
}

/// The spread of the surround's level where the surround shows, and its gradient: per normal,
/// the ring sample reaching furthest beyond the outside level (away from the inside level, in
/// `levels` already multiplied by that sense) stands for that normal's surround; these levels
/// are fitted by a plane in the image (a lighting gradient), three rounds leaving out the
/// normals that lie toward the inside level by more than `tolerance` (there the ring is covered
/// by something of the disc's own polarity: a neighbour of a dense grid, a coded target's ring,
/// the plate's border); the spread is the RMS of the kept normals about the plane. On the paper
/// around a printed disc it is the noise; on textured ground, beside the one-sided shadow of a
/// pin or a glare spot it is not. Returns the spread and the plane's gradient (grey levels per
/// px, in the sense of `levels`).
fn surround_spread(levels: &[(Vector2<f64>, f64)], tolerance: f64) -> (f64, Vector2<f64>) {
    let mut keep: Vec<usize> = (0..levels.len()).collect();
    let mut res = vec![0.0; levels.len()];
    let mut gradient = Vector2::zeros();
    let centre = levels.iter().map(|l| l.0).sum::<Vector2<f64>>() / levels.len().max(1) as f64;
    for _ in 0..3 {
        if keep.len() < 4 {
            return (0.0, Vector2::zeros());
        }
        let mut a = Matrix3::zeros();
        let mut b = Vector3::zeros();
        for &k in &keep {
            let (p, v) = levels[k];
            let x = Vector3::new(1.0, p.x - centre.x, p.y - centre.y);
            a += x * x.transpose();
            b += x * v;
        }
        let Some(inv) = a.try_inverse() else {
            return (0.0, Vector2::zeros());
        };
        let c = inv * b;
        gradient = Vector2::new(c[1], c[2]);
        for (k, &(p, v)) in levels.iter().enumerate() {
            res[k] = v - (c[0] + gradient.dot(&(p - centre)));
        }
        keep = (0..levels.len())
            .filter(|&k| res[k] >= -tolerance)
            .collect();
    }
    if keep.is_empty() {
        return (0.0, gradient);
    }
    let spread = (keep.iter().map(|&k| res[k] * res[k]).sum::<f64>() / keep.len() as f64).sqrt();
    (spread, gradient)
}

/// Fits the blurred step around `e` and measures the interior and the surround.
/// `contrast0` and `width0` start the fit: the grey-level difference outside − inside and the
/// edge width from the sub-pixel edge search; `noise` is the image's noise σ (grey levels).
/// `None` if the profiles leave the image or no step fits.
#[must_use]
pub fn appearance(
    img: &GrayImage,
    e: &Ellipse,
    contrast0: f64,
    width0: f64,
    noise: f64,
) -> Option<Appearance> {
    let width0 = width0.clamp(0.3, 10.0);
    // Deepest sample inside: short of the ellipse's centre (profiles deeper than b along the
    // minor axis would see the opposite edge).
    let depth = 0.9 * e.b;
    let t_lo = -depth.min(3.0 * width0 + 3.0);
    let t_hi = 3.0 * width0 + PLATEAU_PX + ring_width(e) + 1.0;
    // A normal every 1.5 px of perimeter (Ramanujan's approximation), 32 to 128.
    let perimeter =
        std::f64::consts::PI * (3.0 * (e.a + e.b) - ((3.0 * e.a + e.b) * (e.a + 3.0 * e.b)).sqrt());
    let count = (perimeter / 1.5).round().clamp(32.0, 128.0) as usize;
    let prof = sample(img, e, count, t_lo, t_hi);
    let n = prof.values.first().map_or(0, Vec::len);
    let mut median = Vec::with_capacity(n);
    let mut column = Vec::with_capacity(count);
    for j in 0..n {
        column.clear();
        column.extend(prof.values.iter().map(|row| row[j]));
        median.push(median_finite(&mut column, count)?);
    }
    // Start from the levels two edge widths and half a pixel either side of the edge (not at
    // the window's ends: beyond the outer plateau a neighbour may begin). The window: from two
    // edge widths and 1.5 px inside (never deeper than sampled) to two edge widths and a plateau
    // outside; fitted twice, the second time with the first fit's width and offset.
    let at = |t: f64| median[(((t - t_lo) / STEP_PX).round().max(0.0) as usize).min(n - 1)];
    let mut step = StepFit {
        inside: at(-(2.0 * width0 + 0.5)),
        outside: at(2.0 * width0 + 0.5),
        width_px: width0,
        offset_px: 0.0,
        residual: 0.0,
    };
    if (step.outside - step.inside).abs() < 0.5 * contrast0.abs() {
        step.outside = step.inside + contrast0;
    }
    for _ in 0..2 {
        let lo = (step.offset_px - 2.0 * step.width_px - 1.5).max(t_lo);
        let hi = (step.offset_px + 2.0 * step.width_px + PLATEAU_PX).min(t_hi);
        let (t, y): (Vec<f64>, Vec<f64>) = (0..n)
            .map(|j| (prof.t(j), median[j]))
            .filter(|(t, _)| *t >= lo - 1e-9 && *t <= hi + 1e-9)
            .unzip();
        if t.len() < 5 {
            return None;
        }
        step = fit_step(&t, &y, step)?;
        // A step whose levels lie far outside the samples, or wider than the window, is no
        // step that the samples show.
        let (lo_y, hi_y) = y
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        let slack = 0.25 * (hi_y - lo_y);
        let within = |v: f64| v >= lo_y - slack && v <= hi_y + slack;
        if !(within(step.inside) && within(step.outside)) || step.width_px > 0.5 * (hi - lo) {
            return None;
        }
    }
    let (w, d) = (step.width_px, step.offset_px);
    // The ring outside: from two edge widths and half a pixel beyond the step.
    let (r_lo, r_hi) = (d + 2.0 * w + 0.5, d + 2.0 * w + 0.5 + ring_width(e));
    let sense = step.contrast().signum();
    let ring_levels = |p: &Profiles| -> Vec<(Vector2<f64>, f64)> {
        p.values
            .iter()
            .enumerate()
            .filter_map(|(k, row)| {
                let (best, t) = row
                    .iter()
                    .enumerate()
                    .filter(|&(j, v)| {
                        let t = p.t(j);
                        t >= r_lo - 1e-9 && t <= r_hi + 1e-9 && v.is_finite()
                    })
                    .map(|(j, v)| (sense * v, p.t(j)))
                    .fold(
                        (f64::NEG_INFINITY, 0.0),
                        |a, b| if b.0 > a.0 { b } else { a },
                    );
                best.is_finite()
                    .then(|| (p.points[k] + p.normals[k] * t, best))
            })
            .collect()
    };
    let mut levels = ring_levels(&prof);
    if levels.len() * 2 < count {
        // The ring lies beyond the sampled window: sample it now.
        levels = ring_levels(&sample(img, e, count, r_lo, r_hi));
        if levels.len() * 2 < count {
            return None;
        }
    }
    let contrast = step.contrast().abs();
    let tolerance = 0.1 * contrast + 3.0 * noise;
    let (ring_spread, gradient) = surround_spread(&levels, tolerance);
    let ring_spread = ring_spread / contrast;
    // The light falling on the surround falls on the disc too: inside, the same gradient scaled
    // by the ratio of the two levels (of their reflectances). A dome's shading is no such
    // gradient.
    let inside_gradient = gradient * sense * (step.inside / step.outside).clamp(0.0, 10.0);
    // The interior: concentric ellipses deeper than two edge widths and 1.5 px, sampled about
    // every 1.5 px, and the centre.
    let reach = 1.0 - (2.0 * w + INTERIOR_MARGIN_PX - d).max(0.0) / e.b;
    let interior_spread = (reach > 0.0).then(|| {
        let rings = ((reach * e.b) / 1.5).ceil().clamp(1.0, 6.0) as usize;
        let mut flat = Vec::new();
        let mut take = |q: Vector2<f64>| {
            if let Some(v) = img.bicubic(q.x, q.y) {
                flat.push(v - inside_gradient.dot(&(q - e.centre())));
            }
        };
        take(e.centre());
        for i in 1..=rings {
            let s = reach * i as f64 / rings as f64;
            let m = ((std::f64::consts::TAU * s * e.a / 1.5).ceil() as usize).clamp(8, 96);
            for k in 0..m {
                let phi = std::f64::consts::TAU * (k as f64 + 0.5 * (i % 2) as f64) / m as f64;
                take(e.centre() + (e.point(phi) - e.centre()) * s);
            }
        }
        let n = flat.len().max(1) as f64;
        let mean = flat.iter().sum::<f64>() / n;
        (flat.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt() / contrast
    });
    Some(Appearance {
        step,
        interior_spread,
        ring_spread,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erfc_matches_reference_values() {
        // Abramowitz & Stegun, Table 7.1.
        for (x, v) in [
            (0.0, 1.0),
            (0.5, 0.479_500_122),
            (1.0, 0.157_299_207),
            (2.0, 0.004_677_735),
            (-1.0, 1.842_700_793),
        ] {
            assert!((erfc(x) - v).abs() < 2e-7 * v.max(1e-3), "erfc({x})");
        }
        assert!((normal_cdf(1.959_964) - 0.975).abs() < 1e-7);
    }

    #[test]
    fn step_fit_recovers_an_exact_blurred_step() {
        let truth = StepFit {
            inside: 40.0,
            outside: 200.0,
            width_px: 1.7,
            offset_px: -0.3,
            residual: 0.0,
        };
        let t: Vec<f64> = (0..30).map(|j| -7.0 + 0.5 * f64::from(j)).collect();
        let y: Vec<f64> = t.iter().map(|&t| truth.level(t)).collect();
        let start = StepFit {
            inside: 60.0,
            outside: 180.0,
            width_px: 0.8,
            offset_px: 0.0,
            residual: 0.0,
        };
        let f = fit_step(&t, &y, start).unwrap();
        assert!((f.width_px - 1.7).abs() < 1e-6, "{f:?}");
        assert!((f.offset_px + 0.3).abs() < 1e-6, "{f:?}");
        assert!((f.inside - 40.0).abs() < 1e-5 && (f.outside - 200.0).abs() < 1e-5);
        assert!(f.residual < 1e-7, "{f:?}");
    }
}
