//! Self-consistency of the simulated pipe site: dense observations, the fused cloud, the TLS
//! scan and targets against the true geometry.
#![allow(clippy::unwrap_used)]

use std::path::Path;

use nalgebra::{Point3, Vector3};
use pipemeasure::io::observations::DenseObservations;
use pipemeasure::io::{ply, tls};
use pipemeasure::sim::sfm::SfmConfig;
use pipemeasure::sim::simulate::{SimulateOptions, SiteOptions, simulate_site};
use pipemeasure::sim::truth::{PipeTruth, Truth};

fn site(out: &Path, noise_free: bool, seed: u64) -> Truth {
    let mut options = SimulateOptions {
        width: 960,
        height: 540,
        seed,
        ..Default::default()
    };
    let mut site = SiteOptions::default();
    site.site.frames = 10;
    if noise_free {
        options.sfm = SfmConfig {
            rotation_noise_deg: 0.0,
            translation_noise_m: 0.0,
            // The perturbed-truth stand-in (its own bundle adjustment would co-adapt the poses
            // with its EXIF camera): exact poses, the cloud through the true camera.
            adjust: false,
            ..Default::default()
        };
        site.dense.noise_px = 0.0;
        site.tls.range_noise_m = 0.0;
        site.tls.target_noise_m = 0.0;
    }
    site.tls.offset = [500_000.0, 5_600_000.0, 100.0];
    simulate_site(&options, &site, out, &|_| {}).unwrap()
}

/// Distance of `p` from a pipe's surface.
fn pipe_distance(pipe: &PipeTruth, p: &Point3<f64>) -> f64 {
    let a = Vector3::from(pipe.axis_direction);
    let d = p - Point3::from(pipe.axis_point);
    (d - a * d.dot(&a)).norm() - pipe.radius
}

/// Distance of `p` (world) from the nearest surface of the site: wall y = 0, floor z = 0, pipes.
fn surface_distance(truth: &Truth, p: &Point3<f64>) -> f64 {
    let mut best = p.y.abs().min(p.z.abs());
    for pipe in &truth.pipes {
        best = best.min(pipe_distance(pipe, p).abs());
    }
    best
}

#[test]
fn noise_free_dense_observations_and_fused_cloud_are_exact() {
    let dir = tempfile::tempdir().unwrap();
    let truth = site(dir.path(), true, 31);
    let camera = truth.camera.camera();
    let obs = DenseObservations::read(&dir.path().join("dense/observations.bin")).unwrap();
    assert_eq!(obs.points.len(), truth.dense.as_ref().unwrap().points);
    assert!(obs.points.len() > 5000, "{} dense points", obs.points.len());
    // Each observation is the true projection (stored as f32: ≤ 1e-4 px at 960 px).
    let mut worst: f64 = 0.0;
    for p in obs.points.iter().step_by(7) {
        assert!(p.observations.len() >= 3);
        for o in &p.observations {
            let frame = &truth.frames[o.frame as usize];
            let uv = camera
                .project_world(&frame.cam_from_world(), &p.position.coords)
                .unwrap();
            worst = worst.max((uv - o.uv).norm());
        }
        // Points lie on their labelled surface.
        let label = &obs.labels[p.label as usize];
        let d = match label.as_str() {
            "wall" => p.position.y.abs(),
            "floor" => p.position.z.abs(),
            name => pipe_distance(
                truth.pipes.iter().find(|q| q.name == name).unwrap(),
                &p.position,
            )
            .abs(),
        };
        assert!(d < 1e-12, "point {} off its surface {label} by {d} m", p.id);
    }
    assert!(worst < 2e-4, "worst observation error {worst} px");
    // The fused cloud is the true points in the SfM frame (exact poses here).
    let fused = ply::read(&dir.path().join("dense/fused.ply"))
        .unwrap()
        .cloud;
    let sim = truth
        .sfm
        .as_ref()
        .unwrap()
        .stand_in
        .as_ref()
        .unwrap()
        .similarity
        .clone();
    assert_eq!(fused.len(), obs.points.len());
    // fused.ply.vis: per fused point the images (positions in the model's images file) it was
    // triangulated from — each the frame of one of its observations.
    let model = pipemeasure::io::colmap::Reconstruction::read(&dir.path().join("sparse")).unwrap();
    let order =
        pipemeasure::io::colmap::Reconstruction::image_file_order(&dir.path().join("sparse"))
            .unwrap();
    let vis =
        pipemeasure::io::vis::read(&dir.path().join("dense/fused.ply.vis"), fused.len()).unwrap();
    for (v, p) in vis.iter().zip(&obs.points).step_by(13) {
        let names: Vec<&str> = v
            .iter()
            .map(|&k| model.images[&order[k as usize]].name.as_str())
            .collect();
        let seen: Vec<&str> = p
            .observations
            .iter()
            .map(|o| obs.frames[o.frame as usize].as_str())
            .collect();
        assert_eq!(names, seen, "point {}", p.id);
    }
    let mut worst_rel: f64 = 0.0;
    for (f, p) in fused.points.iter().zip(&obs.points).step_by(11) {
        let expected = sim.apply(&p.position);
        worst_rel = worst_rel.max((f - expected).norm() / sim.scale);
    }
    // f32 storage of the observations bounds this: ~1e-4 px ≈ 0.2 µm at 1.5 m.
    assert!(
        worst_rel < 5e-6,
        "fused point error {worst_rel} m (true units)"
    );
}

#[test]
fn tls_scan_and_targets_sit_on_the_truth_with_the_stated_noise() {
    let dir = tempfile::tempdir().unwrap();
    let truth = site(dir.path(), false, 32);
    let tls_truth = truth.tls.as_ref().unwrap();
    let offset = Vector3::from(tls_truth.offset);
    let scan = ply::read(&dir.path().join("tls_scan.ply")).unwrap().cloud;
    assert_eq!(scan.len(), tls_truth.points);
    // Range noise σ = 1.5 mm along the ray: the distance to the surface is below 5σ, and its RMS
    // is close to σ (the ray meets surfaces obliquely, so a little below).
    let d: Vec<f64> = scan
        .points
        .iter()
        .step_by(13)
        .map(|p| surface_distance(&truth, &(p - offset)))
        .collect();
    let worst = d.iter().copied().fold(0.0, f64::max);
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
    assert!(
        worst < 5.0 * tls_truth.range_noise_m + 1e-6,
        "worst {worst} m"
    );
    assert!(
        rms > 0.5 * tls_truth.range_noise_m && rms < 1.2 * tls_truth.range_noise_m,
        "RMS {rms} m"
    );
    // Some scan points are on the pipe of interest, at its radius.
    let pipe = truth.pipes.iter().find(|p| p.of_interest).unwrap();
    let on_pipe = scan
        .points
        .iter()
        .filter(|p| pipe_distance(pipe, &(*p - offset)).abs() < 0.006)
        .count();
    assert!(
        on_pipe > 1000,
        "{on_pipe} scan points on the pipe of interest"
    );
    // Targets: noise σ = 1 mm per axis, offset applied.
    let targets = tls::read_targets(&dir.path().join("tls_targets.csv")).unwrap();
    assert_eq!(targets.len(), truth.targets.len());
    for (t, tt) in targets.iter().zip(&truth.targets) {
        assert_eq!(t.id, tt.id.to_string());
        let e = (t.position - offset - Point3::from(tt.centre)).norm();
        assert!(
            e < 5.0 * tls_truth.target_noise_m * 3f64.sqrt(),
            "target {}: {e} m",
            t.id
        );
    }
}

#[test]
fn video_site_with_focus_breathing_records_each_frames_principal_distance() {
    use pipemeasure::camera::BrownCamera;
    use pipemeasure::sim::devices::{FOCUS_REFERENCE_M, P30};
    use pipemeasure::sim::video::VideoConfig;
    let dir = tempfile::tempdir().unwrap();
    let options = SimulateOptions {
        width: 480,
        height: 270,
        seed: 33,
        video: Some(VideoConfig {
            focus_breathing: true,
            ..Default::default()
        }),
        ..Default::default()
    };
    let mut site = SiteOptions::default();
    site.site.frames = 6;
    site.dense.noise_px = 0.0;
    let truth = simulate_site(&options, &site, dir.path(), &|_| {}).unwrap();
    let video = truth.video.as_ref().unwrap();
    assert_eq!(video.focus_breathing_m, P30.focus_breathing_m);
    assert_eq!(video.readout_s, P30.readout_s);
    let c0 = truth.camera.intrinsics.c;
    let mut factors = Vec::new();
    for frame in &truth.frames {
        let m = frame.motion.as_ref().unwrap();
        let factor = m.principal_distance / c0;
        // The path is 1.5 m from the pipe, the wall 2 m: focused between 1 and 3 m, c is
        // c·(1 + β·(1/d − 1/2.5)) with β = 5.6 mm.
        let (near, far) = (
            1.0 + P30.focus_breathing_m * (1.0 / 1.0 - 1.0 / FOCUS_REFERENCE_M),
            1.0 + P30.focus_breathing_m * (1.0 / 3.0 - 1.0 / FOCUS_REFERENCE_M),
        );
        assert!(
            (far..=near).contains(&factor),
            "{}: factor {factor}",
            frame.name
        );
        factors.push(factor);
        // The views are seen through this frame's camera at their times.
        let mut camera: BrownCamera = truth.camera.camera();
        camera.intrinsics.c = m.principal_distance;
        for v in &frame.targets {
            let t = truth.targets.iter().find(|t| t.id == v.id).unwrap();
            let uv = camera
                .project_world(
                    &video.trajectory.cam_from_world(v.time_s.unwrap()),
                    &Vector3::from(t.centre),
                )
                .unwrap();
            assert!((uv - nalgebra::Vector2::from(v.centre_px)).norm() < 1e-8);
        }
    }
    // Focusing nearer than 2.5 m lengthens c: every frame here does.
    assert!(factors.iter().all(|&f| f > 1.0), "{factors:?}");
    let views: usize = truth.frames.iter().map(|f| f.targets.len()).sum();
    println!("factors {factors:?}, {views} target views");
    // The site's 8 targets, a few in each frame (20 with this seed).
    assert!(views >= 12, "{views} target views");
    // Dense observations are where the rolling-shutter camera sees the points: the pose at
    // the time of the observed row projects the point there (f32 storage: ≤ 1e-4 px).
    let obs = DenseObservations::read(&dir.path().join("dense/observations.bin")).unwrap();
    let (mut worst, mut shift, mut checked) = (0.0f64, 0.0f64, 0);
    for p in obs.points.iter().step_by(5) {
        for o in &p.observations {
            let frame = &truth.frames[o.frame as usize];
            let m = frame.motion.as_ref().unwrap();
            let mut camera: BrownCamera = truth.camera.camera();
            camera.intrinsics.c = m.principal_distance;
            let t = video.shutter(m.time_s).row_time(o.uv.y, camera.height);
            let uv = camera
                .project_world(&video.trajectory.cam_from_world(t), &p.position.coords)
                .unwrap();
            worst = worst.max((uv - o.uv).norm());
            let global = camera
                .project_world(&frame.cam_from_world(), &p.position.coords)
                .unwrap();
            shift = shift.max((global - o.uv).norm());
            checked += 1;
        }
    }
    println!(
        "{checked} dense observations: worst {worst:.2e} px from their row's projection, up to {shift:.3} px from the frame-time projection"
    );
    assert!(
        checked > 1000 && worst < 2e-4,
        "{checked} observations, worst {worst} px"
    );
    assert!(shift > 0.05, "rolling-shutter shift {shift} px");
    assert!(truth.dense.as_ref().unwrap().fused_points > 1000);
    assert!(dir.path().join("frames/frames.json").is_file());
}

#[test]
fn motionless_site_is_unchanged_by_the_video_simulator() {
    // FNV-1a hashes of main's files before video existed (commit 916d7eb; see
    // tests/sim_lab.rs motionless_rendering_is_unchanged_by_the_video_simulator).
    let fnv = |bytes: &[u8]| {
        bytes.iter().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
            (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3)
        })
    };
    let dir = tempfile::tempdir().unwrap();
    let options = SimulateOptions {
        width: 480,
        height: 270,
        seed: 5,
        ..Default::default()
    };
    let mut site = SiteOptions::default();
    site.site.frames = 4;
    simulate_site(&options, &site, dir.path(), &|_| {}).unwrap();
    for (file, hash) in [
        ("frames/frame_0001.png", 0x8dfe_86e3_46f4_3675_u64),
        ("frames/frame_0004.png", 0xd0c5_6120_5236_c2a9),
        ("truth.json", 0x1263_a3df_4417_30c2),
        ("dense/fused.ply", 0x7b31_6a23_5be6_1b83),
    ] {
        let got = fnv(&std::fs::read(dir.path().join(file)).unwrap());
        assert_eq!(got, hash, "{file}: {got:#018x}");
    }
}
