//! Checks of a calibrated model over the whole frame: is the distortion monotonic and
//! invertible, how uncertain is the projection of a ray (from the intrinsics' covariance), and
//! how much do two models differ (cross-validation on disjoint halves, as mrcal does for
//! chessboards).

use nalgebra::{DMatrix, Matrix2, Vector2, Vector3};
use serde::Serialize;

use crate::camera::Intrinsics;

/// Cells per image side of the maps (columns; rows follow the aspect ratio).
pub const MAP_COLUMNS: usize = 32;

/// Where the distortion fails to be monotonic or invertible.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DistortionCheck {
    /// Whether every pixel of the frame undistorts and the distortion's Jacobian stays positive
    /// definite-oriented (det > 0) and radially increasing over the frame.
    pub ok: bool,
    /// Pixels of the frame (out of the checked grid) where it fails.
    pub failing_pixels: usize,
    /// The smallest image radius (px from the principal point) at which it fails.
    pub first_failure_radius_px: Option<f64>,
    /// The largest image radius of the frame (px).
    pub frame_radius_px: f64,
}

/// Cell centres of a `cols × rows` grid over the frame.
fn grid(size: (u32, u32), cols: usize) -> (usize, usize, Vec<Vector2<f64>>) {
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    let rows = ((cols as f64) * h / w).round().max(1.0) as usize;
    let mut out = Vec::with_capacity(cols * rows);
    for j in 0..rows {
        for i in 0..cols {
            out.push(Vector2::new(
                (i as f64 + 0.5) * w / cols as f64,
                (j as f64 + 0.5) * h / rows as f64,
            ));
        }
    }
    (cols, rows, out)
}

/// Checks that the distortion is invertible and monotonic over the whole frame: every pixel of
/// a dense grid (and the frame's corners) undistorts, and along the ray from the principal
/// point to it the distorted radius keeps increasing with det(∂xy_d/∂xy) > 0.
#[must_use]
pub fn check_distortion(i: &Intrinsics, size: (u32, u32)) -> DistortionCheck {
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    let pp = Vector2::new(i.u0, i.v0);
    let (_, _, mut pixels) = grid(size, 4 * MAP_COLUMNS);
    pixels.extend([
        Vector2::new(0.0, 0.0),
        Vector2::new(w, 0.0),
        Vector2::new(0.0, h),
        Vector2::new(w, h),
    ]);
    let frame_radius_px = pixels.iter().map(|p| (p - pp).norm()).fold(0.0, f64::max);
    let mut failing = 0;
    let mut first: Option<f64> = None;
    for uv in &pixels {
        let bad = match i.ideal_from_pixel(uv) {
            Err(_) => true,
            Ok(xy) => {
                // Along the ray to xy: radius and Jacobian determinant.
                let mut prev = 0.0;
                let mut bad = false;
                for k in 1..=32 {
                    let p = xy * (f64::from(k) / 32.0);
                    let (d, jac): (Vector2<f64>, Matrix2<f64>) = i.distort_with_jacobian(&p);
                    let r = d.norm();
                    if jac.determinant() <= 0.0 || r <= prev {
                        bad = true;
                        break;
                    }
                    prev = r;
                }
                bad
            }
        };
        if bad {
            failing += 1;
            let r = (uv - pp).norm();
            first = Some(first.map_or(r, |f: f64| f.min(r)));
        }
    }
    DistortionCheck {
        ok: failing == 0,
        failing_pixels: failing,
        first_failure_radius_px: first,
        frame_radius_px,
    }
}

/// A map over the image: `values[row][col]`, with its largest and RMS value.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageMap {
    /// Grid columns.
    pub cols: usize,
    /// Grid rows.
    pub rows: usize,
    /// Values per cell (row-major rows).
    pub values: Vec<Vec<f64>>,
    /// Largest value.
    pub max: f64,
    /// RMS value.
    pub rms: f64,
}

fn map_from(cols: usize, rows: usize, flat: Vec<f64>) -> ImageMap {
    let finite: Vec<f64> = flat.iter().copied().filter(|v| v.is_finite()).collect();
    let max = finite.iter().copied().fold(0.0, f64::max);
    let rms = (finite.iter().map(|v| v * v).sum::<f64>() / finite.len().max(1) as f64).sqrt();
    ImageMap {
        cols,
        rows,
        values: flat.chunks(cols).map(<[f64]>::to_vec).collect(),
        max,
        rms,
    }
}

impl ImageMap {
    /// The largest ratio of this map to `sigma` over their common cells: how many of its own
    /// projection σ a camera's error against another reaches somewhere in the frame (issue
    /// 19's honesty criterion asks at most 3). A zero σ counts as the smallest positive one.
    #[must_use]
    pub fn max_ratio_to(&self, sigma: &ImageMap) -> f64 {
        self.values
            .iter()
            .flatten()
            .zip(sigma.values.iter().flatten())
            .map(|(d, s)| d / s.max(f64::MIN_POSITIVE))
            .fold(0.0, f64::max)
    }
}

/// σ (px, the larger principal axis of the 2×2 covariance) of the projected pixel of the ray
/// through each grid cell, propagated from the intrinsics' 10×10 covariance (order of
/// [`crate::camera::Term::ALL`]).
#[must_use]
pub fn projection_uncertainty(i: &Intrinsics, cov: &DMatrix<f64>, size: (u32, u32)) -> ImageMap {
    let (cols, rows, pixels) = grid(size, MAP_COLUMNS);
    let flat = pixels
        .iter()
        .map(|uv| {
            let Ok(xy) = i.ideal_from_pixel(uv) else {
                return f64::NAN;
            };
            let Some(p) = i.project_with_jacobians(&Vector3::new(xy.x, xy.y, 1.0)) else {
                return f64::NAN;
            };
            let j = DMatrix::from_fn(2, 10, |r, c| p.d_uv_d_intrinsics[(r, c)]);
            let s = &j * cov * j.transpose();
            let (a, b, d) = (s[(0, 0)], s[(0, 1)], s[(1, 1)]);
            let half = 0.5 * (a + d);
            let disc = (0.25 * (a - d) * (a - d) + b * b).sqrt();
            (half + disc).max(0.0).sqrt()
        })
        .collect();
    map_from(cols, rows, flat)
}

/// Difference (px) between the projections of two models of the same camera: each cell's ray
/// by model `a` projected by model `b`.
#[must_use]
pub fn projection_difference(a: &Intrinsics, b: &Intrinsics, size: (u32, u32)) -> ImageMap {
    let (cols, rows, pixels) = grid(size, MAP_COLUMNS);
    let flat = pixels
        .iter()
        .map(|uv| {
            a.ideal_from_pixel(uv)
                .ok()
                .and_then(|xy| b.project(&Vector3::new(xy.x, xy.y, 1.0)))
                .map_or(f64::NAN, |q| (q - uv).norm())
        })
        .collect();
    map_from(cols, rows, flat)
}

/// [`projection_difference`] after the rotation that best aligns the two models' rays.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RotatedDifference {
    /// The differences (px) after the rotation.
    pub map: ImageMap,
    /// The rotation's angle (degrees).
    pub rotation_deg: f64,
}

/// Difference (px) between the projections of two models of the same camera after
/// compensating a rotation between them (mrcal's `show-projection-diff`): a model estimated
/// from another set of frames can have its whole bundle of rays turned a little — the poses
/// turn with it, so no image tells — and the principal point and a small rotation of every
/// frame are nearly the same thing. The rotation `R` minimising `Σ |π_b(R·ray_a(uv)) − uv|²`
/// over the map's grid is found by Gauss–Newton (numerical derivatives), and each cell's ray by
/// `a`, rotated, is projected by `b`.
#[must_use]
pub fn projection_difference_rotated(
    a: &Intrinsics,
    b: &Intrinsics,
    size: (u32, u32),
) -> RotatedDifference {
    let (cols, rows, pixels) = grid(size, MAP_COLUMNS);
    let rays: Vec<Option<Vector3<f64>>> = pixels
        .iter()
        .map(|uv| {
            a.ideal_from_pixel(uv)
                .ok()
                .map(|xy| Vector3::new(xy.x, xy.y, 1.0).normalize())
        })
        .collect();
    let residuals = |r: &nalgebra::Rotation3<f64>| -> Vec<Option<Vector2<f64>>> {
        rays.iter()
            .zip(&pixels)
            .map(|(ray, uv)| Some(b.project(&(r * (*ray)?))? - uv))
            .collect()
    };
    let mut rotation = nalgebra::Rotation3::identity();
    let h = 1e-7;
    for _ in 0..10 {
        let base = residuals(&rotation);
        let shifted: Vec<Vec<Option<Vector2<f64>>>> = (0..3)
            .map(|k| {
                let mut w = Vector3::zeros();
                w[k] = h;
                residuals(&(nalgebra::Rotation3::new(w) * rotation))
            })
            .collect();
        let (mut jtj, mut jtr) = (nalgebra::Matrix3::zeros(), Vector3::zeros());
        for (i, r0) in base.iter().enumerate() {
            let Some(r0) = r0 else { continue };
            let cols: Option<Vec<Vector2<f64>>> = (0..3)
                .map(|k| shifted[k][i].map(|r| (r - r0) / h))
                .collect();
            let Some(cols) = cols else { continue };
            let j = nalgebra::Matrix2x3::from_columns(&[cols[0], cols[1], cols[2]]);
            jtj += j.transpose() * j;
            jtr += j.transpose() * r0;
        }
        let Some(step) = jtj.try_inverse().map(|inv| -(inv * jtr)) else {
            break;
        };
        rotation = nalgebra::Rotation3::new(step) * rotation;
        if step.norm() < 1e-12 {
            break;
        }
    }
    let flat = residuals(&rotation)
        .into_iter()
        .map(|r| r.map_or(f64::NAN, |r| r.norm()))
        .collect();
    RotatedDifference {
        map: map_from(cols, rows, flat),
        rotation_deg: rotation.angle().to_degrees(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ratio is taken cell by cell, not of the two maps' maxima.
    #[test]
    fn the_largest_ratio_is_per_cell() {
        let error = map_from(2, 2, vec![0.1, 0.4, 0.0, 0.2]);
        let sigma = map_from(2, 2, vec![0.02, 0.4, 0.0, 0.1]);
        // 0.1/0.02 = 5 beats 0.4/0.4 = 1 although 0.4 is the error's maximum; 0/0 counts 0.
        assert!((error.max_ratio_to(&sigma) - 5.0).abs() < 1e-12);
        assert_eq!(error.max / sigma.max, 1.0);
    }

    #[test]
    fn a_moderate_model_passes_and_a_folding_one_fails() {
        let good = Intrinsics {
            k1: 0.0125,
            k2: -0.0094,
            ..Intrinsics::pinhole(3050.0, 1920.0, 1080.0)
        };
        assert!(check_distortion(&good, (3840, 2160)).ok);
        // Strong barrel: r_d = r(1 − 0.5 r²) peaks at r = 0.816, inside the frame at c = 1500.
        let folding = Intrinsics {
            k1: -0.5,
            ..Intrinsics::pinhole(1500.0, 1920.0, 1080.0)
        };
        let c = check_distortion(&folding, (3840, 2160));
        assert!(!c.ok && c.failing_pixels > 0);
        let r = c.first_failure_radius_px.unwrap();
        // Distorted radius at the fold: 1500 · 0.816 · (1 − 0.5·0.667) = 816 px.
        assert!(r > 700.0 && r < 900.0, "{r}");
    }

    #[test]
    fn identical_models_do_not_differ_and_a_shift_shows_everywhere() {
        let a = Intrinsics {
            k1: 0.01,
            ..Intrinsics::pinhole(3000.0, 1920.0, 1080.0)
        };
        let d = projection_difference(&a, &a, (3840, 2160));
        assert!(d.max < 1e-9);
        let b = Intrinsics {
            u0: a.u0 + 0.5,
            ..a
        };
        let d = projection_difference(&a, &b, (3840, 2160));
        assert!((d.max - 0.5).abs() < 1e-9 && (d.rms - 0.5).abs() < 1e-9);
    }

    /// A principal-point shift is nearly a rotation of the rays: compensated, the difference
    /// is smaller, the rotation is about the image's vertical axis by about atan(Δu0 / c), and
    /// it is a least-squares minimum (turning it by 10 µrad about any axis costs more); a model
    /// compared with itself differs by nothing.
    #[test]
    fn a_rotation_between_models_is_compensated() {
        let a = Intrinsics {
            k1: 0.01,
            ..Intrinsics::pinhole(3000.0, 1920.0, 1080.0)
        };
        let b = Intrinsics {
            u0: a.u0 + 2.0,
            ..a
        };
        let size = (3840, 2160);
        let plain = projection_difference(&a, &b, size);
        let rotated = projection_difference_rotated(&a, &b, size);
        assert!((plain.max - 2.0).abs() < 1e-9);
        assert!(
            rotated.map.rms < 0.3 * plain.rms,
            "{} vs {}",
            rotated.map.rms,
            plain.rms
        );
        let expected = (2.0f64 / 3000.0).atan().to_degrees();
        assert!(
            (rotated.rotation_deg / expected - 1.0).abs() < 0.2,
            "{}",
            rotated.rotation_deg
        );
        // Stationarity: the sum of squares of the cells at the found rotation against turned
        // ones (the map's cells are the same grid).
        let (_, _, pixels) = grid(size, MAP_COLUMNS);
        let cost = |r: &nalgebra::Rotation3<f64>| -> f64 {
            pixels
                .iter()
                .map(|uv| {
                    let xy = a.ideal_from_pixel(uv).unwrap();
                    let q = b
                        .project(&(r * Vector3::new(xy.x, xy.y, 1.0).normalize()))
                        .unwrap();
                    (q - uv).norm_squared()
                })
                .sum()
        };
        let found = rotated.map.rms.powi(2) * pixels.len() as f64;
        let turns = (0..3).flat_map(|k| {
            [-1e-5, 1e-5].map(|s| {
                let mut w = Vector3::zeros();
                w[k] = s;
                w
            })
        });
        // The rotation is about the vertical axis (the cost at it is the map's), and every
        // turn of it raises the cost.
        let r0 =
            nalgebra::Rotation3::new(Vector3::new(0.0, -rotated.rotation_deg.to_radians(), 0.0));
        let r1 =
            nalgebra::Rotation3::new(Vector3::new(0.0, rotated.rotation_deg.to_radians(), 0.0));
        let r = if (cost(&r0) - found).abs() < (cost(&r1) - found).abs() {
            r0
        } else {
            r1
        };
        assert!(
            (cost(&r) - found).abs() < 1e-6 * found.max(1e-12),
            "{} vs {found}",
            cost(&r)
        );
        for w in turns {
            assert!(cost(&(nalgebra::Rotation3::new(w) * r)) > found);
        }
        let same = projection_difference_rotated(&a, &a, size);
        assert!(same.map.max < 1e-9 && same.rotation_deg < 1e-9);
    }

    #[test]
    fn uncertainty_of_the_principal_point_alone_is_uniform() {
        let i = Intrinsics::pinhole(3000.0, 1920.0, 1080.0);
        let mut cov = DMatrix::zeros(10, 10);
        cov[(1, 1)] = 0.04; // σ(u0) = 0.2 px
        let m = projection_uncertainty(&i, &cov, (3840, 2160));
        assert!((m.max - 0.2).abs() < 1e-12 && (m.rms - 0.2).abs() < 1e-12);
    }
}
