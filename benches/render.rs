//! Rendering one 3840×2160 lab frame of the p30 preset (issue goal: ≤ 2 s on the 2-core
//! machine), split into the radiance pass and development (blur, noise, quantisation); and the
//! same frame filmed as video (issue 19): rolling shutter (20 ms readout) and motion blur
//! (8 ms exposure) along the hand-held trajectory, at a station with its drawn 3–9 °/s.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use pipemeasure::sim::devices::P30;
use pipemeasure::sim::lab::{LabConfig, build_scene, path, reference_irradiance};
use pipemeasure::sim::render::{
    MovingView, RayGrid, RenderConfig, develop, exposure_gain, render_frame, render_frame_moving,
    render_radiance, render_radiance_moving,
};
use pipemeasure::sim::shutter::{PoseTable, Shutter};
use pipemeasure::sim::simulate::texel_size;
use pipemeasure::sim::trajectory::{MotionConfig, Trajectory};

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

    // Video: the same station as frame 21 of the trajectory (t = 20 s).
    let poses: Vec<_> = path(&lab, 1).iter().map(|s| s.cam_from_world).collect();
    let trajectory = Trajectory::through(&poses, 1.0, &MotionConfig::default(), 1);
    let shutter = Shutter {
        time_s: 20.0,
        readout_s: P30.readout_s,
        exposure_s: 0.008,
    };
    let (t0, t1) = shutter.span();
    let table = PoseTable::new(|t| trajectory.cam_from_world(t), t0, t1);
    let view = MovingView {
        camera: &camera,
        rays: &rays,
        ray_scale: 1.0,
        poses: &table,
        shutter,
    };
    group.bench_function("lab-video-frame-4k", |b| {
        b.iter(|| render_frame_moving(&scene, &view, gain, &config, 1, 20).unwrap())
    });
    group.bench_function("video-radiance-4k", |b| {
        b.iter(|| render_radiance_moving(&scene, &view, &config, 1, 20))
    });
    group.bench_function("pose-table", |b| {
        b.iter(|| PoseTable::new(|t| trajectory.cam_from_world(t), t0, t1))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
