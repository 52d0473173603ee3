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

/// Point–surface distances of 1 M points to a pipe: the fit's residual (distance to the
/// infinite axis less the radius, one cross product) against parry3d's `distance_to_point` on
/// the finite solid cylinder with its pose (the README's "where parry3d did not replace
/// hand-written geometry").
fn residuals(c: &mut Criterion) {
    use parry3d_f64::query::PointQuery;
    use pipemeasure::measure::cylinder::Cylinder;
    let (a, b, r) = (
        Vector3::new(0.3, 0.2, 1.0),
        Vector3::new(2.3, 1.2, 1.4),
        0.057,
    );
    let d = (b - a).normalize();
    let pipe = Cylinder {
        point: a,
        direction: d,
        radius: r,
    };
    let (pose, solid) = pipemeasure::geometry::solid::cylinder_between(&a, &b, r);
    let points: Vec<Vector3<f64>> = (0..1_000_000)
        .map(|k| {
            let t = (k as f64 * 0.618_034).fract();
            let phi = k as f64 * 2.399_963;
            let (e1, e2) = pipe.cross_section_basis();
            a + (b - a) * t + (e1 * phi.cos() + e2 * phi.sin()) * (r + 1e-3 * (phi * 7.0).sin())
        })
        .collect();
    let mut group = c.benchmark_group("residual");
    group.sample_size(20);
    group.bench_function("fit residual, 1 M points", |bench| {
        bench.iter(|| points.iter().map(|p| pipe.residual(p).abs()).sum::<f64>())
    });
    group.bench_function("parry distance_to_point, 1 M points", |bench| {
        bench.iter(|| {
            points
                .iter()
                .map(|p| {
                    solid.distance_to_point(
                        &pose,
                        parry3d_f64::math::Vector::new(p.x, p.y, p.z),
                        false,
                    )
                })
                .sum::<f64>()
        })
    });
    group.finish();
}

criterion_group!(benches, network, residuals);
criterion_main!(benches);
