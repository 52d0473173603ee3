//! Robust cylinder fitting against exact geometry and the real mug scan.

#![allow(clippy::unwrap_used)]

use nalgebra::Vector3;
use pipemeasure::measure::{Cloud, CylinderConfig, CylinderError, fit_all_cylinders, fit_cylinder};
use pipemeasure::robust::standard_normal as gaussian;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A 3-inch-class pipe: 57.15 mm radius (4.5" OD).
const R: f64 = 0.05715;

/// `n` points on a cylinder (axis through `c` along `d`, length `len`), with isotropic
/// Gaussian noise `sigma`.
fn cylinder_points(
    rng: &mut ChaCha8Rng,
    n: usize,
    c: Vector3<f64>,
    d: Vector3<f64>,
    r: f64,
    len: f64,
    sigma: f64,
) -> Vec<Vector3<f64>> {
    let d = d.normalize();
    let e1 = d.cross(&Vector3::new(0.3, 0.5, 0.8)).normalize();
    let e2 = d.cross(&e1);
    (0..n)
        .map(|_| {
            let t: f64 = rng.random_range(-0.5..0.5) * len;
            let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let noise = sigma * Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng));
            c + t * d + r * (a.cos() * e1 + a.sin() * e2) + noise
        })
        .collect()
}

fn pipe_config() -> CylinderConfig {
    CylinderConfig {
        radius_min: 0.02,
        radius_max: 0.3,
        ..CylinderConfig::default()
    }
}

#[test]
fn noise_free_points_give_the_radius_to_1e_9() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    // Far from the origin, as TLS coordinates are.
    let c = Vector3::new(1.0e6, 2.5e6, 310.0);
    let d = Vector3::new(0.2, -0.3, 1.0);
    let pts = cylinder_points(&mut rng, 20_000, c, d, R, 1.5, 0.0);
    let cloud = Cloud::new(&pts).unwrap();
    let fit = fit_cylinder(&cloud, &pipe_config()).unwrap();
    assert!(
        (fit.cylinder.radius - R).abs() < 1e-9,
        "{}",
        fit.cylinder.radius
    );
    assert_eq!(fit.inliers, 20_000);
    assert!(fit.cylinder.direction.dot(&d.normalize()).abs() > 1.0 - 1e-12);
    // The axis passes through c.
    let w = c - fit.cylinder.point;
    assert!(w.cross(&fit.cylinder.direction).norm() < 1e-7);
}

#[test]
fn one_millimetre_noise_leaves_no_radius_bias() {
    let seeds = 100;
    let mut errors = Vec::new();
    let mut stds = Vec::new();
    for seed in 0..seeds {
        let mut rng = ChaCha8Rng::seed_from_u64(1000 + seed);
        let pts = cylinder_points(
            &mut rng,
            100_000,
            Vector3::new(3.0, -1.0, 2.0),
            Vector3::new(1.0, 0.1, 0.05),
            R,
            2.0,
            0.001,
        );
        let cloud = Cloud::new(&pts).unwrap();
        let fit = fit_cylinder(&cloud, &pipe_config()).unwrap();
        errors.push(fit.cylinder.radius - R);
        stds.push(fit.radius_std);
    }
    let mean = errors.iter().sum::<f64>() / seeds as f64;
    let spread =
        (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (seeds - 1) as f64).sqrt();
    let predicted = stds.iter().sum::<f64>() / seeds as f64;
    eprintln!(
        "bias {:.4} mm, spread {:.4} mm, predicted σ {:.4} mm",
        mean * 1e3,
        spread * 1e3,
        predicted * 1e3
    );
    assert!(mean.abs() < 0.05e-3, "bias {} mm", mean * 1e3);
    // The reported σ describes the spread (within 30 % for 100 samples).
    assert!(
        (spread / predicted - 1.0).abs() < 0.3,
        "{spread} vs {predicted}"
    );
}

/// A pipe of interest among a wall, a floor, a second (thinner) pipe and 30 % uniform
/// outliers.
fn cluttered_scene(seed: u64) -> Vec<Vector3<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut pts = cylinder_points(
        &mut rng,
        30_000,
        Vector3::new(1.0, 1.0, 1.2),
        Vector3::new(1.0, 0.0, 0.0),
        R,
        2.0,
        0.001,
    );
    // Second pipe, r = 25 mm, vertical, fewer points.
    pts.extend(cylinder_points(
        &mut rng,
        8_000,
        Vector3::new(1.5, 1.4, 1.0),
        Vector3::new(0.0, 0.0, 1.0),
        0.025,
        2.0,
        0.001,
    ));
    // Wall y = 1.6 and floor z = 0.
    for _ in 0..20_000 {
        let (a, b): (f64, f64) = (rng.random_range(0.0..2.0), rng.random_range(0.0..2.5));
        pts.push(
            Vector3::new(a, 1.6, b)
                + 0.001 * Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng)),
        );
        pts.push(
            Vector3::new(a, b * 0.64, 0.0)
                + 0.001 * Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng)),
        );
    }
    // 30 % uniform outliers in the scene's box.
    let n_out = (pts.len() as f64 * 0.3 / 0.7) as usize;
    for _ in 0..n_out {
        pts.push(Vector3::new(
            rng.random_range(0.0..2.0),
            rng.random_range(0.0..1.6),
            rng.random_range(0.0..2.5),
        ));
    }
    pts
}

#[test]
fn the_pipe_of_interest_is_found_in_clutter() {
    let pts = cluttered_scene(7);
    let cloud = Cloud::new(&pts).unwrap();
    let fit = fit_cylinder(&cloud, &pipe_config()).unwrap();
    eprintln!("{fit:?}");
    assert!(
        (fit.cylinder.radius - R).abs() < 0.2e-3,
        "{}",
        fit.cylinder.radius
    );
    assert!(fit.cylinder.direction.x.abs() > 0.999);
    // With --all both pipes are found, the larger (better supported) first.
    let all = fit_all_cylinders(&cloud, &pipe_config(), 4);
    assert!(all.len() >= 2, "{}", all.len());
    assert!((all[0].cylinder.radius - R).abs() < 0.2e-3);
    assert!(
        all.iter()
            .any(|f| (f.cylinder.radius - 0.025).abs() < 0.5e-3),
        "{:?}",
        all.iter().map(|f| f.cylinder.radius).collect::<Vec<_>>()
    );
}

#[test]
fn a_wall_far_from_the_pipe_costs_no_normals() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut pts = cylinder_points(
        &mut rng,
        20_000,
        Vector3::zeros(),
        Vector3::x(),
        R,
        2.0,
        0.001,
    );
    let pipe = pts.len();
    // A 4 m × 3 m wall 2 m away, five times as many points.
    for _ in 0..100_000 {
        let (a, b): (f64, f64) = (rng.random_range(-2.0..2.0), rng.random_range(-1.5..1.5));
        pts.push(Vector3::new(a, 2.0, b) + 0.001 * Vector3::new(gaussian(&mut rng), 0.0, 0.0));
    }
    let cloud = Cloud::new(&pts).unwrap();
    let fit = fit_cylinder(&cloud, &pipe_config()).unwrap();
    assert!(
        (fit.cylinder.radius - R).abs() < 2e-4,
        "{}",
        fit.cylinder.radius
    );
    // The pipe's points, the scoring subsample and the noise subsample: not the whole wall.
    let sample = pipe_config().score_sample;
    assert!(
        cloud.computed() <= pipe + sample + pipemeasure::measure::cloud::NOISE_SAMPLE,
        "{} of {} computed",
        cloud.computed(),
        cloud.len()
    );
}

#[test]
fn a_plane_is_not_a_cylinder() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let pts: Vec<Vector3<f64>> = (0..20_000)
        .map(|_| {
            Vector3::new(
                rng.random_range(0.0..2.0),
                rng.random_range(0.0..2.0),
                0.001 * gaussian(&mut rng),
            )
        })
        .collect();
    let cloud = Cloud::new(&pts).unwrap();
    let err = fit_cylinder(&cloud, &pipe_config()).unwrap_err();
    assert!(matches!(err, CylinderError::NotFound { .. }), "{err}");
}

#[test]
fn the_mug_is_the_best_cylinder_of_the_real_scan() {
    // The table is left out by the method's own tests, not by removing it first: its bent,
    // noisy surface offers cylinders of 20–100 mm, but their support fills a narrow band of
    // arc (a bent strip plus stray points far round the axis), and the refined candidates
    // compete on every point rather than the subsample. With the default seed the mug wins;
    // the README records that other seeds can still prefer a table artefact.
    let read = pipemeasure::io::ply::read(std::path::Path::new(
        "../shared/data/pcl_mug/table_scene_mug_stereo_textured.ply",
    ))
    .unwrap();
    let pts: Vec<Vector3<f64>> = read.cloud.points.iter().map(|p| p.coords).collect();
    let cloud = Cloud::new(&pts).unwrap();
    // PCL's tutorial settings bound the radius to 0–0.1 m.
    let config = CylinderConfig {
        radius_min: 0.0,
        radius_max: 0.1,
        ..CylinderConfig::default()
    };
    let f = fit_cylinder(&cloud, &config).unwrap();
    eprintln!(
        "r = {:.4} m ± {:.5}, rmse {:.5} m, {} inliers",
        f.cylinder.radius, f.radius_std, f.rmse, f.inliers
    );
    // PCL 1.13 (plane removed first, RANSAC with normals): 0.0388 m. The mug stands on the
    // table: its axis is along the table's normal (≈ (0, −0.84, −0.54) in this scan).
    assert!(
        (f.cylinder.radius - 0.0388).abs() < 0.001,
        "{}",
        f.cylinder.radius
    );
    assert!(f.inliers > 3000);
    let table_normal = Vector3::new(0.01, -0.84, -0.54).normalize();
    assert!(f.cylinder.direction.dot(&table_normal).abs() > 0.98);
}
