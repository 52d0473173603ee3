//! The bundle adjustment engine: the public BAL problem-49-7776 (goal: Ceres 2.1's final cost
//! 1.3344e4 in less than its 1.9 s on one thread / 1.5 s on two) and one self-calibrating
//! adjustment of a simulated 90-frame 4K lab (P30 preset, true centres + 0.01 px noise, c,
//! u0, v0, k1, k2, p1, p2 free), also with the rolling-shutter model (a motion per frame, 540
//! unknowns more, readout held: the selection's rolling-shutter candidate; issue 19's goal
//! ≤ 0.5 s). Reading and building the problems is outside the measurement.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use pipemeasure::adjust::{AdjustConfig, BrownModel, bundle_adjust, problem_from_bal};
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
    group.finish();
}

criterion_group!(benches, adjust);
criterion_main!(benches);
