//! The simulated hand-held motion of the default lab and site videos (issue 19): the speeds at
//! the extracted frames, and at 25 fps the mean angular speed of plain 1 fps extraction, of the
//! frame half a second later, and of the steadiest frame of each second.
//!
//! `cargo run --release --example video_motion`
use pipemeasure::sim::lab::{LabConfig, path};
use pipemeasure::sim::site::{SiteConfig, path as site_path};
use pipemeasure::sim::trajectory::{MotionConfig, Trajectory};

/// Prints the figures of one trajectory through `poses` (one station per second).
fn report(name: &str, poses: Vec<pipemeasure::geometry::Rigid3>, seed: u64) {
    let n = poses.len();
    let tr = Trajectory::through(&poses, 1.0, &MotionConfig::default(), seed);
    let (mut wmin, mut wmax, mut vmin, mut vmax) = (f64::MAX, 0.0f64, f64::MAX, 0.0f64);
    for k in 0..n {
        let m = tr.motion(k as f64);
        let (w, v) = (
            m.angular_velocity.norm().to_degrees(),
            m.linear_velocity.norm(),
        );
        wmin = wmin.min(w);
        wmax = wmax.max(w);
        vmin = vmin.min(v);
        vmax = vmax.max(v);
    }
    let (mut plain, mut steadiest, mut half) = (0.0, 0.0, 0.0);
    for s in 0..n - 1 {
        let speeds: Vec<f64> = (0..25)
            .map(|j| {
                tr.motion(s as f64 + j as f64 / 25.0)
                    .angular_velocity
                    .norm()
                    .to_degrees()
            })
            .collect();
        plain += speeds[0];
        half += speeds[12];
        steadiest += speeds.iter().copied().fold(f64::MAX, f64::min);
    }
    let m = (n - 1) as f64;
    println!(
        "{name} seed {seed}: at frames {wmin:.2}-{wmax:.2} deg/s, {vmin:.3}-{vmax:.3} m/s; 25 fps: 1 fps extraction {:.2} deg/s, phase 0.5 {:.2}, steadiest {:.2} (ratio {:.3})",
        plain / m,
        half / m,
        steadiest / m,
        steadiest / plain
    );
}

/// Seeds 1–3, lab and site.
fn main() {
    for seed in [1, 2, 3] {
        report(
            "lab",
            path(&LabConfig::default(), seed)
                .iter()
                .map(|s| s.cam_from_world)
                .collect(),
            seed,
        );
        report(
            "site",
            site_path(&SiteConfig::default(), seed)
                .iter()
                .map(|s| s.cam_from_world)
                .collect(),
            seed,
        );
    }
}
