//! The main command's TLS association (`measure::scale::estimate_scale`): eight reconstructed
//! targets against TLS lists of 8 to 2,008 targets (the site's eight hidden among others
//! spread over a 60 × 30 × 12 m plant, 1 mm noise, 1e6 m coordinates). Issue 21: the
//! association was cubic in the list (2,008 targets: more than a minute); it is quadratic.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use nalgebra::{Point3, UnitQuaternion, Vector3};
use pipemeasure::adjust::Similarity;
use pipemeasure::measure::{ReconstructedTarget, ScaleConfig, estimate_scale};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The site's eight targets on a wall (y = 0), in metres.
fn wall() -> Vec<Point3<f64>> {
    let xs = [-1.5, -0.9, -0.2, 0.4, 1.1, 1.6, -1.2, 0.8];
    let zs = [0.6, 2.1, 1.0, 2.4, 0.7, 1.9, 1.5, 1.3];
    xs.iter()
        .zip(&zs)
        .map(|(&x, &z)| Point3::new(x, 0.0, z))
        .collect()
}

/// A TLS list of `others` + 8 targets and the eight as reconstructed in an SfM frame.
fn problem(others: usize) -> (Vec<ReconstructedTarget>, Vec<Point3<f64>>) {
    let offset = Vector3::new(5.0e5, 4.2e6, 310.0);
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let mut tls: Vec<Point3<f64>> = (0..others)
        .map(|_| {
            Point3::from(
                offset
                    + Vector3::new(
                        rng.random_range(-30.0..30.0),
                        rng.random_range(0.5..30.0),
                        rng.random_range(0.0..12.0),
                    ),
            )
        })
        .collect();
    let world = wall();
    for (k, p) in world.iter().enumerate() {
        let n = Vector3::from_fn(|_, _| 0.001 * (rng.random::<f64>() - 0.5) * 3.46);
        let at = (k * (others + 8) / 8).min(tls.len());
        tls.insert(at, p + offset + n);
    }
    let sfm = Similarity {
        scale: 0.37,
        rotation: UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0),
        translation: Vector3::new(4.0, -2.0, 7.5),
    };
    let reconstructed = world
        .iter()
        .enumerate()
        .map(|(k, p)| ReconstructedTarget {
            point: Point3::from(sfm.apply(&p.coords)),
            views: 3 + k,
        })
        .collect();
    (reconstructed, tls)
}

fn association(c: &mut Criterion) {
    let mut group = c.benchmark_group("scale/association");
    group.sample_size(10);
    for others in [0, 300, 600, 2000] {
        let (reconstructed, tls) = problem(others);
        group.bench_with_input(
            BenchmarkId::new("8 targets, TLS list of", tls.len()),
            &(reconstructed, tls),
            |b, (r, t)| {
                b.iter(|| {
                    let est = estimate_scale(r, t, &ScaleConfig::default()).unwrap();
                    assert_eq!(est.associated.len(), 8);
                    est.similarity.unwrap().scale
                });
            },
        );
    }
    // The worst case: a ninth reconstructed target that no TLS target matches (a mismatch),
    // so no pass associates every target and every seed triangle is tried.
    let (mut reconstructed, tls) = problem(2000);
    reconstructed.push(ReconstructedTarget {
        point: Point3::new(9.0, 9.0, 9.0),
        views: 20,
    });
    group.bench_function(
        BenchmarkId::new("8 of 9 targets (one unmatched), TLS list of", tls.len()),
        |b| {
            b.iter(|| {
                let est = estimate_scale(&reconstructed, &tls, &ScaleConfig::default()).unwrap();
                assert_eq!(est.associated.len(), 8);
                est.similarity.unwrap().scale
            });
        },
    );
    group.finish();
}

criterion_group!(benches, association);
criterion_main!(benches);
