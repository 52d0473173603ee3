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
use pipemeasure::sim::trajectory::Trajectory;
use pipemeasure::sim::truth::Truth;
use pipemeasure::sim::video::{VideoConfig, VideoMotion};

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

/// FNV-1a, 64 bit: a stable hash of file bytes.
fn fnv(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

#[test]
fn motionless_rendering_is_unchanged_by_the_video_simulator() {
    // FNV-1a hashes of the files written by main's simulator before video existed (commit
    // 916d7eb, this machine's x86-64 Linux build; libm's sin/exp enter the texture and the
    // noise, so another platform may need them regenerated with that commit). Still frames,
    // the truth and the sparse model must stay byte for byte what they were.
    let dir = tempfile::tempdir().unwrap();
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
        dir.path(),
        &|_| {},
    )
    .unwrap();
    let expected = [
        ("frames/frame_0001.png", 0x1225_ea56_8ed0_b7e3_u64),
        ("frames/frame_0002.png", 0xd48c_2742_4ea6_815a),
        ("frames/frame_0003.png", 0xab2e_1178_7f04_493c),
        ("truth.json", 0x866f_1b2a_b33d_5858),
        ("sparse/images.txt", 0xa593_2fcd_4308_e946),
        ("sparse/points3D.txt", 0xfe0a_4703_aedc_288c),
    ];
    for (file, hash) in expected {
        let got = fnv(&std::fs::read(dir.path().join(file)).unwrap());
        assert_eq!(got, hash, "{file}: {got:#018x}");
    }
    assert!(!dir.path().join("frames/frames.json").exists());
}

fn video_lab(out: &Path, width: u32, frames: usize, video: VideoConfig, seed: u64) -> Truth {
    let options = SimulateOptions {
        width,
        height: width * 9 / 16,
        seed,
        video: Some(video),
        ..Default::default()
    };
    let lab = LabConfig {
        frames,
        ..Default::default()
    };
    simulate_lab(&options, &lab, out, &|_| {}).unwrap()
}

/// ω and ν from one-sided second-order differences of the truth's trajectory after t
/// (independent of the analytic velocities the truth records; one-sided because some frame
/// times — the first, the last and those beside a turn without a pause — are knots, where the
/// path is only C²): with φ(s) = log(R(t + s)·R(t)ᵀ),
/// ω ≈ (4·φ(h) − φ(2h))/2h, and Ṫ likewise; error O(h²·jerk) ≈ 1e-8.
fn differences(tr: &Trajectory, t: f64) -> (Vector3<f64>, Vector3<f64>) {
    let h = 1e-5;
    let (m, a, b) = (
        tr.cam_from_world(t),
        tr.cam_from_world(t + h),
        tr.cam_from_world(t + 2.0 * h),
    );
    let phi = |p: &pipemeasure::geometry::Rigid3| (p.rotation * m.rotation.inverse()).scaled_axis();
    let w = (phi(&a) * 4.0 - phi(&b)) / (2.0 * h);
    let t_dot = (a.translation.vector * 4.0 - b.translation.vector - m.translation.vector * 3.0)
        / (2.0 * h);
    (w, t_dot - w.cross(&m.translation.vector))
}

#[test]
fn video_lab_has_hand_held_motion_neighbours_a_sidecar_and_a_full_rate_video() {
    let dir = tempfile::tempdir().unwrap();
    let config = VideoConfig {
        neighbours: true,
        frame_rate: 25.0,
        full_rate_width: Some(160),
        ..Default::default()
    };
    let truth = video_lab(dir.path(), 480, 6, config, 41);
    let video = truth.video.as_ref().unwrap();
    // The p30 preset's readout, the default exposure.
    assert_eq!(
        (video.readout_s, video.exposure_s, video.frame_rate),
        (0.020, 0.008, 25.0)
    );
    let tr = &video.trajectory;
    for (k, frame) in truth.frames.iter().enumerate() {
        let m = frame.motion.as_ref().unwrap();
        assert_eq!(m.time_s, k as f64);
        assert_eq!((m.readout_s, m.exposure_s, m.dt_s), (0.020, 0.008, None));
        // The frame's pose is the trajectory's at the frame time.
        let pose = tr.cam_from_world(m.time_s);
        assert!(pose.rotation.angle_to(&frame.cam_from_world().rotation) < 1e-12);
        assert!(
            (pose.translation.vector - frame.cam_from_world().translation.vector).norm() < 1e-12
        );
        let (w, v) = differences(tr, m.time_s);
        assert!(
            (w - Vector3::from(m.angular_velocity)).norm() < 1e-7,
            "frame {k}: ω"
        );
        assert!(
            (v - Vector3::from(m.linear_velocity)).norm() < 1e-7,
            "frame {k}: ν"
        );
        let (w_deg, v_m) = (w.norm().to_degrees(), v.norm());
        assert!(
            (3.0 - 1e-5..=9.0 + 1e-5).contains(&w_deg),
            "frame {k}: {w_deg} °/s"
        );
        assert!(
            (0.05 - 1e-7..=0.15 + 1e-7).contains(&v_m),
            "frame {k}: {v_m} m/s"
        );
        assert_eq!(m.principal_distance, truth.camera.intrinsics.c);
        // Neighbours: ±1/25 s, on disk, not in the sparse model.
        assert_eq!(frame.neighbours.len(), 2);
        for (n, (dt, suffix)) in frame.neighbours.iter().zip([(-0.04, "-1"), (0.04, "+1")]) {
            let nm = n.motion.as_ref().unwrap();
            assert_eq!(nm.dt_s, Some(dt));
            assert!((nm.time_s - (m.time_s + dt)).abs() < 1e-12);
            let stem = frame.name.trim_end_matches(".png");
            assert_eq!(n.name, format!("neighbours/{stem}{suffix}.png"));
            assert!(dir.path().join("frames").join(&n.name).is_file());
            assert!(!n.targets.is_empty() && n.image_id == frame.image_id);
        }
    }
    let model = pipemeasure::io::colmap::Reconstruction::read(&dir.path().join("sparse")).unwrap();
    assert_eq!(
        model.images.len(),
        6,
        "the sparse model holds the extracted frames only"
    );
    // The sidecar.
    let sidecar: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("frames/frames.json")).unwrap())
            .unwrap();
    assert_eq!(sidecar["schema"], "pipemeasure.frames/1");
    assert_eq!(sidecar["frames"][2]["name"], "frame_0003.png");
    assert_eq!(sidecar["frames"][2]["time_s"], 2.0);
    assert_eq!(
        sidecar["frames"][2]["neighbours"][1]["name"],
        "neighbours/frame_0003+1.png"
    );
    assert_eq!(sidecar["frames"][2]["neighbours"][0]["dt_s"], -0.04);
    // The full-rate video: 5 s at 25 fps, frame 1 at t = 0.
    let full = video.full_rate.as_ref().unwrap();
    assert_eq!((full.width, full.height, full.frames), (160, 90, 126));
    let motion: VideoMotion =
        serde_json::from_slice(&std::fs::read(dir.path().join("video/motion.json")).unwrap())
            .unwrap();
    assert_eq!(motion.frames.len(), 126);
    assert!(dir.path().join("video/frame_00126.png").is_file());
    let img = image::open(dir.path().join("video/frame_00001.png")).unwrap();
    assert_eq!((img.width(), img.height()), (160, 90));
    // Choosing the steadiest video frame of each second at least halves the angular speed of
    // plain 1 fps extraction (the frames at whole seconds).
    let (mut plain, mut steadiest) = (0.0, 0.0);
    for second in 0..5 {
        let frames = &motion.frames[25 * second..25 * (second + 1)];
        assert_eq!(
            frames[0].extracted.as_deref(),
            Some(truth.frames[second].name.as_str())
        );
        plain += frames[0].angular_speed_deg_s;
        steadiest += frames
            .iter()
            .map(|f| f.angular_speed_deg_s)
            .fold(f64::MAX, f64::min);
    }
    println!(
        "mean angular speed: 1 fps extraction {:.2} °/s, steadiest per second {:.2} °/s",
        plain / 5.0,
        steadiest / 5.0
    );
    assert!(
        steadiest <= 0.5 * plain,
        "steadiest {steadiest} vs plain {plain}"
    );
    match &full.mp4 {
        Some(name) => assert!(dir.path().join(name).is_file()),
        None => assert!(full.note.as_ref().unwrap().contains("ffmpeg")),
    }
}

#[test]
fn rolling_shutter_truth_centres_triangulate_with_the_poses_at_their_times() {
    let dir = tempfile::tempdir().unwrap();
    let truth = video_lab(dir.path(), 960, 6, VideoConfig::default(), 42);
    let camera = truth.camera.camera();
    let video = truth.video.as_ref().unwrap();
    let tr = &video.trajectory;
    let (mut checked, mut worst_frame_pose, mut largest_shift) = (0, 0.0f64, 0.0f64);
    for frame in &truth.frames {
        let shutter = video.shutter(frame.motion.as_ref().unwrap().time_s);
        for v in &frame.targets {
            // The centre is seen in the row its time says, through the pose at that time.
            let t = v.time_s.unwrap();
            assert!((shutter.row_time(v.centre_px[1], camera.height) - t).abs() < 1e-12);
            let target = truth.targets.iter().find(|x| x.id == v.id).unwrap();
            let uv = camera
                .project_world(&tr.cam_from_world(t), &Vector3::from(target.centre))
                .unwrap();
            assert!((uv - Vector2::from(v.centre_px)).norm() < 1e-8);
            let global = camera
                .project_world(&frame.cam_from_world(), &Vector3::from(target.centre))
                .unwrap();
            largest_shift = largest_shift.max((global - uv).norm());
        }
    }
    for target in &truth.targets {
        let views: Vec<(Observation, Observation)> = truth
            .frames
            .iter()
            .filter_map(|f| {
                let v = f.targets.iter().find(|v| v.id == target.id)?;
                let xy = camera
                    .intrinsics
                    .ideal_from_pixel(&Vector2::from(v.centre_px))
                    .unwrap();
                Some((
                    Observation::normalized(&tr.cam_from_world(v.time_s.unwrap()), xy),
                    Observation::normalized(&f.cam_from_world(), xy),
                ))
            })
            .collect();
        if views.len() < 2 {
            continue;
        }
        let truth_x = Point3::from(target.centre);
        let rows: Vec<Observation> = views.iter().map(|v| v.0).collect();
        let x = triangulate(&rows).unwrap();
        let rel = (x - truth_x).norm() / truth_x.coords.norm();
        assert!(rel <= 1e-9, "target {}: relative error {rel}", target.id);
        let frames: Vec<Observation> = views.iter().map(|v| v.1).collect();
        let x = triangulate(&frames).unwrap();
        worst_frame_pose = worst_frame_pose.max((x - truth_x).norm());
        checked += 1;
    }
    println!(
        "{checked} targets; rolling-shutter shift up to {largest_shift:.2} px; triangulated with the frame-time poses up to {:.2} mm off",
        worst_frame_pose * 1e3
    );
    assert!(checked > 50, "{checked} targets checked");
    // The rows matter: at the frame-time poses the same centres triangulate millimetres off.
    assert!(
        largest_shift > 0.3,
        "largest rolling-shutter shift {largest_shift} px"
    );
    assert!(worst_frame_pose > 1e-4, "{worst_frame_pose} m");
}

#[test]
fn rendered_video_discs_match_the_rolling_shutter_truth_ellipses() {
    let dir = tempfile::tempdir().unwrap();
    let options = SimulateOptions {
        width: 960,
        height: 540,
        seed: 21,
        render: RenderConfig {
            read_noise_dn: 0.3,
            shot_noise: 0.002,
            ..Default::default()
        },
        video: Some(VideoConfig::default()),
        ..Default::default()
    };
    let truth = simulate_lab(
        &options,
        &LabConfig {
            frames: 6,
            ..Default::default()
        },
        dir.path(),
        &|_| {},
    )
    .unwrap();
    let camera = truth.camera.camera();
    let (mut errors, mut shifts) = (Vec::new(), Vec::new());
    for frame in &truth.frames {
        let img = image::open(dir.path().join("frames").join(&frame.name))
            .unwrap()
            .to_rgb8();
        for view in &frame.targets {
            let e = view.fitted;
            if e.b < 5.0 {
                continue;
            }
            let pts = edge_points(&img, &e);
            assert!(pts.len() > 200, "target {} in {}", view.id, frame.name);
            let fit = fit_ellipse_direct(&pts).unwrap();
            errors.push((fit.centre() - e.centre()).norm());
            let target = truth.targets.iter().find(|t| t.id == view.id).unwrap();
            let global = camera
                .project_world(&frame.cam_from_world(), &Vector3::from(target.centre))
                .unwrap();
            shifts.push((global - Vector2::from(view.centre_px)).norm());
        }
    }
    let worst = errors.iter().copied().fold(0.0, f64::max);
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    let shift = shifts.iter().sum::<f64>() / shifts.len() as f64;
    println!(
        "{} discs: centre error RMS {rms:.4} px, worst {worst:.4} px; mean rolling-shutter shift {shift:.3} px",
        errors.len()
    );
    assert!(errors.len() > 50, "only {} discs checked", errors.len());
    // As for still frames (rendered_discs_match_the_truth_ellipses): the motion blur is
    // symmetric about mid-exposure to first order, so the half-level edge stays put.
    assert!(
        worst <= 0.05,
        "worst rendered-disc centre error {worst} px (RMS {rms})"
    );
    assert!(
        shift > 0.1,
        "mean rolling-shutter shift {shift} px: the check must see it"
    );
}

#[test]
fn same_seed_gives_identical_video_files_whatever_the_thread_count() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let run = |out: &Path, threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let config = VideoConfig {
                    neighbours: true,
                    focus_breathing: true,
                    frame_rate: 10.0,
                    full_rate_width: Some(160),
                    encode: false,
                    ..Default::default()
                };
                video_lab(out, 480, 3, config, 6);
            });
    };
    run(a.path(), 1);
    run(b.path(), 3);
    let files = [
        "truth.json",
        "frames/frame_0001.png",
        "frames/frame_0003.png",
        "frames/neighbours/frame_0002-1.png",
        "frames/frames.json",
        "video/frame_00007.png",
        "video/motion.json",
        "sparse/images.txt",
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
fn simulate_cli_films_video_and_refuses_bad_video_options_with_exit_code_2() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("lab");
    let o = out.to_str().unwrap();
    for (args, says) in [
        (vec!["--fps", "10"], "--video"),
        (
            vec!["--video", "--angular-speed", "9,3"],
            "MIN must not exceed MAX",
        ),
        (vec!["--video", "--readout=-5"], "--readout"),
        (
            vec!["--video", "--fps", "100", "--exposure", "20"],
            "exposure",
        ),
        (vec!["--video", "--pause", "0.5"], "pause"),
    ] {
        let mut all = vec![
            "simulate", "lab", "--out", o, "--width", "320", "--frames", "2",
        ];
        all.extend(args.iter());
        let (code, _, stderr) = common::pipemeasure(dir.path(), &all, &[]);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
        assert!(!out.join("truth.json").exists());
    }
    let (code, stdout, stderr) = common::pipemeasure(
        dir.path(),
        &[
            "simulate",
            "lab",
            "--out",
            o,
            "--width",
            "320",
            "--frames",
            "2",
            "--video",
            "--neighbours",
            "--fps",
            "5",
            "--video-width",
            "128",
            "--focus-breathing",
            "--readout",
            "25",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("video: readout 25.0 ms, exposure 8.0 ms"),
        "{stdout}"
    );
    assert!(
        stdout.contains("full-rate video: 6 frames 128x72 at 5 fps"),
        "{stdout}"
    );
    let truth = Truth::read(&out.join("truth.json")).unwrap();
    let video = truth.video.unwrap();
    assert_eq!(video.readout_s, 0.025);
    assert!(video.focus_breathing_m > 0.0);
    assert!(out.join("frames/neighbours/frame_0002+1.png").is_file());
    assert!(out.join("video/frame_00006.png").is_file());
    // Replaced by still frames: no stale neighbours, sidecar or video stay behind.
    common::simulate(
        dir.path(),
        o,
        &["lab", "--width", "320", "--frames", "2", "--force"],
    );
    assert!(
        Truth::read(&out.join("truth.json"))
            .unwrap()
            .video
            .is_none()
    );
    for stale in [
        "frames/neighbours/frame_0002+1.png",
        "frames/frames.json",
        "video/frame_00006.png",
        "video/motion.json",
        "video.mp4",
    ] {
        assert!(!out.join(stale).exists(), "{stale} left behind");
    }
}

/// Decodes every frame of `mp4` as raw RGB with ffmpeg.
fn decode_rgb(mp4: &Path) -> Vec<u8> {
    let out = std::process::Command::new("ffmpeg")
        .args(["-loglevel", "error", "-i"])
        .arg(mp4)
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

#[test]
fn a_streamed_full_rate_video_is_the_png_video_without_the_pngs() {
    if !common::program_available("ffmpeg", "-version", "apt-get install -y ffmpeg") {
        return;
    }
    let (png, streamed) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let config = |stream_full_rate| VideoConfig {
        frame_rate: 10.0,
        full_rate_width: Some(160),
        stream_full_rate,
        ..Default::default()
    };
    let a = video_lab(png.path(), 320, 3, config(false), 4);
    let b = video_lab(streamed.path(), 320, 3, config(true), 4);
    let (fa, fb) = (
        a.video.unwrap().full_rate.unwrap(),
        b.video.unwrap().full_rate.unwrap(),
    );
    // Two seconds at 10 fps, frame 1 at t = 0.
    assert_eq!((fb.frames, fb.streamed, fa.streamed), (21, true, false));
    assert_eq!(fb.mp4.as_deref(), Some("video.mp4"));
    assert!(png.path().join("video/frame_00021.png").is_file());
    assert!(!streamed.path().join("video/frame_00001.png").exists());
    assert!(streamed.path().join("video/motion.json").is_file());
    assert!(!streamed.path().join("video.partial.mp4").exists());
    // The same pixels reach the encoder either way: the decoded videos are identical, and
    // frame 21 is the PNG's up to the encoding.
    let (da, db) = (
        decode_rgb(&png.path().join("video.mp4")),
        decode_rgb(&streamed.path().join("video.mp4")),
    );
    let size = 160 * 90 * 3;
    assert_eq!(db.len(), 21 * size);
    assert!(da == db, "the streamed video differs from the PNG one");
    let last = image::open(png.path().join("video/frame_00021.png"))
        .unwrap()
        .to_rgb8();
    let mean_abs = last
        .as_raw()
        .iter()
        .zip(&db[20 * size..])
        .map(|(&x, &y)| f64::from(x.abs_diff(y)))
        .sum::<f64>()
        / size as f64;
    assert!(
        mean_abs < 3.0,
        "frame 21 is {mean_abs} grey levels off its PNG"
    );
}
