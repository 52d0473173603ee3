//! Diagnostic: the rolling-shutter self-calibration of a simulated video lab from its *true*
//! target projections (no rendering, no detection): `cargo run --release --example
//! video_truth_adjust -- LAB/truth.json [NOISE_PX] [NEIGHBOUR_WEIGHT]`, or with
//! `sim:PRESET:WIDTH:TREMOR_DEG_S:SEED[:EXPOSURE_MS]` in place of the truth file to simulate
//! the lab's truth (`simulate lab --video --neighbours`) without rendering it. Each frame and
//! its neighbours see the targets' exact rolling-shutter projections (plus NOISE_PX of Gaussian
//! noise, default 0), the adjustment is the calibration's (third-order motions, or the fourth
//! with `MOTION_ORDER=4` in the environment; readout free; c u0 v0 k1 k2 p1 p2), and the camera
//! is scored against the truth over the frame: what is left is the motion model's own error.
#![allow(missing_docs)]

use std::path::PathBuf;

use nalgebra::Vector2;
use pipemeasure::adjust::{AdjustConfig, BrownModel, Observation, Problem, bundle_adjust};
use pipemeasure::calibrate::checks::{projection_difference, projection_difference_rotated};
use pipemeasure::camera::rolling::MotionOrder;
use pipemeasure::camera::{Intrinsics, Term};
use pipemeasure::experiments::calibration::{
    TRUTH_MIN_SEMI_MINOR_PX, truth_target_index, truth_target_points,
};
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::simulate::{SimulateOptions, lab_geometry};
use pipemeasure::sim::trajectory::MotionConfig;
use pipemeasure::sim::truth::Truth;
use pipemeasure::sim::video::VideoConfig;
use rand::{Rng, SeedableRng};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else {
        anyhow::bail!("usage: video_truth_adjust truth.json [NOISE_PX] [neighbour weight]");
    };
    let noise: f64 = args.get(1).map_or(Ok(0.0), |s| s.parse())?;
    let neighbour_weight: f64 = args.get(2).map_or(Ok(1.0), |s| s.parse())?;
    let truth = if let Some(spec) = path.strip_prefix("sim:") {
        // sim:PRESET:WIDTH:TREMOR:SEED[:EXPOSURE_MS] — the truth of `simulate lab --video
        // --neighbours` without rendering.
        let f: Vec<&str> = spec.split(':').collect();
        let [preset, width, tremor, seed, rest @ ..] = f.as_slice() else {
            anyhow::bail!("expected sim:PRESET:WIDTH:TREMOR:SEED[:EXPOSURE_MS], got `{path}`");
        };
        let width: u32 = width.parse()?;
        let video = VideoConfig {
            motion: MotionConfig {
                tremor_deg_s: tremor.parse()?,
                ..MotionConfig::default()
            },
            exposure_s: rest.first().map_or(Ok(8.0), |s| s.parse::<f64>())? / 1e3,
            neighbours: true,
            ..VideoConfig::default()
        };
        let options = SimulateOptions {
            device: (*preset).into(),
            width,
            height: width * 9 / 16,
            seed: seed.parse()?,
            video: Some(video),
            ..SimulateOptions::default()
        };
        lab_geometry(&options, &LabConfig::default())?.0
    } else {
        Truth::read(&PathBuf::from(path))?
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut gauss = move || {
        let (a, b): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    };
    let index_of = truth_target_index(&truth);
    let (point_of, points) = truth_target_points(&truth);
    let mut observations = Vec::new();
    let mut has_neighbours = Vec::new();
    for (k, f) in truth.frames.iter().enumerate() {
        let mut views = vec![(0.0, 1.0, &f.targets)];
        for n in &f.neighbours {
            let dt = n.motion.as_ref().and_then(|m| m.dt_s).unwrap_or(0.0);
            views.push((dt, neighbour_weight, &n.targets));
        }
        has_neighbours.push(f.neighbours.len() == 2);
        for (dt, weight, targets) in views {
            for t in targets.iter() {
                let Some(p) = index_of
                    .get(&t.id)
                    .filter(|_| t.fitted.b >= TRUTH_MIN_SEMI_MINOR_PX)
                    .and_then(|&k| point_of[k])
                else {
                    continue;
                };
                observations.push(Observation {
                    camera: k,
                    point: p,
                    uv: Vector2::new(t.centre_px[0], t.centre_px[1])
                        + noise * Vector2::new(gauss(), gauss()),
                    weight,
                    time_offset_s: dt,
                });
            }
        }
    }
    let tru = truth.camera.intrinsics;
    let start = Intrinsics::pinhole(tru.c * 1.002, tru.u0 + 1.0, tru.v0 - 1.0);
    let height = f64::from(truth.camera.height);
    let mut global = start.to_array().to_vec();
    global.push(0.025);
    let model = BrownModel::rolling_shutter(height);
    let cameras: Vec<_> = truth.frames.iter().map(|f| f.cam_from_world()).collect();
    let local = truth
        .frames
        .iter()
        .flat_map(|f| {
            let m = f.motion.as_ref();
            let w = m.map_or([0.0; 3], |m| m.angular_velocity);
            let v = m.map_or([0.0; 3], |m| m.linear_velocity);
            [w[0], w[1], w[2], v[0], v[1], v[2]]
        })
        .collect();
    let first = Problem::new(model, cameras, local, global, points, observations)?;
    // MOTION_ORDER=4 tries fourth-order motions (the calibration's are third order).
    let order = match std::env::var("MOTION_ORDER").as_deref() {
        Ok("4") => MotionOrder::Fourth,
        Ok("2") => MotionOrder::Second,
        _ => MotionOrder::Third,
    };
    let mut problem = first.with_motion_order(order, &has_neighbours);
    // The terms the truth does not have are held (the selection's job is not judged here).
    problem.fixed.global = [Term::K3, Term::B1, Term::B2]
        .into_iter()
        .filter(|t| tru.get(*t) == 0.0)
        .map(Term::index)
        .collect();
    let config = AdjustConfig {
        max_iterations: 200,
        ..AdjustConfig::default()
    };
    let summary = bundle_adjust(&mut problem, &config)?;
    let mut a = [0.0; 10];
    a.copy_from_slice(&problem.global[..10]);
    let est = Intrinsics::from_array(a);
    let size = (truth.camera.width, truth.camera.height);
    let diff = projection_difference(&est, &tru, size);
    let rotated = projection_difference_rotated(&est, &tru, size);
    let n = problem.observations.len() as f64;
    println!(
        "{} observations, {} iterations, RMS residual {:.5} px",
        problem.observations.len(),
        summary.iterations,
        (2.0 * summary.final_cost / n).sqrt()
    );
    println!(
        "camera vs truth: max {:.4} px, RMS {:.4} px; after the best rotation max {:.4} px",
        diff.max, diff.rms, rotated.map.max
    );
    println!(
        "c {:+.4} u0 {:+.4} v0 {:+.4} px; readout {:.4} ms (true {:.4})",
        est.c - tru.c,
        est.u0 - tru.u0,
        est.v0 - tru.v0,
        1e3 * problem.global[BrownModel::READOUT],
        1e3 * truth.video.as_ref().map_or(f64::NAN, |v| v.readout_s)
    );
    Ok(())
}
