//! The paper's Fig. 7 and Fig. 8 on simulated data: one large circular target (radius 100 mm)
//! seen by 28 convergent 4K views of the p30 preset, poses with SfM-level errors (σ = 0.1° per
//! rotation axis, 3 mm per camera-centre axis), ellipses with the detector's noise (σ = 0.01 px
//! on centre and axes).
//!
//! Fig. 7: mean 3D error of the target centre triangulated from k views (50 random
//! combinations per k) using the fitted ellipse centres and Algorithm 3's centres (computed
//! within each combination). Fig. 8: per view, the eccentricity by Algorithm 3 (fitted centre
//! minus corrected centre) and by Luhmann's closed form (true 3D centre, radius and normal,
//! with the noisy poses, as the paper used the estimated EOPs), each compared with the true
//! eccentricity (fitted centre minus the projection of the true centre with the true pose).
//!
//! `cargo run --release --example eccentricity_experiments -- [--seed S]`

use nalgebra::{Point3, Translation3, UnitQuaternion, Vector2, Vector3, Vector4};
use pipemeasure::calibrate::eccentricity::{
    ConicView, EccentricityConfig, correct_target, eccentricity_bound,
};
use pipemeasure::geometry::Rigid3;
use pipemeasure::geometry::conic::{Ellipse, conic_of_circle};
use pipemeasure::geometry::eccentricity::luhmann_eccentricity;
use pipemeasure::geometry::pose::camera_centre;
use pipemeasure::geometry::triangulation::{Observation, camera_matrix, triangulate};
use pipemeasure::sim::devices::{P30, preset_camera};
use pipemeasure::sim::lab::look_at;
use pipemeasure::sim::sfm::gaussian;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn perturb(pose: &Rigid3, rng: &mut ChaCha8Rng) -> Rigid3 {
    let omega = Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)) * 0.1f64.to_radians();
    let rotation = UnitQuaternion::from_scaled_axis(omega) * pose.rotation;
    let centre =
        camera_centre(pose) + Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)) * 0.003;
    Rigid3::from_parts(Translation3::from(-(rotation * centre.coords)), rotation)
}

struct View {
    true_p: nalgebra::Matrix3x4<f64>,
    true_pose: Rigid3,
    noisy_p: nalgebra::Matrix3x4<f64>,
    noisy_pose: Rigid3,
    ellipse: Ellipse,
    true_centre_px: Vector2<f64>,
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args
        .iter()
        .position(|a| a == "--seed")
        .and_then(|k| args.get(k + 1))
        .map_or(Ok(1), |s| s.parse())
        .map_err(|e| format!("--seed: {e}"))?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let camera = preset_camera(&P30, 3840, 2160);
    let k = camera.intrinsics.pinhole_matrix();
    let c = camera.intrinsics.c;
    // The target on a wall (normal −y... facing the cameras along −z), 100 mm radius.
    let centre = Vector3::new(0.0, 0.0, 0.0);
    let normal = Vector3::new(0.0, 0.0, -1.0);
    let radius = 0.1;
    // 28 convergent views at 1.2–2.5 m, up to 55° off the normal.
    let mut views = Vec::new();
    while views.len() < 28 {
        let tilt: f64 = rng.random_range(5.0f64..55.0).to_radians();
        let azimuth: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        let dist: f64 = rng.random_range(1.2..2.5);
        let eye = Point3::new(
            dist * tilt.sin() * azimuth.cos(),
            dist * tilt.sin() * azimuth.sin(),
            -dist * tilt.cos(),
        );
        // Aim near the target, not exactly at it (the target is off the image centre).
        let aim = Point3::new(
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.2..0.2),
            0.0,
        );
        let pose = look_at(&eye, &aim, &Vector3::y(), 0.0);
        let Some(conic) = conic_of_circle(&k, &pose, &centre, &normal, radius) else {
            continue;
        };
        let Some(exact) = Ellipse::from_conic(&conic) else {
            continue;
        };
        let inside = |p: Vector2<f64>| p.x > 50.0 && p.y > 50.0 && p.x < 3790.0 && p.y < 2110.0;
        if !(0..32).all(|s| inside(exact.point(std::f64::consts::TAU * f64::from(s) / 32.0))) {
            continue;
        }
        let n = 0.01;
        let ellipse = Ellipse::new(
            exact.cx + n * gaussian(&mut rng),
            exact.cy + n * gaussian(&mut rng),
            exact.a + n * gaussian(&mut rng),
            exact.b + n * gaussian(&mut rng),
            exact.theta + n / exact.a * gaussian(&mut rng),
        );
        let h = camera_matrix(&k, &pose) * Vector4::new(centre.x, centre.y, centre.z, 1.0);
        let noisy_pose = perturb(&pose, &mut rng);
        views.push(View {
            true_p: camera_matrix(&k, &pose),
            true_pose: pose,
            noisy_p: camera_matrix(&k, &noisy_pose),
            noisy_pose,
            ellipse,
            true_centre_px: Vector2::new(h.x / h.z, h.y / h.z),
        });
    }
    let conic_view = |v: &View, exact: bool| ConicView {
        p: if exact { v.true_p } else { v.noisy_p },
        eye: camera_centre(if exact { &v.true_pose } else { &v.noisy_pose }),
        conic: v.ellipse.to_conic(),
        centre: v.ellipse.centre(),
        axis_ratio: v.ellipse.b / v.ellipse.a,
        bound: eccentricity_bound(v.ellipse.a, v.ellipse.b, c),
        eligible: true,
    };
    let config = EccentricityConfig::default();
    // Algorithm 3 on a subset of views: corrected centres (fitted where no partner).
    let corrected = |subset: &[&View], exact: bool| -> Option<Vec<Vector2<f64>>> {
        let cv: Vec<ConicView> = subset.iter().map(|v| conic_view(v, exact)).collect();
        let x = triangulate(
            &cv.iter()
                .map(|v| Observation {
                    p: v.p,
                    xy: v.centre,
                })
                .collect::<Vec<_>>(),
        )?;
        let pair = |a: usize, b: usize| Some((cv[a].p, cv[a].eye, cv[b].p, cv[b].eye));
        let out = correct_target(&cv, &x, &config, &|_, _| true, &pair);
        Some(
            out.iter()
                .zip(subset)
                .map(|(c, v)| c.map_or(v.ellipse.centre(), |c| c.centre))
                .collect(),
        )
    };
    // Fig. 7.
    println!(
        "Fig. 7 — mean 3D error of the target centre (mm), 50 random view combinations per k (seed {seed})\n"
    );
    println!(
        "| views | fitted, exact poses | Algorithm 3, exact poses | fitted, noisy poses | Algorithm 3, noisy poses | ratio (noisy) |"
    );
    println!("|---:|---:|---:|---:|---:|---:|");
    for n in [2usize, 3, 4, 5, 7, 10, 14, 20, 28] {
        let mut sums = [0.0; 4];
        let mut count = 0;
        for _ in 0..50 {
            let mut idx: Vec<usize> = (0..views.len()).collect();
            idx.shuffle(&mut rng);
            let subset: Vec<&View> = idx[..n].iter().map(|&i| &views[i]).collect();
            let fitted_centres: Vec<Vector2<f64>> =
                subset.iter().map(|v| v.ellipse.centre()).collect();
            let mut errors = [0.0; 4];
            let mut ok = true;
            for (e, exact) in [(0usize, true), (2, false)] {
                let obs = |centres: &[Vector2<f64>]| -> Vec<Observation> {
                    subset
                        .iter()
                        .zip(centres)
                        .map(|(v, c)| Observation {
                            p: if exact { v.true_p } else { v.noisy_p },
                            xy: *c,
                        })
                        .collect()
                };
                match (
                    triangulate(&obs(&fitted_centres)),
                    corrected(&subset, exact).and_then(|cc| triangulate(&obs(&cc))),
                ) {
                    (Some(xf), Some(xa)) => {
                        errors[e] = (xf.coords - centre).norm();
                        errors[e + 1] = (xa.coords - centre).norm();
                    }
                    _ => ok = false,
                }
            }
            if ok {
                for (s, e) in sums.iter_mut().zip(errors) {
                    *s += e;
                }
                count += 1;
            }
        }
        let m: Vec<f64> = sums
            .iter()
            .map(|s| 1000.0 * s / f64::from(count.max(1)))
            .collect();
        println!(
            "| {n} | {:.2} | {:.3} | {:.2} | {:.2} | {:.1}x |",
            m[0],
            m[1],
            m[2],
            m[3],
            m[2] / m[3]
        );
    }
    // Fig. 8.
    let all: Vec<&View> = views.iter().collect();
    let cc = corrected(&all, false).ok_or("Algorithm 3 failed on the 28 views")?;
    let (mut e_alg3, mut e_luhmann, mut e_true_sum) = (0.0, 0.0, 0.0);
    println!(
        "\nFig. 8 — eccentricity per view (px): truth, Algorithm 3, Luhmann (true 3D centre, radius, normal; estimated poses)\n"
    );
    println!(
        "| view | true | Algorithm 3 | error | Luhmann | error |\n|---:|---:|---:|---:|---:|---:|"
    );
    for (i, (v, corr)) in views.iter().zip(&cc).enumerate() {
        let truth = v.ellipse.centre() - v.true_centre_px;
        let alg3 = v.ellipse.centre() - corr;
        let luhmann = luhmann_eccentricity(&k, &v.noisy_pose, &centre, &normal, radius)
            .ok_or("Luhmann failed")?;
        let (ea, el) = ((alg3 - truth).norm(), (luhmann - truth).norm());
        e_alg3 += ea;
        e_luhmann += el;
        e_true_sum += truth.norm();
        println!(
            "| {} | {:.3} | {:.3} | {ea:.4} | {:.3} | {el:.4} |",
            i + 1,
            truth.norm(),
            alg3.norm(),
            luhmann.norm()
        );
    }
    let n = views.len() as f64;
    println!(
        "\nmean true eccentricity {:.3} px; mean error: Algorithm 3 {:.4} px, Luhmann {:.4} px",
        e_true_sum / n,
        e_alg3 / n,
        e_luhmann / n
    );
    Ok(())
}
