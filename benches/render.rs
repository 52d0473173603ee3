//! Rendering one 3840×2160 lab frame of the p30 preset (issue goal: ≤ 2 s on the 2-core
//! machine), split into the radiance pass and development (blur, noise, quantisation).
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use pipemeasure::sim::devices::P30;
use pipemeasure::sim::lab::{LabConfig, build_scene, path, reference_irradiance};
use pipemeasure::sim::render::{
    RayGrid, RenderConfig, develop, exposure_gain, render_frame, render_radiance,
};
use pipemeasure::sim::simulate::texel_size;

fn bench(c: &mut Criterion) {
    let camera = P30.camera;
    let lab = LabConfig::default();
    let scene = build_scene(&lab, texel_size(&camera), 1);
    let station = path(&lab, 1)[20];
    let rays = RayGrid::new(&camera);
    let config = RenderConfig::default();
    let gain = exposure_gain(&config, reference_irradiance(&scene, &lab));
    let mut group = c.benchmark_group("render");
    group.sample_size(10);
    group.bench_function("lab-frame-4k", |b| {
        b.iter(|| {
            render_frame(
                &scene,
                &camera,
                &rays,
                &station.cam_from_world,
                gain,
                &config,
                1,
                20,
            )
            .unwrap()
        })
    });
    group.bench_function("radiance-4k", |b| {
        b.iter(|| render_radiance(&scene, &camera, &rays, &station.cam_from_world, &config))
    });
    let radiance = render_radiance(&scene, &camera, &rays, &station.cam_from_world, &config);
    group.bench_function("develop-4k", |b| {
        b.iter(|| develop(radiance.clone(), &camera, gain, &config, 1, 20).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
