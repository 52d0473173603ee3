//! Algorithm 2 + 3 (matching, robust triangulation, centre correction) on the paper's Table II
//! setting: three simulated 90-frame 4K labs (p30, iphone11, s10; 270 frames). Issue goal:
//! ≤ 5 s for the 270 frames on this 2-core machine. Scenario preparation (the simulator and
//! Algorithm 1) is outside the measurement.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use pipemeasure::calibrate::matching::MatchConfig;
use pipemeasure::experiments::matching::{Scenario, prepare, run};
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::simulate::SimulateOptions;

fn matching(c: &mut Criterion) {
    let prepared: Vec<_> = ["p30", "iphone11", "s10"]
        .iter()
        .map(|device| {
            prepare(&Scenario {
                options: SimulateOptions {
                    device: (*device).into(),
                    ..SimulateOptions::default()
                },
                lab: LabConfig::default(),
                ..Scenario::default()
            })
            .unwrap()
        })
        .collect();
    let mut group = c.benchmark_group("matching");
    group.sample_size(10);
    group.bench_function("270 frames 4K (3 x 90)", |b| {
        b.iter(|| {
            prepared
                .iter()
                .map(|p| run(p, &MatchConfig::default()).tracks.len())
                .sum::<usize>()
        });
    });
    group.finish();
}

criterion_group!(benches, matching);
criterion_main!(benches);
