//! Properties that must hold for every input, not just the scenes written by hand: a conic
//! and its ellipse map onto each other, the symmetric epipolar distance does not care which
//! image comes first, and the camera model's undistortion inverts its projection wherever the
//! model is invertible. proptest draws the inputs (seeded) and shrinks a failure to its smallest
//! case.
#![allow(clippy::unwrap_used)]

use nalgebra::{Matrix3, Vector2};
use pipemeasure::camera::Intrinsics;
use pipemeasure::geometry::conic::{Ellipse, conic_centre};
use pipemeasure::geometry::epipolar::symmetric_distance;
use proptest::prelude::*;

/// Ellipses as the detector meets them: centres anywhere on a 4K frame, semi-axes from the
/// 2 px of the smallest target to 500 px, any orientation, axis ratios down to 0.05.
fn ellipse() -> impl Strategy<Value = Ellipse> {
    (
        0.0..3840.0f64,
        0.0..2160.0f64,
        2.0..500.0f64,
        0.05..1.0f64,
        -std::f64::consts::PI..std::f64::consts::PI,
    )
        .prop_map(|(cx, cy, a, ratio, theta)| Ellipse::new(cx, cy, a, a * ratio, theta))
}

/// The shortest distance between two orientations of an ellipse's major axis (they are the
/// same modulo π).
fn axis_angle_difference(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::PI);
    d.min(std::f64::consts::PI - d)
}

proptest! {
    // Seeded, so a run is the same run everywhere; 1,024 cases each (a few milliseconds).
    #![proptest_config(ProptestConfig {
        cases: 1024,
        rng_seed: proptest::test_runner::RngSeed::Fixed(1),
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    /// Ellipse → conic → ellipse gives the same centre, semi-axes and (for a non-circular
    /// ellipse) orientation; the conic's own centre is the ellipse's.
    #[test]
    fn conic_round_trip(e in ellipse()) {
        let c = e.to_conic();
        let back = Ellipse::from_conic(&c).unwrap();
        let scale = e.a.max(e.cx.abs()).max(e.cy.abs());
        prop_assert!((back.cx - e.cx).abs() <= 1e-9 * scale, "{e:?} → {back:?}");
        prop_assert!((back.cy - e.cy).abs() <= 1e-9 * scale, "{e:?} → {back:?}");
        prop_assert!((back.a - e.a).abs() <= 1e-9 * scale, "{e:?} → {back:?}");
        prop_assert!((back.b - e.b).abs() <= 1e-9 * scale, "{e:?} → {back:?}");
        if e.b < 0.99 * e.a {
            prop_assert!(axis_angle_difference(back.theta, e.theta) <= 1e-7, "{e:?} → {back:?}");
        }
        let centre = conic_centre(&c).unwrap();
        prop_assert!((centre - e.centre()).norm() <= 1e-9 * scale);
    }

    /// The symmetric epipolar distance of `x1` in image 1 and `x2` in image 2 under `F` equals
    /// that of `x2` in image 1 and `x1` in image 2 under `Fᵀ` (the two images swapped).
    #[test]
    fn epipolar_distance_is_symmetric(
        f in proptest::collection::vec(-1.0..1.0f64, 9),
        x1 in (0.0..4000.0f64, 0.0..3000.0f64),
        x2 in (0.0..4000.0f64, 0.0..3000.0f64),
    ) {
        let f = Matrix3::from_row_slice(&f);
        let (x1, x2) = (Vector2::new(x1.0, x1.1), Vector2::new(x2.0, x2.1));
        let d = symmetric_distance(&f, &x1, &x2);
        let swapped = symmetric_distance(&f.transpose(), &x2, &x1);
        prop_assume!(d.is_finite());
        prop_assert!((d - swapped).abs() <= 1e-9 * d.max(1.0), "{d} vs {swapped}");
    }

    /// Pixel → ideal → pixel is the identity over a 4K frame for phone-like cameras (the
    /// presets' principal distances and distortions, and more), wherever the undistortion
    /// succeeds; and it succeeds everywhere the distortion is invertible over the frame
    /// (k1 ≥ 0 and small k2, k3 here).
    #[test]
    fn undistortion_inverts_the_projection(
        c in 2500.0..3500.0f64,
        u0 in 1800.0..2040.0f64,
        v0 in 1000.0..1160.0f64,
        k1 in 0.0..0.2f64,
        k2 in -0.05..0.05f64,
        p in (-1e-3..1e-3f64, -1e-3..1e-3f64),
        b in (-1.0..1.0f64, -1.0..1.0f64),
        uv in (0.0..3840.0f64, 0.0..2160.0f64),
    ) {
        let cam = Intrinsics {
            c,
            u0,
            v0,
            k1,
            k2,
            k3: 0.0,
            p1: p.0,
            p2: p.1,
            b1: b.0,
            b2: b.1,
        };
        let uv = Vector2::new(uv.0, uv.1);
        let xy = cam.ideal_from_pixel(&uv).unwrap();
        let back = cam.pixel_from_ideal(&xy);
        prop_assert!((back - uv).norm() < 1e-8, "{:?}: {} px", cam, (back - uv).norm());
    }
}
