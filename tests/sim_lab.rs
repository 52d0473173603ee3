//! Self-consistency of the simulated lab: rendered discs against the truth ellipses, the truth
//! centres against exact triangulation, the sparse model against the real COLMAP, and
//! determinism across thread counts.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::Path;
use std::process::Command;

use image::RgbImage;
use nalgebra::{Point3, Vector2, Vector3};
use pipemeasure::geometry::conic::{Ellipse, fit_ellipse_direct};
use pipemeasure::geometry::triangulation::{Observation, triangulate};
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::render::RenderConfig;
use pipemeasure::sim::simulate::{SimulateOptions, simulate_lab};
use pipemeasure::sim::truth::Truth;

fn small_lab(out: &Path, render: RenderConfig, seed: u64) -> Truth {
    let options = SimulateOptions {
        width: 960,
        height: 540,
        seed,
        render,
        ..Default::default()
    };
    let lab = LabConfig {
        frames: 6,
        ..Default::default()
    };
    simulate_lab(&options, &lab, out, &|_| {}).unwrap()
}

/// Grey level at a pixel position by bilinear interpolation (pixel centres at half-integers).
fn sample(img: &RgbImage, u: f64, v: f64) -> f64 {
    let (x, y) = (u - 0.5, v - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let at = |dx: f64, dy: f64| {
        let px = img.get_pixel((x0 + dx) as u32, (y0 + dy) as u32).0;
        (f64::from(px[0]) + f64::from(px[1]) + f64::from(px[2])) / 3.0
    };
    let top = at(0.0, 0.0) * (1.0 - fx) + at(1.0, 0.0) * fx;
    let bottom = at(0.0, 1.0) * (1.0 - fx) + at(1.0, 1.0) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// Edge points of a rendered disc, found independently of any detector: along 240 rays from the
/// truth centre, where the grey level crosses halfway between the disc just inside the edge and
/// the plate just outside.
fn edge_points(img: &RgbImage, e: &Ellipse) -> Vec<Vector2<f64>> {
    let mut pts = Vec::new();
    for k in 0..240 {
        let phi = std::f64::consts::TAU * f64::from(k) / 240.0;
        let edge = e.point(phi);
        let dir = (edge - e.centre()).normalize();
        let r = (edge - e.centre()).norm();
        let at = |s: f64| {
            let p = e.centre() + dir * s;
            sample(img, p.x, p.y)
        };
        // Levels 2.5 px inside and outside the edge (blur σ 0.7 px: fully settled there; the
        // plate extends 0.3 R beyond the disc, R ≥ 5 px here).
        let (inside, outside) = (at(r - 2.5), at(r + 1.4));
        let mid = (inside + outside) / 2.0;
        // Walk outward in 0.02 px steps and interpolate the crossing.
        let mut prev = (r - 2.0, at(r - 2.0));
        let mut s = r - 2.0;
        while s < r + 1.4 {
            s += 0.02;
            let v = at(s);
            if (prev.1 - mid) * (v - mid) <= 0.0 && prev.1 != v {
                let t = (mid - prev.1) / (v - prev.1);
                pts.push(e.centre() + dir * (prev.0 + t * (s - prev.0)));
                break;
            }
            prev = (s, v);
        }
    }
    pts
}

#[test]
fn rendered_discs_match_the_truth_ellipses() {
    let dir = tempfile::tempdir().unwrap();
    let render = RenderConfig {
        read_noise_dn: 0.3,
        shot_noise: 0.002,
        ..Default::default()
    };
    let truth = small_lab(dir.path(), render, 21);
    let mut errors = Vec::new();
    for frame in &truth.frames {
        let img = image::open(dir.path().join("frames").join(&frame.name))
            .unwrap()
            .to_rgb8();
        for view in &frame.targets {
            let e = view.fitted;
            if e.b < 5.0 {
                continue; // discs at least 10 px across
            }
            let pts = edge_points(&img, &e);
            assert!(
                pts.len() > 200,
                "target {} in {}: {} edge points",
                view.id,
                frame.name,
                pts.len()
            );
            let fit = fit_ellipse_direct(&pts).unwrap();
            errors.push((fit.centre() - e.centre()).norm());
        }
    }
    assert!(errors.len() > 50, "only {} discs checked", errors.len());
    let worst = errors.iter().copied().fold(0.0, f64::max);
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    println!(
        "{} discs: centre error RMS {rms:.4} px, worst {worst:.4} px",
        errors.len()
    );
    assert!(
        worst <= 0.05,
        "worst rendered-disc centre error {worst} px (RMS {rms})"
    );
}

#[test]
fn true_projected_centres_triangulate_to_the_true_3d_centres() {
    let dir = tempfile::tempdir().unwrap();
    let truth = small_lab(dir.path(), RenderConfig::default(), 22);
    let camera = truth.camera.camera();
    let mut checked = 0;
    for target in &truth.targets {
        let obs: Vec<Observation> = truth
            .frames
            .iter()
            .filter_map(|f| {
                let v = f.targets.iter().find(|v| v.id == target.id)?;
                let xy = camera
                    .intrinsics
                    .ideal_from_pixel(&Vector2::from(v.centre_px))
                    .unwrap();
                Some(Observation::normalized(&f.cam_from_world(), xy))
            })
            .collect();
        if obs.len() < 2 {
            continue;
        }
        let x = triangulate(&obs).unwrap();
        let truth_x = Point3::from(target.centre);
        let rel = (x - truth_x).norm() / truth_x.coords.norm();
        assert!(rel <= 1e-9, "target {}: relative error {rel}", target.id);
        checked += 1;
    }
    assert!(checked > 50, "{checked} targets checked");
}

#[test]
fn pinhole_truth_centre_is_the_pole_of_the_vanishing_line() {
    // Independent check of the pinhole ellipse and centre (math §3.3): the image of the circle's
    // centre is the pole of the plane's vanishing line l = K⁻ᵀ R n with respect to the conic.
    let dir = tempfile::tempdir().unwrap();
    let truth = small_lab(dir.path(), RenderConfig::default(), 23);
    let k = pipemeasure::sim::truth::pinhole_matrix(&truth.camera.intrinsics);
    let kinv_t = k.try_inverse().unwrap().transpose();
    let mut largest: f64 = 0.0;
    for frame in &truth.frames {
        let pose = frame.cam_from_world();
        for v in &frame.targets {
            let t = truth.targets.iter().find(|t| t.id == v.id).unwrap();
            let l = kinv_t * (pose.rotation * Vector3::from(t.normal));
            let conic = v.pinhole.to_conic();
            let pole = conic.try_inverse().unwrap() * l;
            let pole = Vector2::new(pole.x / pole.z, pole.y / pole.z);
            let err = (pole - Vector2::from(v.pinhole_centre_px)).norm();
            assert!(
                err < 1e-6,
                "target {} in {}: pole {pole:?} vs centre {:?}",
                v.id,
                frame.name,
                v.pinhole_centre_px
            );
            largest = largest.max((v.pinhole.centre() - Vector2::from(v.pinhole_centre_px)).norm());
        }
    }
    assert!(
        largest > 0.01,
        "some view must show eccentricity, largest {largest} px"
    );
}

#[test]
fn same_seed_gives_identical_files_whatever_the_thread_count() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let run = |out: &Path, threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let options = SimulateOptions {
                    width: 480,
                    height: 270,
                    seed: 5,
                    ..Default::default()
                };
                simulate_lab(
                    &options,
                    &LabConfig {
                        frames: 3,
                        ..Default::default()
                    },
                    out,
                    &|_| {},
                )
                .unwrap();
            });
    };
    run(a.path(), 1);
    run(b.path(), 3);
    let files = [
        "truth.json",
        "frames/frame_0001.png",
        "frames/frame_0003.png",
        "sparse/cameras.txt",
        "sparse/images.txt",
        "sparse/points3D.txt",
    ];
    for f in files {
        let (x, y) = (
            std::fs::read(a.path().join(f)).unwrap(),
            std::fs::read(b.path().join(f)).unwrap(),
        );
        assert!(x == y, "{f} differs between 1 and 3 threads");
    }
}

#[test]
fn colmap_reads_the_stand_in_model() {
    if !common::colmap_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let truth = small_lab(dir.path(), RenderConfig::default(), 24);
    let out = Command::new("colmap")
        .args(["model_analyzer", "--path"])
        .arg(dir.path().join("sparse"))
        .env("QT_QPA_PLATFORM", "offscreen")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let log =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(
        log.contains(&format!("Images: {}", truth.frames.len())),
        "{log}"
    );
}

#[test]
fn real_colmap_reconstructs_a_short_rendered_sequence() {
    use pipemeasure::sim::simulate::SfmSource;
    if !common::colmap_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let options = SimulateOptions {
        width: 960,
        height: 540,
        seed: 25,
        sfm_source: SfmSource::Colmap,
        ..Default::default()
    };
    let truth = simulate_lab(
        &options,
        &LabConfig {
            frames: 8,
            ..Default::default()
        },
        dir.path(),
        &|_| {},
    )
    .unwrap();
    let model = pipemeasure::io::colmap::Reconstruction::read(&dir.path().join("sparse")).unwrap();
    assert_eq!(
        model.images.len(),
        8,
        "COLMAP registered {} of 8 frames",
        model.images.len()
    );
    let cam = model.cameras.values().next().unwrap();
    let f = cam.params[0];
    let c = truth.camera.intrinsics.c;
    // COLMAP's in-situ focal length for this sequence is within 2 % of the truth.
    assert!((f / c - 1.0).abs() < 0.02, "COLMAP f {f} vs true c {c}");
    // Relative geometry: the distance between the first and last camera centres, normalised by
    // the distance between the first two, matches the truth (COLMAP's frame is a similarity).
    let centre = |q: [f64; 4], t: [f64; 3]| {
        pipemeasure::geometry::pose::camera_centre(&pipemeasure::geometry::pose::rigid_from_colmap(
            q, t,
        ))
    };
    let est: Vec<Point3<f64>> = (1..=8)
        .map(|k| {
            let im = model
                .images
                .values()
                .find(|i| i.name == options.frame_name(k - 1))
                .unwrap();
            centre(im.qvec, im.tvec)
        })
        .collect();
    let tru: Vec<Point3<f64>> = truth
        .frames
        .iter()
        .map(|f| centre(f.qvec, f.tvec))
        .collect();
    let ratio = |p: &[Point3<f64>]| (p[7] - p[0]).norm() / (p[1] - p[0]).norm().max(1e-12);
    let (re, rt) = (ratio(&est), ratio(&tru));
    assert!(
        (re / rt - 1.0).abs() < 0.05,
        "shape ratio {re} vs truth {rt}"
    );
}
