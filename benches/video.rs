//! Frame choice from video (issue 19, Deliver 3): the work per video frame of the measuring
//! pass at the analysis width (960×540): its pyramid, its sharpness and the feature flow to
//! the previous frame. A 90 s 4K30 video has 2700 such frames (decoding by ffmpeg not
//! included).
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use pipemeasure::video::flow::{Grey, Pyramid, apparent_motion, sharpness};

/// A textured frame (sums of sinusoids and a checker) shifted by `(sx, sy)`.
fn frame(sx: f32, sy: f32) -> Grey {
    let (w, h) = (960, 540);
    let data = (0..w * h)
        .map(|i| {
            let (u, v) = ((i % w) as f32 - sx, (i / w) as f32 - sy);
            let checker = if ((u / 24.0).floor() + (v / 24.0).floor()) as i32 % 2 == 0 {
                30.0
            } else {
                -30.0
            };
            128.0
                + checker
                + 40.0 * (0.21 * u).sin() * (0.17 * v).cos()
                + 20.0 * (0.07 * u - 0.19 * v).cos()
        })
        .collect();
    Grey {
        width: w,
        height: h,
        data,
    }
}

fn bench(c: &mut Criterion) {
    let a = frame(0.0, 0.0);
    let b = frame(3.4, -1.2);
    let previous = Pyramid::new(a);
    let mut group = c.benchmark_group("video");
    group.sample_size(20);
    group.bench_function("measure-frame-960x540", |bench| {
        bench.iter(|| {
            let s = sharpness(&b);
            let p = Pyramid::new(b.clone());
            (s, apparent_motion(&previous, &p))
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
