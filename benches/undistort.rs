//! Undistorting one 3840×2160 RGB frame of the p30 preset once the remap table exists
//! (issue goal: ≤ 60 ms on the 2-core machine), and building the table.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use image::{DynamicImage, ImageBuffer, Rgb};
use pipemeasure::camera::undistort_map::{Interpolation, OutputView, RemapTable, pinhole_for_view};
use pipemeasure::sim::devices::P30;

fn bench(c: &mut Criterion) {
    let cam = P30.camera;
    let target = pinhole_for_view(&cam, OutputView::Same).unwrap();
    let frame = DynamicImage::ImageRgb8(ImageBuffer::from_fn(cam.width, cam.height, |x, y| {
        Rgb([
            (x * 7 % 251) as u8,
            (y * 3 % 253) as u8,
            ((x ^ y) % 256) as u8,
        ])
    }));
    let mut group = c.benchmark_group("undistort");
    group.sample_size(20);
    for (name, interp) in [
        ("bicubic", Interpolation::Bicubic),
        ("bilinear", Interpolation::Bilinear),
    ] {
        let table = RemapTable::new(&cam, target, interp);
        group.bench_function(format!("apply-4k-rgb8/{name}"), |b| {
            b.iter(|| table.apply(&frame).unwrap())
        });
    }
    group.sample_size(10);
    group.bench_function("table-4k/bicubic", |b| {
        b.iter(|| RemapTable::new(&cam, target, Interpolation::Bicubic))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
