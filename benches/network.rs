//! The pipe network of a simulated plant room (issue 20): `extract_network` on the TLS scan
//! of room seed 1 (two stations, 3 mrad, 3.8 M points: 7 pipe segments among walls, a pump,
//! a valve, supports, conduits and a column), and the scan itself (parry3d ray casts); and a
//! scan beyond the search's budget read from its file (`extract_network_from`: room seed 1 at
//! 2 mrad, 8.5 M points, streamed, one point in two searched, the segments re-fitted on every
//! point; the 50 M-point figure of the README is `/usr/bin/time -v pipemeasure pipes` on the
//! 0.83 mrad scan).
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;
use pipemeasure::measure::scan::{ScanConfig, extract_network_from};
use pipemeasure::measure::{NetworkConfig, extract_network};
use pipemeasure::sim::plant::{PlantScanConfig, plant_room, scan};

fn network(c: &mut Criterion) {
    let room = plant_room(1);
    let config = PlantScanConfig::default();
    let (cloud, _) = scan(&room, &config, 1);
    let points: Vec<Vector3<f64>> = cloud.points.iter().map(|p| p.coords).collect();
    let mut group = c.benchmark_group("network");
    group.sample_size(10);
    group.bench_function("plant room seed 1, 3.8 M points", |b| {
        b.iter(|| {
            extract_network(&points, &NetworkConfig::default())
                .unwrap()
                .segments
                .len()
        })
    });
    group.bench_function("TLS scan of plant room seed 1 (2 stations, 3 mrad)", |b| {
        b.iter(|| scan(&room, &config, 1).0.len())
    });
    let dense = PlantScanConfig {
        step_rad: 2e-3,
        ..PlantScanConfig::default()
    };
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("room_2mrad.ply");
    pipemeasure::io::ply::write_binary(&file, &scan(&room, &dense, 1).0).unwrap();
    group.bench_function(
        "scan file of plant room seed 1 at 2 mrad, 8.5 M points",
        |b| {
            b.iter(|| {
                extract_network_from(&file, &ScanConfig::default(), &mut |_, _| {})
                    .unwrap()
                    .network
                    .segments
                    .len()
            })
        },
    );
    group.finish();
}

criterion_group!(benches, network);
criterion_main!(benches);
