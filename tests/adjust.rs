//! The bundle adjustment engine against exact truth: convergence on noise-free data, the free
//! datum, σ against Monte-Carlo spread, and the real BAL problem against Ceres' figures.

#![allow(clippy::unwrap_used)]

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};
use pipemeasure::adjust::{
    AdjustConfig, AdjustSummary, BrownModel, Elimination, Observation, PrecisionRequest, Problem,
    Similarity, apply_similarity, bundle_adjust, free_network_datum, inner_constraint_basis,
    precision, problem_from_bal, similarity_from_points,
};
use pipemeasure::calibrate::jackknife::{JACKKNIFE_GROUPS, frame_jackknife};
use pipemeasure::camera::Intrinsics;
use pipemeasure::camera::rolling::MotionOrder;
use pipemeasure::robust::standard_normal as gaussian;
use pipemeasure::sim::devices::{P30, preset_camera};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A lab-like network: targets on two walls and the floor of a corner, 24 convergent views with
/// roll diversity (portrait and landscape), the P30 preset at 1920×1080.
struct Network {
    truth: Intrinsics,
    poses: Vec<Isometry3<f64>>,
    points: Vec<Vector3<f64>>,
    observations: Vec<Observation>,
}

fn look_at(eye: Vector3<f64>, target: Vector3<f64>, roll: f64) -> Isometry3<f64> {
    let z = (target - eye).normalize();
    let up = Vector3::new(0.0, 0.0, 1.0);
    let x = z.cross(&up).normalize();
    let y = z.cross(&x);
    let r = nalgebra::Rotation3::from_basis_unchecked(&[x, y, z]).transpose();
    let roll = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), roll);
    let r = roll * r;
    let q = UnitQuaternion::from_rotation_matrix(&r);
    let t = -(q * eye);
    Isometry3::from_parts(Translation3::from(t), q)
}

fn network() -> Network {
    let cam = preset_camera(&P30, 1920, 1080);
    let truth = cam.intrinsics;
    let mut points = Vec::new();
    for i in 0..8 {
        for j in 0..6 {
            let (a, b) = (0.25 + 0.3 * f64::from(i), 0.2 + 0.3 * f64::from(j));
            points.push(Vector3::new(a, 0.0, b)); // wall y = 0
            points.push(Vector3::new(0.0, a, b)); // wall x = 0
            points.push(Vector3::new(a, b + 0.2, 0.0)); // floor
        }
    }
    let mut poses = Vec::new();
    for k in 0..24 {
        let ang = 0.15 + 1.25 * f64::from(k) / 23.0;
        let dist = 2.6 + 0.6 * f64::from(k % 3);
        let eye = Vector3::new(
            dist * ang.cos(),
            dist * ang.sin(),
            1.2 + 0.3 * f64::from(k % 4),
        );
        let roll = match k % 4 {
            0 => 0.0,
            1 => std::f64::consts::FRAC_PI_2,
            2 => -std::f64::consts::FRAC_PI_2,
            _ => 0.3,
        };
        poses.push(look_at(eye, Vector3::new(0.8, 0.8, 0.6), roll));
    }
    let mut observations = Vec::new();
    for (c, pose) in poses.iter().enumerate() {
        for (p, x) in points.iter().enumerate() {
            let pc = pose * nalgebra::Point3::from(*x);
            if let Some(uv) = truth.project(&pc.coords)
                && cam.contains(&uv, 5.0)
            {
                observations.push(Observation {
                    camera: c,
                    point: p,
                    uv,
                    weight: 1.0,
                    time_offset_s: 0.0,
                });
            }
        }
    }
    // Keep the points seen at least three times, renumbered.
    let mut count = vec![0usize; points.len()];
    for o in &observations {
        count[o.point] += 1;
    }
    let mut index = vec![usize::MAX; points.len()];
    let mut kept = Vec::new();
    for (p, x) in points.iter().enumerate() {
        if count[p] >= 3 {
            index[p] = kept.len();
            kept.push(*x);
        }
    }
    observations.retain(|o| index[o.point] != usize::MAX);
    for o in &mut observations {
        o.point = index[o.point];
    }
    Network {
        truth,
        poses,
        points: kept,
        observations,
    }
}

/// A problem started from perturbed values: intrinsics off by 2 % / 15 px / zero distortion,
/// poses by ~0.5° and 2 cm, points by 1 cm; b1, b2 fixed at zero.
fn perturbed(net: &Network, seed: u64, noise_px: f64) -> Problem<BrownModel> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let t = net.truth;
    let start = Intrinsics::pinhole(t.c * 1.02, t.u0 + 15.0, t.v0 - 12.0);
    let poses = net
        .poses
        .iter()
        .map(|p| {
            let dw = Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng));
            let dt = Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng));
            Isometry3::from_parts(
                Translation3::from(p.translation.vector + 0.02 * dt),
                UnitQuaternion::from_scaled_axis(0.009 * dw) * p.rotation,
            )
        })
        .collect();
    let points = net
        .points
        .iter()
        .map(|x| {
            x + 0.01 * Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng))
        })
        .collect();
    let observations = net
        .observations
        .iter()
        .map(|o| Observation {
            uv: o.uv + noise_px * Vector2::new(gaussian(&mut rng), gaussian(&mut rng)),
            ..*o
        })
        .collect();
    let mut p = Problem::new(
        BrownModel::GLOBAL_SHUTTER,
        poses,
        Vec::new(),
        start.to_array().to_vec(),
        points,
        observations,
    )
    .unwrap();
    p.fixed.global = vec![8, 9];
    p
}

fn tight() -> AdjustConfig {
    AdjustConfig {
        function_tolerance: 1e-16,
        gradient_tolerance: 1e-14,
        parameter_tolerance: 1e-14,
        max_iterations: 200,
        ..AdjustConfig::default()
    }
}

#[test]
fn noise_free_network_converges_to_the_truth() {
    let net = network();
    assert!(net.observations.len() > 1500, "{}", net.observations.len());
    let mut p = perturbed(&net, 1, 0.0);
    let summary = bundle_adjust(&mut p, &tight()).unwrap();
    assert!(summary.is_usable(), "{summary:?}");
    assert!(summary.final_cost < 1e-16, "{summary:?}");
    let truth = net.truth.to_array();
    for (k, (est, tru)) in p.global.iter().zip(truth).enumerate() {
        // Relative to the parameter's size, or to the distortion's effect for the small terms.
        let scale = if k < 3 { tru.abs() } else { 1.0 };
        assert!(
            (est - tru).abs() <= 1e-8 * scale,
            "intrinsic {k}: {est} vs {tru}"
        );
    }
    // The object points equal the truth up to a similarity.
    let sim = similarity_from_points(&p.points, &net.points).unwrap();
    for (x, t) in p.points.iter().zip(&net.points) {
        assert!(
            (sim.apply(x) - t).norm() < 1e-8,
            "{}",
            (sim.apply(x) - t).norm()
        );
    }
}

/// Both adjustments ended usable at the same cost (1e-9 of it).
fn assert_same_minimum(sa: &AdjustSummary, sb: &AdjustSummary) {
    assert!(sa.is_usable() && sb.is_usable(), "{sa:?} {sb:?}");
    assert!(
        (sa.final_cost - sb.final_cost).abs() <= 1e-9 * sa.final_cost,
        "{} vs {}",
        sa.final_cost,
        sb.final_cost
    );
}

/// Observations of one point by one camera share one Schur block (the solver sums them per
/// (camera, point) pair, as a video frame's neighbours observe the same target at other
/// times): splitting each observation into two copies of half its weight, the copies placed
/// apart in the list, leaves the least-squares normal equations as they were, so every step
/// is the same. A wrong block would still converge (the gradient is summed per observation)
/// but by other steps: the first step is compared, relative to its length, then the cost at
/// convergence (the iteration counts differ by the rejected steps at rounding level near the
/// tight tolerances' end).
#[test]
fn split_observations_adjust_as_the_whole() {
    let net = network();
    let whole = perturbed(&net, 5, 0.3);
    let mut split = whole.clone();
    let halves: Vec<Observation> = whole
        .observations
        .iter()
        .map(|o| Observation {
            weight: 0.5 * o.weight,
            ..*o
        })
        .collect();
    split.observations = halves.iter().chain(halves.iter().rev()).copied().collect();
    let one_step = AdjustConfig {
        max_iterations: 1,
        ..tight()
    };
    let (mut a, mut b) = (whole.clone(), split.clone());
    bundle_adjust(&mut a, &one_step).unwrap();
    bundle_adjust(&mut b, &one_step).unwrap();
    for (k, ((x, y), x0)) in a
        .global
        .iter()
        .zip(&b.global)
        .zip(&whole.global)
        .enumerate()
    {
        if k >= 8 {
            continue; // b1, b2: fixed
        }
        assert!(
            (x - y).abs() <= 1e-9 * (x - x0).abs(),
            "intrinsic {k} after one step: {x} vs {y} (from {x0})"
        );
    }
    let (mut a, mut b) = (whole, split);
    let sa = bundle_adjust(&mut a, &tight()).unwrap();
    let sb = bundle_adjust(&mut b, &tight()).unwrap();
    assert_same_minimum(&sa, &sb);
}

/// Every value a problem adjusts, flattened: shared and per-camera values, poses (translation,
/// rotation vector), points.
fn state(p: &Problem<BrownModel>) -> Vec<f64> {
    let mut out: Vec<f64> = p.global.iter().chain(&p.local).copied().collect();
    for pose in &p.cam_from_world {
        out.extend(pose.translation.vector.iter());
        out.extend(pose.rotation.scaled_axis().iter());
    }
    out.extend(p.points.iter().flat_map(|x| x.iter().copied()));
    out
}

/// Eliminating the cameras instead of the points solves the same damped normal equations: on
/// the network with third-order rolling-shutter motions (24 values a frame, every third frame's
/// higher orders held, the others seen again `±1/30 s` away as a video's neighbours are; one
/// pose, b1 and b2 held) the first step agrees with the point elimination's to 1e-9 of its
/// length, and the adjustments end at the same cost and intrinsics. `Auto` takes the cameras
/// here (2 + 24·24 camera unknowns against 3 per point) and the points on BAL (49 cameras,
/// 7,776 points): the same numbers to the bit as the choice forced.
#[test]
fn eliminating_the_cameras_gives_the_same_steps() {
    let net = network();
    let free: Vec<bool> = (0..net.poses.len()).map(|c| c % 3 != 0).collect();
    let mut start = perturbed(&net, 7, 0.1)
        .with_rolling_shutter(1080.0, 0.02)
        .with_motion_order(MotionOrder::Third, &free);
    let neighbours: Vec<Observation> = start
        .observations
        .iter()
        .filter(|o| free[o.camera])
        .flat_map(|o| {
            [-1.0 / 30.0, 1.0 / 30.0].map(|dt| Observation {
                time_offset_s: dt,
                weight: 0.4,
                ..*o
            })
        })
        .collect();
    start.observations.extend(neighbours);
    start.fixed.poses = vec![4];
    let with = |elimination, config: AdjustConfig| AdjustConfig {
        elimination,
        ..config
    };
    let one_step = AdjustConfig {
        max_iterations: 1,
        ..tight()
    };
    let x0 = state(&start);
    let step = |elimination| {
        let mut p = start.clone();
        let s = bundle_adjust(&mut p, &with(elimination, one_step)).unwrap();
        assert_eq!(s.successful_steps, 1, "{s:?}");
        let x = state(&p);
        (
            x.iter().zip(&x0).map(|(a, b)| a - b).collect::<Vec<f64>>(),
            x,
        )
    };
    let (by_points, _) = step(Elimination::Points);
    let (by_cameras, x_cameras) = step(Elimination::Cameras);
    let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
    let diff: Vec<f64> = by_points
        .iter()
        .zip(&by_cameras)
        .map(|(a, b)| a - b)
        .collect();
    assert!(
        norm(&diff) <= 1e-9 * norm(&by_points),
        "steps differ by {} of {}",
        norm(&diff),
        norm(&by_points)
    );
    assert!(
        step(Elimination::Auto).1 == x_cameras,
        "Auto did not eliminate the cameras"
    );

    let (mut a, mut b) = (start.clone(), start.clone());
    let sa = bundle_adjust(&mut a, &with(Elimination::Points, tight())).unwrap();
    let sb = bundle_adjust(&mut b, &with(Elimination::Cameras, tight())).unwrap();
    assert_same_minimum(&sa, &sb);
    for (k, (x, y)) in a.global.iter().zip(&b.global).enumerate() {
        assert!(
            (x - y).abs() <= 1e-9 * x.abs().max(1.0),
            "intrinsic {k}: {x} vs {y}"
        );
    }

    let bal = pipemeasure::io::bal::read_bal(std::path::Path::new(
        "../shared/data/bal/problem-49-7776-pre.txt",
    ))
    .unwrap();
    let bal = problem_from_bal(&bal).unwrap();
    let bal_step = |elimination| {
        let mut p = bal.clone();
        bundle_adjust(
            &mut p,
            &AdjustConfig {
                max_iterations: 1,
                elimination,
                ..AdjustConfig::default()
            },
        )
        .unwrap();
        (p.local, p.points)
    };
    assert!(
        bal_step(Elimination::Auto) == bal_step(Elimination::Points),
        "Auto did not eliminate BAL's points"
    );
}

#[test]
fn inner_constraint_basis_spans_the_null_space() {
    // J·B = 0 for every observation of a consistent network: the similarity changes no image.
    let net = network();
    let p = perturbed(&net, 2, 0.0);
    let b = inner_constraint_basis(&p, true);
    let n_r = 10 + 6 * p.num_cameras();
    let h = 1e-6;
    for k in 0..7 {
        let mut q = p.clone();
        // Move every parameter along column k of B by h.
        for (g, v) in q.global.iter_mut().enumerate() {
            *v += h * b[g * 7 + k];
        }
        for c in 0..q.num_cameras() {
            let d: Vec<f64> = (0..6).map(|i| h * b[(10 + 6 * c + i) * 7 + k]).collect();
            q.cam_from_world[c] = pipemeasure::geometry::pose::retract(
                &q.cam_from_world[c],
                &nalgebra::Vector6::from_column_slice(&d),
            );
        }
        for (i, x) in q.points.iter_mut().enumerate() {
            for j in 0..3 {
                x[j] += h * b[(n_r + 3 * i + j) * 7 + k];
            }
        }
        for o in p.observations.iter().take(400) {
            let (a, z) = (p.residual(o).unwrap(), q.residual(o).unwrap());
            // First order in h: a change of h·(J·B) ≤ 1e-3·h·|J| px would show as ≫ h².
            assert!((a - z).norm() < 1e-8, "column {k}: {}", (a - z).norm());
        }
    }
}

#[test]
fn the_datum_is_free() {
    // A similarity of the initial values gives the same intrinsics and the same point
    // precision (scaled by s²).
    let net = network();
    let base = perturbed(&net, 3, 0.05);
    let mut a = base.clone();
    let reference_a = a.points.clone();
    bundle_adjust(&mut a, &tight()).unwrap();
    free_network_datum(&mut a, &reference_a).unwrap();
    let pa = precision(
        &a,
        PrecisionRequest {
            poses: false,
            points: true,
        },
    )
    .unwrap();

    let sim = Similarity {
        scale: 3.7,
        rotation: UnitQuaternion::from_euler_angles(0.4, -1.1, 2.0),
        translation: Vector3::new(120.0, -40.0, 7.5),
    };
    let mut b = base.clone();
    apply_similarity(&mut b, &sim);
    let reference_b = b.points.clone();
    bundle_adjust(&mut b, &tight()).unwrap();
    free_network_datum(&mut b, &reference_b).unwrap();
    let pb = precision(
        &b,
        PrecisionRequest {
            poses: false,
            points: true,
        },
    )
    .unwrap();

    for k in 0..8 {
        let (x, y) = (a.global[k], b.global[k]);
        assert!(
            (x - y).abs() <= 1e-7 * x.abs().max(1e-3),
            "intrinsic {k}: {x} vs {y}"
        );
    }
    let (sa, sb) = (pa.global_std(), pb.global_std());
    for k in 0..8 {
        assert!(
            (sa[k] - sb[k]).abs() <= 1e-5 * sa[k],
            "σ {k}: {} vs {}",
            sa[k],
            sb[k]
        );
    }
    assert!((pa.sigma0 - pb.sigma0).abs() < 1e-7 * pa.sigma0);
    let (ca, cb) = (pa.point_covariance.unwrap(), pb.point_covariance.unwrap());
    for (x, y) in ca.iter().zip(&cb) {
        let (ta, tb) = (x.trace(), y.trace() / (sim.scale * sim.scale));
        assert!((ta - tb).abs() <= 1e-5 * ta, "{ta} vs {tb}");
    }
    // Minimum trace: the inner-constraint datum gives a smaller total point variance than
    // fixing the datum elsewhere would; at least it is far below that of the perturbed start
    // moved by a similarity (a sanity bound: the sum over points is finite and positive).
    let total: f64 = ca.iter().map(|m| m.trace()).sum();
    assert!(total > 0.0 && total.is_finite());
}

#[test]
fn standard_deviations_agree_with_monte_carlo_spread() {
    // 200 repetitions rather than the 50 the issue names: the spread of 50 samples has a 10 %
    // sampling error of its own, so ±20 % would fail by chance for one of eight intrinsics about
    // a third of the time; with 200 (5 %) a ±20 % miss means the covariance is wrong.
    let net = network();
    let noise = 0.1;
    let runs: u64 = std::env::var("MC_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    let mut estimates: Vec<Vec<f64>> = Vec::new();
    let mut predicted = Vec::new();
    for seed in 0..runs {
        let mut p = perturbed(&net, 100 + seed, noise);
        bundle_adjust(&mut p, &AdjustConfig::default()).unwrap();
        if seed == 0 {
            let prec = precision(&p, PrecisionRequest::default()).unwrap();
            // σ with the known noise, not the estimated σ0.
            predicted = prec
                .global_std()
                .iter()
                .map(|s| s / prec.sigma0 * noise)
                .collect();
            assert!(
                (prec.sigma0 / noise - 1.0).abs() < 0.1,
                "σ0 {}",
                prec.sigma0
            );
        }
        estimates.push(p.global.clone());
    }
    for k in 0..8 {
        let mean = estimates.iter().map(|e| e[k]).sum::<f64>() / runs as f64;
        let var = estimates.iter().map(|e| (e[k] - mean).powi(2)).sum::<f64>() / (runs - 1) as f64;
        let spread = var.sqrt();
        let ratio = spread / predicted[k];
        eprintln!(
            "intrinsic {k}: Monte-Carlo σ {spread:.4e}, predicted {:.4e}, ratio {ratio:.3}",
            predicted[k]
        );
        assert!(
            (0.8..=1.2).contains(&ratio),
            "intrinsic {k}: Monte-Carlo σ {spread:.3e}, predicted {:.3e} (ratio {ratio:.3})",
            predicted[k]
        );
    }
}

#[test]
fn bal_problem_reaches_the_ceres_cost() {
    let path = std::path::Path::new("../shared/data/bal/problem-49-7776-pre.txt");
    let bal = pipemeasure::io::bal::read_bal(path).unwrap();
    assert_eq!(
        (bal.cameras.len(), bal.points.len(), bal.observations.len()),
        (49, 7776, 31843)
    );
    let mut p = problem_from_bal(&bal).unwrap();
    let s = bundle_adjust(&mut p, &AdjustConfig::default()).unwrap();
    // Ceres 2.1 on the same file: 8.509e5 → 1.3344e4.
    // Ceres' figure has four significant digits.
    assert!((s.initial_cost - 8.509e5).abs() <= 0.0005e5, "{s:?}");
    assert!(s.final_cost <= 1.3345e4, "{s:?}");
}

/// The network's observations with `noise_px` of independent noise and, per frame, a radial
/// distortion `Δ = κ·(r/c)²·(uv − centre)` of its own (κ of σ `radial_sd`): an error shared by
/// all the targets of a frame, as a frame's motion error or its focus breathing is, and one
/// no pose can take up.
fn with_frame_errors(
    net: &Network,
    seed: u64,
    noise_px: f64,
    radial_sd: f64,
) -> Problem<BrownModel> {
    let mut p = perturbed(net, seed, noise_px);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
    let kappa: Vec<f64> = (0..net.poses.len())
        .map(|_| radial_sd * gaussian(&mut rng))
        .collect();
    let centre = Vector2::new(net.truth.u0, net.truth.v0);
    for o in &mut p.observations {
        let d = o.uv - centre;
        o.uv += d * (kappa[o.camera] * (d.norm() / net.truth.c).powi(2));
    }
    p
}

/// Monte-Carlo σ of the shared intrinsics `of` over `runs` problems of `make`, with the RMS
/// over the runs of the adjustment's σ and of the jackknife's.
fn spread_and_sigmas<const N: usize>(
    runs: u64,
    of: [usize; N],
    make: impl Fn(u64) -> Problem<BrownModel>,
) -> ([f64; N], [f64; N], [f64; N]) {
    let mut estimates = Vec::new();
    let (mut formal, mut jack) = ([0.0; N], [0.0; N]);
    for seed in 0..runs {
        let mut p = make(seed);
        bundle_adjust(&mut p, &AdjustConfig::default()).unwrap();
        let prec = precision(&p, PrecisionRequest::default()).unwrap();
        let j = frame_jackknife(&p, &AdjustConfig::default()).unwrap();
        assert_eq!(j.replicates.len(), JACKKNIFE_GROUPS);
        for (i, &k) in of.iter().enumerate() {
            formal[i] += prec.global_std()[k].powi(2);
            jack[i] += j.std(k).powi(2);
        }
        estimates.push(p.global.clone());
    }
    let n = runs as f64;
    let mut spread = [0.0; N];
    for (i, &k) in of.iter().enumerate() {
        let mean = estimates.iter().map(|e| e[k]).sum::<f64>() / n;
        spread[i] =
            (estimates.iter().map(|e| (e[k] - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        formal[i] = (formal[i] / n).sqrt();
        jack[i] = (jack[i] / n).sqrt();
    }
    (spread, formal, jack)
}

/// Monte-Carlo runs of the jackknife tests: the spread of 60 has a sampling error of 9 %.
const JACKKNIFE_RUNS: u64 = 60;

#[test]
fn the_frame_jackknife_agrees_with_the_covariance_on_independent_noise() {
    // Independent noise: the adjustment's σ is right (see the Monte-Carlo test above), and the
    // jackknife over the frames must find the same spread of c, u0, v0 and k1.
    let net = network();
    let (spread, formal, jack) = spread_and_sigmas(JACKKNIFE_RUNS, [0, 1, 2, 3], |s| {
        perturbed(&net, 500 + s, 0.1)
    });
    for k in 0..4 {
        let ratio = jack[k] / spread[k];
        eprintln!(
            "intrinsic {k}: Monte-Carlo σ {:.4e}, adjustment {:.4e}, jackknife {:.4e}",
            spread[k], formal[k], jack[k]
        );
        assert!(
            (0.7..=1.4).contains(&ratio),
            "intrinsic {k}: jackknife σ {:.4e} against the Monte-Carlo {:.4e}",
            jack[k],
            spread[k]
        );
    }
}

#[test]
fn the_frame_jackknife_sees_errors_shared_within_a_frame() {
    // A radial error of its own per frame (κ of σ 3·10⁻³: 0.9 px at 700 px from the centre) on
    // top of 0.02 px of noise: the adjustment counts every target as independent and
    // under-states the σ of k1; the jackknife over the frames follows the Monte-Carlo spread.
    let net = network();
    let (spread, formal, jack) = spread_and_sigmas(JACKKNIFE_RUNS, [3], |s| {
        with_frame_errors(&net, 700 + s, 0.02, 3e-3)
    });
    eprintln!(
        "k1: Monte-Carlo σ {:.4e}, adjustment {:.4e}, jackknife {:.4e}",
        spread[0], formal[0], jack[0]
    );
    assert!(
        formal[0] < 0.6 * spread[0],
        "the adjustment's σ of k1 {:.4e} against the Monte-Carlo {:.4e}: the frame errors do not show",
        formal[0],
        spread[0]
    );
    let ratio = jack[0] / spread[0];
    assert!(
        (0.7..=1.4).contains(&ratio),
        "jackknife σ of k1 {:.4e} against the Monte-Carlo {:.4e}",
        jack[0],
        spread[0]
    );
}
