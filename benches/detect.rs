//! Detection on a 3840×2160 simulated lab frame: time per frame on one core (issue goal:
//! ≤ 100 ms) and frames per second on the whole machine (frames in parallel).
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use image::DynamicImage;
use pipemeasure::detect::{DetectConfig, Detector};
use pipemeasure::sim::devices::P30;
use pipemeasure::sim::lab::{LabConfig, build_scene, path, reference_irradiance};
use pipemeasure::sim::render::{RayGrid, RenderConfig, exposure_gain, render_frame};
use pipemeasure::sim::simulate::texel_size;
use rayon::prelude::*;

fn frames(n: usize) -> Vec<DynamicImage> {
    let camera = P30.camera;
    let lab = LabConfig::default();
    let scene = build_scene(&lab, texel_size(&camera), 1);
    let config = RenderConfig::default();
    let gain = exposure_gain(&config, reference_irradiance(&scene, &lab));
    let rays = RayGrid::new(&camera);
    let stations = path(&lab, 1);
    (0..n)
        .map(|k| {
            let st = stations[10 + 20 * k];
            DynamicImage::ImageRgb8(
                render_frame(
                    &scene,
                    &camera,
                    &rays,
                    &st.cam_from_world,
                    gain,
                    &config,
                    1,
                    k as u64,
                )
                .unwrap()
                .image,
            )
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let frames = frames(4);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let mut group = c.benchmark_group("detect");
    group.sample_size(10);
    // A detector reuses its buffers from frame to frame, as the CLI and the calibration do.
    let mut detector = Detector::new(DetectConfig::default()).unwrap();
    let mut k = 0;
    group.bench_function("frame-4k/one-core", |b| {
        b.iter(|| {
            k = (k + 1) % frames.len();
            one.install(|| detector.detect(&frames[k]).ellipses.len())
        })
    });
    group.throughput(Throughput::Elements(frames.len() as u64));
    group.bench_function("frames-4k/all-cores", |b| {
        b.iter(|| {
            frames
                .par_iter()
                .map_init(
                    || Detector::new(DetectConfig::default()).unwrap(),
                    |d, f| d.detect(f).ellipses.len(),
                )
                .sum::<usize>()
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
