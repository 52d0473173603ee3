//! Conversions between the `brown` model and COLMAP's and OpenCV's cameras (docs/math.md §8).
//!
//! pipemeasure's model maps ideal normalised coordinates to distorted pixels exactly as OpenCV
//! does, so a conversion is **exact** whenever the target model has every non-zero term (checked
//! structurally, then verified: the round trip agrees to 1e-9 px). When it does not, the target
//! model's parameters are fitted by least squares to the source camera's projection of rays
//! through a grid of pixels covering the whole image, and the result carries the maximum and RMS
//! pixel error over a denser grid, so no term is ever dropped silently.

use nalgebra::{DMatrix, DVector, Vector2};
use serde::{Deserialize, Serialize};

use super::brown::{BrownCamera, Intrinsics};

/// COLMAP's camera models (ids as in COLMAP 3.8 `camera_models.h`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "SCREAMING_SNAKE_CASE")]
pub enum ColmapModel {
    /// `f, cx, cy`
    SimplePinhole,
    /// `fx, fy, cx, cy`
    Pinhole,
    /// `f, cx, cy, k`
    SimpleRadial,
    /// `f, cx, cy, k1, k2`
    Radial,
    /// `fx, fy, cx, cy, k1, k2, p1, p2`
    Opencv,
    /// `fx, fy, cx, cy, k1, k2, k3, k4` (equidistant fisheye)
    OpencvFisheye,
    /// `fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6`
    FullOpencv,
    /// `fx, fy, cx, cy, omega`
    Fov,
    /// `f, cx, cy, k`
    SimpleRadialFisheye,
    /// `f, cx, cy, k1, k2`
    RadialFisheye,
    /// `fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, sx1, sy1`
    ThinPrismFisheye,
}

impl ColmapModel {
    /// Every model, in id order.
    pub const ALL: [ColmapModel; 11] = [
        ColmapModel::SimplePinhole,
        ColmapModel::Pinhole,
        ColmapModel::SimpleRadial,
        ColmapModel::Radial,
        ColmapModel::Opencv,
        ColmapModel::OpencvFisheye,
        ColmapModel::FullOpencv,
        ColmapModel::Fov,
        ColmapModel::SimpleRadialFisheye,
        ColmapModel::RadialFisheye,
        ColmapModel::ThinPrismFisheye,
    ];

    /// The models [`brown_from_colmap`] and [`colmap_from_brown`] support, simplest first.
    pub const CONVERTIBLE: [ColmapModel; 6] = [
        ColmapModel::SimplePinhole,
        ColmapModel::Pinhole,
        ColmapModel::SimpleRadial,
        ColmapModel::Radial,
        ColmapModel::Opencv,
        ColmapModel::FullOpencv,
    ];

    /// COLMAP's numeric model id.
    #[must_use]
    pub fn id(self) -> i32 {
        Self::ALL
            .iter()
            .position(|&m| m == self)
            .map_or(-1, |i| i as i32)
    }

    /// The model with COLMAP id `id`.
    #[must_use]
    pub fn from_id(id: i32) -> Option<Self> {
        usize::try_from(id)
            .ok()
            .and_then(|i| Self::ALL.get(i).copied())
    }

    /// COLMAP's model name, e.g. `"SIMPLE_RADIAL"`.
    #[must_use]
    pub fn name(self) -> &'static str {
        [
            "SIMPLE_PINHOLE",
            "PINHOLE",
            "SIMPLE_RADIAL",
            "RADIAL",
            "OPENCV",
            "OPENCV_FISHEYE",
            "FULL_OPENCV",
            "FOV",
            "SIMPLE_RADIAL_FISHEYE",
            "RADIAL_FISHEYE",
            "THIN_PRISM_FISHEYE",
        ][self.id() as usize]
    }

    /// The model called `name` (COLMAP spelling).
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Number of parameters COLMAP stores for the model.
    #[must_use]
    pub fn num_params(self) -> usize {
        [3, 4, 4, 5, 8, 8, 12, 5, 4, 5, 12][self.id() as usize]
    }
}

impl std::fmt::Display for ColmapModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A COLMAP camera: model, image size and parameters in COLMAP's order.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// The model.
    pub model: ColmapModel,
    /// Image width (px).
    pub width: u64,
    /// Image height (px).
    pub height: u64,
    /// Parameters in COLMAP's order (see [`ColmapModel`]).
    pub params: Vec<f64>,
}

/// An OpenCV camera: `K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]` (pixel centres at integers)
/// and the distortion vector `(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]])`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OpencvCamera {
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// The 3×3 camera matrix, row-major.
    pub camera_matrix: [[f64; 3]; 3],
    /// Distortion coefficients: 4, 5, 8 or 12 of them.
    pub dist_coeffs: Vec<f64>,
}

/// The outcome of a conversion: the camera, whether it is exact, and its error over the image.
#[derive(Clone, Debug, PartialEq)]
pub struct Converted<T> {
    /// The converted camera.
    pub camera: T,
    /// True when the target model represents the source exactly.
    pub exact: bool,
    /// Largest pixel distance between the two cameras' projections of one ray over the image.
    pub max_error_px: f64,
    /// RMS of those distances.
    pub rms_error_px: f64,
    /// Source terms the target model lacks (empty when exact).
    pub missing_terms: Vec<&'static str>,
}

/// Why a camera could not be converted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ConvertError {
    /// The COLMAP model is not one of [`ColmapModel::CONVERTIBLE`].
    #[error(
        "COLMAP model {0} cannot be converted (supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV)"
    )]
    UnsupportedModel(ColmapModel),
    /// Wrong number of parameters for the model.
    #[error("COLMAP model {model} takes {expected} parameters, got {got}")]
    ParamCount {
        /// The model.
        model: ColmapModel,
        /// Its parameter count.
        expected: usize,
        /// Parameters given.
        got: usize,
    },
    /// OpenCV distortion vector of an unsupported length.
    #[error(
        "OpenCV distortion vector has {0} coefficients; supported lengths are 4, 5, 8 and 12 \
         (14 adds the tilted-sensor model, which is not supported)"
    )]
    DistortionLength(usize),
    /// The OpenCV camera matrix is not of the form [[fx, 0, cx], [0, fy, cy], [0, 0, 1]].
    #[error("OpenCV camera matrix entry {0} must be {1} (OpenCV's projection ignores skew)")]
    CameraMatrix(&'static str, f64),
    /// A parameter is not finite, or a focal length is not positive.
    #[error("camera parameters must be finite with positive focal lengths")]
    InvalidParameters,
    /// Too few pixels of the image could be undistorted to fit over it.
    #[error(
        "only {valid} of {total} grid pixels could be undistorted: the camera's distortion is not invertible over the image"
    )]
    NotInvertible {
        /// Grid pixels that undistorted.
        valid: usize,
        /// Grid pixels tried.
        total: usize,
    },
}

/// Relative pixel error below which a structurally exact conversion is accepted.
const EXACT_TOLERANCE_PX: f64 = 1e-9;
/// Grid used to fit a model (per side).
const FIT_GRID: usize = 41;
/// Denser grid used to report the error of a conversion (per side).
const CHECK_GRID: usize = 81;

/// The brown projection of a parameter slice in [`super::Term::ALL`] order.
fn brown_project(p: &[f64], xy: &Vector2<f64>) -> Vector2<f64> {
    let i = Intrinsics::from_array([p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9]]);
    i.pixel_from_ideal(xy)
}

/// The generic OpenCV projection: fx, fy, cx, cy (COLMAP convention), then
/// k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4.
fn opencv_project(p: &[f64; 16], xy: &Vector2<f64>) -> Vector2<f64> {
    let (x, y) = (xy.x, xy.y);
    let r2 = x * x + y * y;
    let r4 = r2 * r2;
    let r6 = r4 * r2;
    let [
        fx,
        fy,
        cx,
        cy,
        k1,
        k2,
        p1,
        p2,
        k3,
        k4,
        k5,
        k6,
        s1,
        s2,
        s3,
        s4,
    ] = *p;
    let radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
    let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r4;
    let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + s3 * r2 + s4 * r4;
    Vector2::new(fx * xd + cx, fy * yd + cy)
}

/// The 16 generic OpenCV parameters of a supported COLMAP camera.
fn generic_from_colmap(model: ColmapModel, p: &[f64]) -> Result<[f64; 16], ConvertError> {
    let mut g = [0.0; 16];
    match model {
        ColmapModel::SimplePinhole => g[..4].copy_from_slice(&[p[0], p[0], p[1], p[2]]),
        ColmapModel::Pinhole => g[..4].copy_from_slice(&p[..4]),
        ColmapModel::SimpleRadial => {
            g[..5].copy_from_slice(&[p[0], p[0], p[1], p[2], p[3]]);
        }
        ColmapModel::Radial => g[..6].copy_from_slice(&[p[0], p[0], p[1], p[2], p[3], p[4]]),
        ColmapModel::Opencv => g[..8].copy_from_slice(&p[..8]),
        ColmapModel::FullOpencv => g[..12].copy_from_slice(&p[..12]),
        other => return Err(ConvertError::UnsupportedModel(other)),
    }
    Ok(g)
}

/// COLMAP parameters from the generic vector (terms the model lacks are simply not read).
fn colmap_from_generic(model: ColmapModel, g: &[f64; 16]) -> Vec<f64> {
    match model {
        ColmapModel::SimplePinhole => vec![g[0], g[2], g[3]],
        ColmapModel::Pinhole => g[..4].to_vec(),
        ColmapModel::SimpleRadial => vec![g[0], g[2], g[3], g[4]],
        ColmapModel::Radial => vec![g[0], g[2], g[3], g[4], g[5]],
        ColmapModel::Opencv => g[..8].to_vec(),
        _ => g[..12].to_vec(),
    }
}

/// Indices into the generic vector that a COLMAP model can vary when fitted, and how to tie them.
fn colmap_free(model: ColmapModel) -> (&'static [usize], bool) {
    // (free generic indices, fx tied to fy)
    match model {
        ColmapModel::SimplePinhole => (&[0, 2, 3], true),
        ColmapModel::Pinhole => (&[0, 1, 2, 3], false),
        ColmapModel::SimpleRadial => (&[0, 2, 3, 4], true),
        ColmapModel::Radial => (&[0, 2, 3, 4, 5], true),
        ColmapModel::Opencv => (&[0, 1, 2, 3, 4, 5, 6, 7], false),
        _ => (&[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11], false),
    }
}

/// Which brown terms a COLMAP model lacks for this camera (names), empty when exact.
fn missing_in_colmap(model: ColmapModel, i: &Intrinsics) -> Vec<&'static str> {
    let mut missing = Vec::new();
    let mut need = |present: bool, value: f64, name: &'static str| {
        if !present && value != 0.0 {
            missing.push(name);
        }
    };
    let (has_b1, has_k1, has_k2, has_p, has_k3) = match model {
        ColmapModel::SimplePinhole => (false, false, false, false, false),
        ColmapModel::Pinhole => (true, false, false, false, false),
        ColmapModel::SimpleRadial => (false, true, false, false, false),
        ColmapModel::Radial => (false, true, true, false, false),
        ColmapModel::Opencv => (true, true, true, true, false),
        _ => (true, true, true, true, true),
    };
    need(has_b1, i.b1, "b1");
    need(false, i.b2, "b2");
    need(has_k1, i.k1, "k1");
    need(has_k2, i.k2, "k2");
    need(has_k3, i.k3, "k3");
    need(has_p, i.p1, "p1");
    need(has_p, i.p2, "p2");
    missing
}

/// Generic OpenCV parameters of a brown camera that has no shear (b2 is dropped here; callers
/// fit when it is non-zero).
fn generic_from_brown(i: &Intrinsics) -> [f64; 16] {
    let mut g = [0.0; 16];
    g[..9].copy_from_slice(&[i.c + i.b1, i.c, i.u0, i.v0, i.k1, i.k2, i.p1, i.p2, i.k3]);
    g
}

/// Pixels of a `n × n` grid spanning the whole image, corners included.
fn grid(width: f64, height: f64, n: usize) -> impl Iterator<Item = Vector2<f64>> {
    (0..n).flat_map(move |r| {
        (0..n).map(move |c| {
            Vector2::new(
                width * c as f64 / (n - 1) as f64,
                height * r as f64 / (n - 1) as f64,
            )
        })
    })
}

/// Ideal normalised coordinates of a pixel under any lens, by Newton's method with a numeric
/// Jacobian, starting from the pinhole guess.
fn ideal_from_pixel_numeric(
    project: &dyn Fn(&Vector2<f64>) -> Vector2<f64>,
    uv: &Vector2<f64>,
    guess: Vector2<f64>,
) -> Option<Vector2<f64>> {
    let mut xy = guess;
    for _ in 0..60 {
        let f = project(&xy) - uv;
        if f.norm() < 1e-11 {
            return Some(xy);
        }
        let h = 1e-7;
        let jx = (project(&(xy + Vector2::new(h, 0.0))) - project(&(xy - Vector2::new(h, 0.0))))
            / (2.0 * h);
        let jy = (project(&(xy + Vector2::new(0.0, h))) - project(&(xy - Vector2::new(0.0, h))))
            / (2.0 * h);
        let j = nalgebra::Matrix2::from_columns(&[jx, jy]);
        let step = j.try_inverse()? * f;
        xy -= step;
        if !xy.iter().all(|v| v.is_finite()) {
            return None;
        }
    }
    None
}

/// A ray (ideal normalised coordinates) and the pixel the source camera projects it to.
type Ray = (Vector2<f64>, Vector2<f64>);
/// A projection of ideal normalised coordinates with a parameter vector.
type ParamProjection<'a> = &'a dyn Fn(&[f64], &Vector2<f64>) -> Vector2<f64>;

/// Rays of a grid over the image with the source's pixels: `(xy, uv)`.
fn rays(
    project: &dyn Fn(&Vector2<f64>) -> Vector2<f64>,
    unproject: &dyn Fn(&Vector2<f64>) -> Option<Vector2<f64>>,
    width: f64,
    height: f64,
    n: usize,
) -> Result<Vec<Ray>, ConvertError> {
    let total = n * n;
    let out: Vec<_> = grid(width, height, n)
        .filter_map(|uv| {
            let xy = unproject(&uv)?;
            // Keep only rays that really re-project onto their pixel.
            ((project(&xy) - uv).norm() < 1e-6).then_some((xy, uv))
        })
        .collect();
    // Fitting needs the image essentially covered: allow a few corner pixels to fail.
    if out.len() * 10 < total * 9 {
        return Err(ConvertError::NotInvertible {
            valid: out.len(),
            total,
        });
    }
    Ok(out)
}

/// Max and RMS of `|project(xy) − uv|` over rays.
fn errors(project: &dyn Fn(&Vector2<f64>) -> Vector2<f64>, rays: &[Ray]) -> (f64, f64) {
    let mut max: f64 = 0.0;
    let mut sum = 0.0;
    for (xy, uv) in rays {
        let e = (project(xy) - uv).norm();
        max = max.max(e);
        sum += e * e;
    }
    (max, (sum / rays.len().max(1) as f64).sqrt())
}

/// Levenberg–Marquardt on `params[free]` minimising `Σ |project(params, xy) − uv|²`, with
/// numeric Jacobians (conversions are offline and small: ≤ 12 parameters, ≤ 1681 rays).
/// `tie` lists pairs `(dst, src)` of indices kept equal (fx = fy in single-focal models).
fn fit(
    project: ParamProjection<'_>,
    mut params: Vec<f64>,
    free: &[usize],
    tie: &[(usize, usize)],
    rays: &[Ray],
) -> Vec<f64> {
    let apply_ties = |p: &mut Vec<f64>| {
        for &(dst, src) in tie {
            p[dst] = p[src];
        }
    };
    apply_ties(&mut params);
    let residuals = |p: &[f64]| -> DVector<f64> {
        let mut r = DVector::zeros(2 * rays.len());
        for (k, (xy, uv)) in rays.iter().enumerate() {
            let e = project(p, xy) - uv;
            r[2 * k] = e.x;
            r[2 * k + 1] = e.y;
        }
        r
    };
    let mut r = residuals(&params);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..200 {
        let mut jac = DMatrix::zeros(r.len(), free.len());
        for (col, &idx) in free.iter().enumerate() {
            let h = 1e-7 * params[idx].abs().max(1e-3);
            let mut plus = params.clone();
            plus[idx] += h;
            apply_ties(&mut plus);
            let mut minus = params.clone();
            minus[idx] -= h;
            apply_ties(&mut minus);
            let d = (residuals(&plus) - residuals(&minus)) / (2.0 * h);
            jac.set_column(col, &d);
        }
        let jtj = jac.transpose() * &jac;
        let jtr = jac.transpose() * &r;
        let mut improved = false;
        for _ in 0..20 {
            let mut a = jtj.clone();
            for k in 0..free.len() {
                a[(k, k)] += lambda * jtj[(k, k)].max(1e-300);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = params.clone();
            for (col, &idx) in free.iter().enumerate() {
                trial[idx] -= step[col];
            }
            apply_ties(&mut trial);
            let rt = residuals(&trial);
            let ct = rt.norm_squared();
            if ct < cost {
                let converged = (cost - ct) <= 1e-15 * cost.max(1e-30);
                params = trial;
                r = rt;
                cost = ct;
                lambda = (lambda * 0.3).max(1e-12);
                improved = !converged;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    params
}

fn check_camera_size(width: u64, height: u64) -> Result<(f64, f64), ConvertError> {
    if width == 0 || height == 0 {
        return Err(ConvertError::InvalidParameters);
    }
    Ok((width as f64, height as f64))
}

/// Converts a `brown` camera to a COLMAP camera of the given model.
///
/// # Errors
///
/// [`ConvertError::UnsupportedModel`] for a model outside [`ColmapModel::CONVERTIBLE`];
/// [`ConvertError::InvalidParameters`] or [`ConvertError::NotInvertible`] for a camera that
/// cannot be fitted over its image.
pub fn colmap_from_brown(
    cam: &BrownCamera,
    model: ColmapModel,
) -> Result<Converted<ColmapCamera>, ConvertError> {
    if !ColmapModel::CONVERTIBLE.contains(&model) {
        return Err(ConvertError::UnsupportedModel(model));
    }
    let i = &cam.intrinsics;
    if !i.is_valid() {
        return Err(ConvertError::InvalidParameters);
    }
    let (w, h) = check_camera_size(u64::from(cam.width), u64::from(cam.height))?;
    let missing = missing_in_colmap(model, i);
    let source = |xy: &Vector2<f64>| i.pixel_from_ideal(xy);
    let mut generic = generic_from_brown(i);
    if !missing.is_empty() {
        let unproject = |uv: &Vector2<f64>| i.ideal_from_pixel(uv).ok();
        let fit_rays = rays(&source, &unproject, w, h, FIT_GRID)?;
        let (free, tie_f) = colmap_free(model);
        if tie_f {
            generic[0] = i.c;
            generic[1] = i.c;
        }
        let ties: &[(usize, usize)] = if tie_f { &[(1, 0)] } else { &[] };
        // Zero what the model cannot hold, then fit what it can.
        let mut start = [0.0; 16];
        for &k in free {
            start[k] = generic[k];
        }
        let project = |p: &[f64], xy: &Vector2<f64>| {
            let mut g = [0.0; 16];
            g.copy_from_slice(p);
            opencv_project(&g, xy)
        };
        let fitted = fit(&project, start.to_vec(), free, ties, &fit_rays);
        generic.copy_from_slice(&fitted);
    }
    let target = |xy: &Vector2<f64>| opencv_project(&generic, xy);
    let unproject = |uv: &Vector2<f64>| i.ideal_from_pixel(uv).ok();
    let check = rays(&source, &unproject, w, h, CHECK_GRID)?;
    let (max_error_px, rms_error_px) = errors(&target, &check);
    Ok(Converted {
        camera: ColmapCamera {
            model,
            width: u64::from(cam.width),
            height: u64::from(cam.height),
            params: colmap_from_generic(model, &generic),
        },
        exact: missing.is_empty() && max_error_px <= EXACT_TOLERANCE_PX,
        max_error_px,
        rms_error_px,
        missing_terms: missing,
    })
}

/// The simplest COLMAP model that represents the camera exactly, or FULL_OPENCV (fitted, with
/// its error reported) when none does.
#[must_use]
pub fn simplest_colmap_model(cam: &BrownCamera) -> ColmapModel {
    ColmapModel::CONVERTIBLE
        .into_iter()
        .find(|&m| missing_in_colmap(m, &cam.intrinsics).is_empty())
        .unwrap_or(ColmapModel::FullOpencv)
}

fn check_generic(g: &[f64; 16]) -> Result<(), ConvertError> {
    if g.iter().all(|v| v.is_finite()) && g[0] > 0.0 && g[1] > 0.0 {
        Ok(())
    } else {
        Err(ConvertError::InvalidParameters)
    }
}

/// Converts a generic OpenCV-style lens to `brown`: exact without rational or thin-prism terms,
/// fitted otherwise.
fn brown_from_generic(
    g: &[f64; 16],
    width: u32,
    height: u32,
) -> Result<Converted<BrownCamera>, ConvertError> {
    check_generic(g)?;
    let (w, h) = check_camera_size(u64::from(width), u64::from(height))?;
    let names = ["k4", "k5", "k6", "s1", "s2", "s3", "s4"];
    let missing: Vec<&'static str> = (9..16)
        .filter(|&k| g[k] != 0.0)
        .map(|k| names[k - 9])
        .collect();
    let [fx, fy, cx, cy, k1, k2, p1, p2, k3, ..] = *g;
    let mut intrinsics = Intrinsics {
        c: fy,
        u0: cx,
        v0: cy,
        k1,
        k2,
        k3,
        p1,
        p2,
        b1: fx - fy,
        b2: 0.0,
    };
    let source = |xy: &Vector2<f64>| opencv_project(g, xy);
    let unproject = |uv: &Vector2<f64>| {
        ideal_from_pixel_numeric(
            &source,
            uv,
            Vector2::new((uv.x - cx) / fx, (uv.y - cy) / fy),
        )
    };
    if !missing.is_empty() {
        let fit_rays = rays(&source, &unproject, w, h, FIT_GRID)?;
        let free = [0, 1, 2, 3, 4, 5, 6, 7, 8];
        let fitted = fit(
            &brown_project,
            intrinsics.to_array().to_vec(),
            &free,
            &[],
            &fit_rays,
        );
        let mut a = [0.0; 10];
        a.copy_from_slice(&fitted);
        intrinsics = Intrinsics::from_array(a);
    }
    let check = rays(&source, &unproject, w, h, CHECK_GRID)?;
    let target = |xy: &Vector2<f64>| intrinsics.pixel_from_ideal(xy);
    let (max_error_px, rms_error_px) = errors(&target, &check);
    Ok(Converted {
        camera: BrownCamera {
            width,
            height,
            intrinsics,
        },
        exact: missing.is_empty() && max_error_px <= EXACT_TOLERANCE_PX,
        max_error_px,
        rms_error_px,
        missing_terms: missing,
    })
}

/// Converts a COLMAP camera to `brown`.
///
/// # Errors
///
/// [`ConvertError::UnsupportedModel`], [`ConvertError::ParamCount`],
/// [`ConvertError::InvalidParameters`] (non-finite or non-positive focal length, image size
/// zero or beyond `u32`), [`ConvertError::NotInvertible`].
pub fn brown_from_colmap(cam: &ColmapCamera) -> Result<Converted<BrownCamera>, ConvertError> {
    if !ColmapModel::CONVERTIBLE.contains(&cam.model) {
        return Err(ConvertError::UnsupportedModel(cam.model));
    }
    if cam.params.len() != cam.model.num_params() {
        return Err(ConvertError::ParamCount {
            model: cam.model,
            expected: cam.model.num_params(),
            got: cam.params.len(),
        });
    }
    let g = generic_from_colmap(cam.model, &cam.params)?;
    let width = u32::try_from(cam.width).map_err(|_| ConvertError::InvalidParameters)?;
    let height = u32::try_from(cam.height).map_err(|_| ConvertError::InvalidParameters)?;
    brown_from_generic(&g, width, height)
}

/// Converts a `brown` camera to OpenCV's camera matrix and 5-coefficient distortion vector
/// `(k1, k2, p1, p2, k3)`, fitting when the camera has shear (b2), which OpenCV's projection
/// ignores.
///
/// # Errors
///
/// [`ConvertError::InvalidParameters`], [`ConvertError::NotInvertible`].
pub fn opencv_from_brown(cam: &BrownCamera) -> Result<Converted<OpencvCamera>, ConvertError> {
    let c = colmap_from_brown(cam, ColmapModel::FullOpencv)?;
    let p = &c.camera.params;
    Ok(Converted {
        camera: OpencvCamera {
            width: cam.width,
            height: cam.height,
            camera_matrix: [
                [p[0], 0.0, p[2] - 0.5],
                [0.0, p[1], p[3] - 0.5],
                [0.0, 0.0, 1.0],
            ],
            dist_coeffs: vec![p[4], p[5], p[6], p[7], p[8]],
        },
        exact: c.exact,
        max_error_px: c.max_error_px,
        rms_error_px: c.rms_error_px,
        missing_terms: c.missing_terms,
    })
}

/// Converts an OpenCV camera to `brown`: exact for 4 or 5 coefficients (or longer vectors whose
/// extra terms are zero), fitted for rational (k4–k6) and thin-prism (s1–s4) terms.
///
/// # Errors
///
/// [`ConvertError::DistortionLength`], [`ConvertError::CameraMatrix`] for a skew or a malformed
/// last row, [`ConvertError::InvalidParameters`], [`ConvertError::NotInvertible`].
pub fn brown_from_opencv(cam: &OpencvCamera) -> Result<Converted<BrownCamera>, ConvertError> {
    let k = &cam.camera_matrix;
    let fixed = [
        ("K[0][1]", k[0][1], 0.0),
        ("K[1][0]", k[1][0], 0.0),
        ("K[2][0]", k[2][0], 0.0),
        ("K[2][1]", k[2][1], 0.0),
        ("K[2][2]", k[2][2], 1.0),
    ];
    for (name, got, want) in fixed {
        if got != want {
            return Err(ConvertError::CameraMatrix(name, want));
        }
    }
    let d = &cam.dist_coeffs;
    if ![4, 5, 8, 12].contains(&d.len()) {
        return Err(ConvertError::DistortionLength(d.len()));
    }
    let mut g = [0.0; 16];
    g[..4].copy_from_slice(&[k[0][0], k[1][1], k[0][2] + 0.5, k[1][2] + 0.5]);
    g[4..4 + d.len()].copy_from_slice(d);
    brown_from_generic(&g, cam.width, cam.height)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(i: Intrinsics) -> BrownCamera {
        BrownCamera {
            width: 3840,
            height: 2160,
            intrinsics: i,
        }
    }

    fn full() -> Intrinsics {
        Intrinsics {
            c: 3050.0,
            u0: 1931.4,
            v0: 1074.6,
            k1: 0.0125,
            k2: -0.0094,
            k3: 0.004,
            p1: 1.6e-4,
            p2: -2.1e-4,
            b1: 0.8,
            b2: 0.0,
        }
    }

    /// Max pixel distance between two brown cameras over the image.
    fn brown_distance(a: &BrownCamera, b: &BrownCamera) -> f64 {
        grid(f64::from(a.width), f64::from(a.height), 33)
            .map(|uv| {
                let xy = a.intrinsics.ideal_from_pixel(&uv).unwrap();
                (b.intrinsics.pixel_from_ideal(&xy) - uv).norm()
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn model_ids_and_names_round_trip() {
        for m in ColmapModel::ALL {
            assert_eq!(ColmapModel::from_id(m.id()), Some(m));
            assert_eq!(ColmapModel::from_name(m.name()), Some(m));
        }
        assert_eq!(ColmapModel::SimpleRadial.id(), 2);
        assert_eq!(ColmapModel::FullOpencv.id(), 6);
        assert_eq!(ColmapModel::from_id(11), None);
    }

    #[test]
    fn each_model_round_trips_exactly_when_it_can_represent_the_camera() {
        let cases = [
            (
                ColmapModel::SimplePinhole,
                Intrinsics::pinhole(3000.0, 1920.5, 1079.25),
            ),
            (
                ColmapModel::Pinhole,
                Intrinsics {
                    b1: 2.5,
                    ..Intrinsics::pinhole(3000.0, 1921.0, 1080.0)
                },
            ),
            (
                ColmapModel::SimpleRadial,
                Intrinsics {
                    k1: -0.02,
                    ..Intrinsics::pinhole(2900.0, 1900.0, 1090.0)
                },
            ),
            (
                ColmapModel::Radial,
                Intrinsics {
                    k1: -0.02,
                    k2: 0.01,
                    ..Intrinsics::pinhole(2900.0, 1900.0, 1090.0)
                },
            ),
            (ColmapModel::Opencv, Intrinsics { k3: 0.0, ..full() }),
            (ColmapModel::FullOpencv, full()),
        ];
        for (model, intrinsics) in cases {
            let cam = camera(intrinsics);
            assert_eq!(simplest_colmap_model(&cam), model);
            let there = colmap_from_brown(&cam, model).unwrap();
            assert!(there.exact, "{model}: {} px", there.max_error_px);
            assert!(
                there.max_error_px < 1e-9,
                "{model}: {} px",
                there.max_error_px
            );
            assert_eq!(there.camera.params.len(), model.num_params());
            let back = brown_from_colmap(&there.camera).unwrap();
            assert!(back.exact);
            assert!(brown_distance(&cam, &back.camera) < 1e-9, "{model}");
        }
    }

    #[test]
    fn opencv_matrix_uses_pixel_centre_origin() {
        let cam = camera(full());
        let cv = opencv_from_brown(&cam).unwrap();
        assert!(cv.exact);
        let k = cv.camera.camera_matrix;
        assert_eq!(k[0][0], 3050.8);
        assert_eq!(k[1][1], 3050.0);
        assert_eq!(k[0][2], 1931.4 - 0.5);
        assert_eq!(k[1][2], 1074.6 - 0.5);
        assert_eq!(
            cv.camera.dist_coeffs,
            vec![0.0125, -0.0094, 1.6e-4, -2.1e-4, 0.004]
        );
        let back = brown_from_opencv(&cv.camera).unwrap();
        assert!(back.exact);
        assert!(brown_distance(&cam, &back.camera) < 1e-9);
    }

    #[test]
    fn dropping_a_term_is_a_reported_fit_not_silent() {
        // k3 = 0.004 moves the corner (r = 0.72) by c·k3·r⁷ ≈ 1.2 px; OPENCV lacks k3.
        let cam = camera(full());
        let fitted = colmap_from_brown(&cam, ColmapModel::Opencv).unwrap();
        assert!(!fitted.exact);
        assert_eq!(fitted.missing_terms, vec!["k3"]);
        // The fit absorbs most of it but not all: error between 1e-4 px and the raw effect.
        assert!(
            fitted.max_error_px > 1e-4 && fitted.max_error_px < 1.2,
            "{}",
            fitted.max_error_px
        );
        // And the raw truncation (just dropping k3) is much worse than the fit.
        let mut dropped = full();
        dropped.k3 = 0.0;
        let raw = brown_distance(&cam, &camera(dropped));
        assert!(
            raw > 3.0 * fitted.max_error_px,
            "raw {raw} vs fit {}",
            fitted.max_error_px
        );
    }

    #[test]
    fn shear_is_fitted_for_colmap_and_opencv() {
        let cam = camera(Intrinsics { b2: 0.5, ..full() });
        let c = colmap_from_brown(&cam, ColmapModel::FullOpencv).unwrap();
        assert!(!c.exact);
        assert_eq!(c.missing_terms, vec!["b2"]);
        // Shear of 0.5 px per unit yd: at most 0.5·0.36 = 0.18 px at the top and bottom edges.
        assert!(
            c.max_error_px < 0.19 && c.max_error_px > 0.0,
            "{}",
            c.max_error_px
        );
        let cv = opencv_from_brown(&cam).unwrap();
        assert!(!cv.exact && cv.missing_terms == vec!["b2"]);
    }

    #[test]
    fn rational_opencv_terms_are_fitted_into_brown() {
        let cv = OpencvCamera {
            width: 3840,
            height: 2160,
            camera_matrix: [
                [3000.0, 0.0, 1919.5],
                [0.0, 3000.0, 1079.5],
                [0.0, 0.0, 1.0],
            ],
            dist_coeffs: vec![0.02, -0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0],
        };
        let b = brown_from_opencv(&cv).unwrap();
        assert!(!b.exact);
        assert_eq!(b.missing_terms, vec!["k4"]);
        assert!(b.max_error_px < 0.5, "{}", b.max_error_px);
        // Zero rational terms are exact.
        let cv0 = OpencvCamera {
            dist_coeffs: vec![0.02, -0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            ..cv
        };
        let b0 = brown_from_opencv(&cv0).unwrap();
        assert!(b0.exact && b0.max_error_px < 1e-9);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let cv = OpencvCamera {
            width: 640,
            height: 480,
            camera_matrix: [[500.0, 1.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]],
            dist_coeffs: vec![0.0; 5],
        };
        assert_eq!(
            brown_from_opencv(&cv),
            Err(ConvertError::CameraMatrix("K[0][1]", 0.0))
        );
        let cv = OpencvCamera {
            camera_matrix: [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]],
            dist_coeffs: vec![0.0; 6],
            ..cv
        };
        assert_eq!(
            brown_from_opencv(&cv),
            Err(ConvertError::DistortionLength(6))
        );
        let fisheye = ColmapCamera {
            model: ColmapModel::OpencvFisheye,
            width: 10,
            height: 10,
            params: vec![1.0; 8],
        };
        assert_eq!(
            brown_from_colmap(&fisheye),
            Err(ConvertError::UnsupportedModel(ColmapModel::OpencvFisheye))
        );
        let short = ColmapCamera {
            model: ColmapModel::Radial,
            width: 10,
            height: 10,
            params: vec![1.0; 3],
        };
        assert!(matches!(
            brown_from_colmap(&short),
            Err(ConvertError::ParamCount { .. })
        ));
        let nan = ColmapCamera {
            model: ColmapModel::Pinhole,
            width: 10,
            height: 10,
            params: vec![f64::NAN, 1.0, 5.0, 5.0],
        };
        assert_eq!(
            brown_from_colmap(&nan),
            Err(ConvertError::InvalidParameters)
        );
    }
}
