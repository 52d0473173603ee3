//! The bundle adjustment engine: the public BAL problem-49-7776 (goal: Ceres 2.1's final cost
//! 1.3344e4 in less than its 1.9 s on one thread / 1.5 s on two) and one self-calibrating
//! adjustment of a simulated 90-frame 4K lab (P30 preset, true centres + 0.01 px noise, c,
//! u0, v0, k1, k2, p1, p2 free), also with the rolling-shutter model (a motion per frame, 540
//! unknowns more, readout held: the selection's rolling-shutter candidate; issue 19's goal
//! ≤ 0.5 s), and the readout time's estimate over the neighbouring video frames (fourth-order
//! motions, 24 per frame, 2160 unknowns, each frame's targets also seen `±1/30 s` away,
//! readout free: `calibrate::selection::estimate_readout_time`'s adjustment), and the grouped
//! jackknife over the frames that then checks its covariance (`calibrate::jackknife`, ten
//! adjustments of nine tenths of the frames). Reading and building the problems is outside the
//! measurement.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Vector2, Vector3};
use pipemeasure::adjust::{
    AdjustConfig, BrownModel, Observation, Problem, bundle_adjust, problem_from_bal,
};
use pipemeasure::calibrate::jackknife::frame_jackknife;
use pipemeasure::calibrate::selection::NEIGHBOUR_MOTION_ORDER;
use pipemeasure::camera::Intrinsics;
use pipemeasure::camera::rolling::{self, Motion, RowTiming};
use pipemeasure::experiments::calibration::truth_target_problem;
use pipemeasure::io::bal::read_bal;
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::simulate::{SimulateOptions, lab_geometry};

fn adjust(c: &mut Criterion) {
    let bal = read_bal(std::path::Path::new(
        "../shared/data/bal/problem-49-7776-pre.txt",
    ))
    .unwrap();
    let bal_problem = problem_from_bal(&bal).unwrap();
    let (truth, _) = lab_geometry(&SimulateOptions::default(), &LabConfig::default()).unwrap();
    let lab_problem = truth_target_problem(&truth, 0.01, 1);
    let mut group = c.benchmark_group("adjust");
    group.sample_size(10);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        group.bench_function(format!("bal-49-7776/{threads} thread(s)"), |b| {
            b.iter(|| {
                let mut p = bal_problem.clone();
                pool.install(|| bundle_adjust(&mut p, &AdjustConfig::default()).unwrap())
            });
        });
    }
    group.bench_function("lab-p30-4k-90", |b| {
        b.iter(|| {
            let mut p = lab_problem.clone();
            bundle_adjust(&mut p, &AdjustConfig::default()).unwrap()
        });
    });
    let mut rolling = lab_problem.with_rolling_shutter(2160.0, 0.02);
    rolling.fixed.global.push(BrownModel::READOUT);
    group.bench_function("lab-p30-4k-90-rolling-shutter", |b| {
        b.iter(|| {
            let mut p = rolling.clone();
            bundle_adjust(&mut p, &AdjustConfig::default()).unwrap()
        });
    });
    let neighbours = neighbour_problem(&lab_problem, &truth.camera.intrinsics);
    group.bench_function("lab-p30-4k-90-neighbours-fourth-order", |b| {
        b.iter(|| {
            let mut p = neighbours.clone();
            bundle_adjust(&mut p, &AdjustConfig::default()).unwrap()
        });
    });
    // The jackknife over the frames that checks a video calibration's covariance: ten
    // adjustments of nine tenths of the frames, from the adjusted solution.
    let mut adjusted = neighbours.clone();
    bundle_adjust(&mut adjusted, &AdjustConfig::default()).unwrap();
    group.bench_function("lab-p30-4k-90-neighbours-jackknife", |b| {
        b.iter(|| frame_jackknife(&adjusted, &AdjustConfig::default()).unwrap());
    });
    group.finish();
}

/// The lab's targets seen by frames moving with a hand-held third-order motion (a seeded
/// 3–9 °/s turn and 0.05–0.15 m/s, accelerations and jerks of a few frame intervals' change)
/// under a 20 ms readout, in each frame and in its two neighbours `±1/30 s` away (exact
/// rolling-shutter projections, 0.01 px of noise; the neighbours weighted 0.4 as the variance
/// components put them), started as the selection leaves it: first-order motions at their
/// truth, higher orders (to the calibration's [`NEIGHBOUR_MOTION_ORDER`]) at zero, readout
/// 25 ms, the intrinsics of `start`'s problem.
fn neighbour_problem(start: &Problem<BrownModel>, camera: &Intrinsics) -> Problem<BrownModel> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(19);
    let (height, readout, dt) = (2160.0, 0.02, 1.0 / 30.0);
    let timing = RowTiming {
        readout_s: readout,
        height_px: height,
    };
    let mut unit = |scale: f64| {
        let v = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        v.normalize() * scale
    };
    let motions: Vec<Motion> = (0..start.num_cameras())
        .map(|_| Motion {
            angular: unit(6f64.to_radians()),
            linear: unit(0.1),
            angular_acceleration: unit(30f64.to_radians()),
            linear_acceleration: unit(0.5),
            angular_jerk: unit(600f64.to_radians()),
            linear_jerk: unit(10.0),
            ..Motion::default()
        })
        .collect();
    let mut noise = rand_chacha::ChaCha8Rng::seed_from_u64(20);
    let mut observations = Vec::new();
    for o in &start.observations {
        let p0 = start.cam_from_world[o.camera]
            .transform_point(&nalgebra::Point3::from(start.points[o.point]));
        for (offset, weight) in [(0.0, 1.0), (-dt, 0.4), (dt, 0.4)] {
            let Some((uv, _)) =
                rolling::project(camera, &timing, &motions[o.camera], &p0.coords, offset)
            else {
                continue;
            };
            let n = Vector2::new(
                noise.random_range(-0.017..0.017),
                noise.random_range(-0.017..0.017),
            );
            observations.push(Observation {
                uv: uv + n,
                weight,
                time_offset_s: offset,
                ..*o
            });
        }
    }
    let first = start.with_rolling_shutter(height, 0.025);
    let mut higher =
        first.with_motion_order(NEIGHBOUR_MOTION_ORDER, &vec![true; start.num_cameras()]);
    for (local, m) in higher
        .local
        .chunks_mut(NEIGHBOUR_MOTION_ORDER.values())
        .zip(&motions)
    {
        local[..6].copy_from_slice(&m.values()[..6]);
    }
    higher.observations = observations;
    higher
}

criterion_group!(benches, adjust);
criterion_main!(benches);
