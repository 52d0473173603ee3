//! The command line: exit codes, messages that name the file or field, no partial output.
#![allow(clippy::unwrap_used)]

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::pipemeasure;
use image::{DynamicImage, ImageBuffer, Rgb};
use pipemeasure::io::colmap::{CameraId, ColmapModel, ModelFormat, Reconstruction};
use pipemeasure::profile::Profile;
use pipemeasure::sim::devices::{P30, preset_camera};

/// A small profile of the p30 preset at 320×180 written to `dir/p30small.json`.
fn small_profile(dir: &Path) -> std::path::PathBuf {
    let cam = preset_camera(&P30, 320, 180);
    let p = Profile::uncalibrated("p30small", &cam, BTreeMap::new());
    let path = dir.join("p30small.json");
    p.write(&path, false).unwrap();
    path
}

fn frame(w: u32, h: u32) -> DynamicImage {
    DynamicImage::ImageRgb8(ImageBuffer::from_fn(w, h, |x, y| {
        Rgb([(x % 256) as u8, (y % 256) as u8, 128])
    }))
}

#[test]
fn undistort_writes_frames_and_a_pinhole_cameras_txt() {
    let dir = tempfile::tempdir().unwrap();
    let profile = small_profile(dir.path());
    let input = dir.path().join("frames");
    std::fs::create_dir(&input).unwrap();
    frame(320, 180).save(input.join("a.png")).unwrap();
    frame(320, 180).save(input.join("b.jpg")).unwrap();
    let out = dir.path().join("out");
    let (code, stdout, stderr) = pipemeasure(
        dir.path(),
        &[
            "undistort",
            "--device",
            profile.to_str().unwrap(),
            "frames",
            "out",
            "--quiet",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("undistorted 2 frames"), "{stdout}");
    for name in ["a.png", "b.png"] {
        let img = image::open(out.join(name)).unwrap();
        assert_eq!((img.width(), img.height()), (320, 180));
    }
    // cameras.txt is a COLMAP PINHOLE camera with fx = fy = c and the same principal point.
    std::fs::write(out.join("images.txt"), "").unwrap();
    std::fs::write(out.join("points3D.txt"), "").unwrap();
    let model = Reconstruction::read_format(&out, ModelFormat::Text).unwrap();
    let cam = &model.cameras[&CameraId(1)];
    let truth = preset_camera(&P30, 320, 180).intrinsics;
    assert_eq!(cam.model, ColmapModel::Pinhole);
    assert_eq!(cam.params, vec![truth.c, truth.c, truth.u0, truth.v0]);
}

#[test]
fn undistort_bad_inputs_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let profile = small_profile(dir.path());
    let prof = profile.to_str().unwrap();

    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["undistort", "--device", prof, "missing", "out"],
        &[],
    );
    assert_eq!(code, 1);
    assert!(stderr.contains("missing: not found"), "{stderr}");

    let input = dir.path().join("frames");
    std::fs::create_dir(&input).unwrap();
    frame(320, 180).save(input.join("a.png")).unwrap();
    frame(640, 360).save(input.join("b.png")).unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["undistort", "--device", prof, "frames", "out"],
        &[],
    );
    assert_eq!(code, 1);
    assert!(
        stderr.contains("b.png is 640x360") && stderr.contains("320x180"),
        "{stderr}"
    );
    assert!(
        !dir.path().join("out").exists(),
        "nothing may be written when a frame is wrong"
    );

    std::fs::remove_file(input.join("b.png")).unwrap();
    std::fs::write(input.join("c.png"), b"this is not a png").unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["undistort", "--device", prof, "frames", "out"],
        &[],
    );
    assert_eq!(code, 1);
    assert!(stderr.contains("c.png"), "{stderr}");
    assert!(!dir.path().join("out").exists());

    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["undistort", "--device", "nokia", "frames", "out"],
        &[],
    );
    assert_eq!(code, 1);
    assert!(stderr.contains("unknown device `nokia`"), "{stderr}");
}

/// `--device NAME` from a folder without profiles found none (only `$PIPEMEASURE_CALIBRATIONS`
/// and `./calibrations/` were searched): the lookup is the env folder, `./calibrations/`, the
/// user data folder, then the presets built in, first found wins.
#[test]
fn device_lookup_searches_env_working_folder_user_data_then_presets() {
    let dir = tempfile::tempdir().unwrap();
    let env_dir = dir.path().join("env");
    let local = dir.path().join("calibrations");
    let data = dir.path().join("data");
    let user = data.join("pipemeasure/calibrations");
    for d in [&env_dir, &local, &user] {
        std::fs::create_dir_all(d).unwrap();
    }
    let cam = preset_camera(&P30, 320, 180);
    // alpha in all three folders with different c; beta in ./calibrations and the user's;
    // gamma only in the user's; p30 in the user's, shadowing the preset.
    let mut a = Profile::uncalibrated("alpha", &cam, BTreeMap::new());
    a.write(&env_dir.join("alpha.json"), false).unwrap();
    a.intrinsics.c += 1.0;
    a.write(&local.join("alpha.json"), false).unwrap();
    a.intrinsics.c += 1.0;
    a.write(&user.join("alpha.json"), false).unwrap();
    let b = Profile::uncalibrated("beta", &cam, BTreeMap::new());
    b.write(&local.join("beta.json"), false).unwrap();
    b.write(&user.join("beta.json"), false).unwrap();
    Profile::uncalibrated("gamma", &cam, BTreeMap::new())
        .write(&user.join("gamma.json"), false)
        .unwrap();
    Profile::uncalibrated("p30", &cam, BTreeMap::new())
        .write(&user.join("p30.json"), false)
        .unwrap();
    let xdg = ("XDG_DATA_HOME", data.to_str().unwrap());
    let all = [("PIPEMEASURE_CALIBRATIONS", env_dir.to_str().unwrap()), xdg];
    let c_of = |cwd: &Path, name: &str, env: &[(&str, &str)]| {
        let (code, stdout, stderr) = pipemeasure(cwd, &["profile", "show", name, "--json"], env);
        assert_eq!(code, 0, "{name}: {stderr}");
        Profile::from_json(&stdout, Path::new("stdout"))
            .unwrap()
            .intrinsics
            .c
    };
    let c = cam.intrinsics.c;
    assert_eq!(c_of(dir.path(), "alpha", &all), c, "the env folder first");
    assert_eq!(
        c_of(dir.path(), "alpha", &[xdg]),
        c + 1.0,
        "./calibrations next"
    );
    assert_eq!(
        c_of(&env_dir, "alpha", &[xdg]),
        c + 2.0,
        "the user's folder next"
    );
    assert_eq!(
        c_of(&env_dir, "p30", &[xdg]),
        c,
        "the user's p30 shadows the preset"
    );
    // From a folder without profiles and no user data, the preset is the repository's file.
    let (code, stdout, stderr) = pipemeasure(&env_dir, &["profile", "show", "p30", "--json"], &[]);
    assert_eq!(code, 0, "{stderr}");
    let shipped = Profile::read(&Path::new(common::CALIBRATIONS).join("p30.json")).unwrap();
    assert_eq!(
        Profile::from_json(&stdout, Path::new("stdout")).unwrap(),
        shipped
    );
    let (code, stdout, _) = pipemeasure(&env_dir, &["profile", "show", "s10"], &[]);
    assert_eq!(code, 0);
    assert!(stdout.contains("(built in)/s10.json, built in"), "{stdout}");

    // An unknown name lists every folder searched and every device, presets included.
    let (code, _, stderr) = pipemeasure(dir.path(), &["profile", "show", "delta"], &all);
    assert_eq!(code, 1);
    for part in [
        format!("{} ($PIPEMEASURE_CALIBRATIONS)", env_dir.display()),
        "calibrations (./calibrations)".to_string(),
        format!("{} (user data folder)", user.display()),
        "nor a preset built in".to_string(),
        "available devices: alpha, beta, gamma, iphone11, p30, s10".to_string(),
    ] {
        assert!(stderr.contains(&part), "{part}: {stderr}");
    }

    // The list: every profile with its origin, the shadowed ones marked, names sorted.
    let (code, stdout, _) = pipemeasure(dir.path(), &["profile", "list"], &all);
    assert_eq!(code, 0);
    let rows: Vec<(&str, &str, Option<&str>)> = stdout
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split('\t').collect();
            (f[0], f[1], f.get(3).copied())
        })
        .collect();
    assert_eq!(
        rows,
        [
            ("alpha", "$PIPEMEASURE_CALIBRATIONS", None),
            (
                "alpha",
                "./calibrations",
                Some("shadowed by $PIPEMEASURE_CALIBRATIONS")
            ),
            (
                "alpha",
                "user data folder",
                Some("shadowed by $PIPEMEASURE_CALIBRATIONS")
            ),
            ("beta", "./calibrations", None),
            (
                "beta",
                "user data folder",
                Some("shadowed by ./calibrations")
            ),
            ("gamma", "user data folder", None),
            ("iphone11", "built in", None),
            ("p30", "user data folder", None),
            ("p30", "built in", Some("shadowed by user data folder")),
            ("s10", "built in", None),
        ]
    );

    // `calibrate` without --out writes to $PIPEMEASURE_CALIBRATIONS when it is set (an existing
    // profile there is what it refuses to replace), else to the user's folder.
    std::fs::create_dir(dir.path().join("frames")).unwrap();
    let calibrate = [
        "calibrate",
        "--device",
        "alpha",
        "--frames",
        "frames",
        "--sfm",
        "x",
    ];
    let (code, _, stderr) = pipemeasure(dir.path(), &calibrate, &all);
    assert_eq!(code, 1);
    assert!(
        stderr.contains(&format!("{} exists", env_dir.join("alpha.json").display())),
        "{stderr}"
    );
    let (code, _, stderr) = pipemeasure(dir.path(), &calibrate, &[xdg]);
    assert_eq!(code, 1);
    assert!(
        stderr.contains(&format!("{} exists", user.join("alpha.json").display())),
        "{stderr}"
    );
}

#[test]
fn malformed_profile_names_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = small_profile(dir.path());
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("\"v0\": ", "\"v0\": \"oops\", \"x\": ");
    std::fs::write(&path, text).unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["profile", "show", path.to_str().unwrap()],
        &[],
    );
    assert_eq!(code, 1);
    assert!(
        stderr.contains("p30small.json:") && stderr.contains("intrinsics.v0"),
        "{stderr}"
    );
}

#[test]
fn profile_show_and_export() {
    let dir = tempfile::tempdir().unwrap();
    let path = small_profile(dir.path());
    let p = path.to_str().unwrap();
    let (code, stdout, _) = pipemeasure(dir.path(), &["profile", "show", p], &[]);
    assert_eq!(code, 0);
    let c = format!("{:.4} px", preset_camera(&P30, 320, 180).intrinsics.c);
    assert!(
        stdout.contains("320 x 180") && stdout.contains(&c),
        "{stdout}"
    );

    let (code, stdout, _) = pipemeasure(
        dir.path(),
        &["profile", "export", p, "--format", "colmap"],
        &[],
    );
    assert_eq!(code, 0);
    assert!(stdout.contains("exact conversion"), "{stdout}");
    let cams = dir.path().join("cams");
    std::fs::create_dir(&cams).unwrap();
    std::fs::write(cams.join("cameras.txt"), &stdout).unwrap();
    std::fs::write(cams.join("images.txt"), "").unwrap();
    std::fs::write(cams.join("points3D.txt"), "").unwrap();
    let model = Reconstruction::read(&cams).unwrap();
    let c = &model.cameras[&CameraId(1)];
    let i = preset_camera(&P30, 320, 180).intrinsics;
    assert_eq!(c.model, ColmapModel::Opencv);
    assert_eq!(c.params, vec![i.c, i.c, i.u0, i.v0, i.k1, i.k2, i.p1, i.p2]);

    let (code, stdout, stderr) = pipemeasure(
        dir.path(),
        &[
            "profile", "export", p, "--format", "colmap", "--model", "radial",
        ],
        &[],
    );
    assert_eq!(code, 0);
    assert!(
        stdout.contains("least-squares fit") && stderr.contains("lacks p1, p2"),
        "{stdout}{stderr}"
    );

    let (code, stdout, _) = pipemeasure(
        dir.path(),
        &["profile", "export", p, "--format", "opencv"],
        &[],
    );
    assert_eq!(code, 0);
    assert!(
        stdout.starts_with("%YAML:1.0")
            && stdout.contains(&format!("{:?}, 0.0, {:?}", i.c, i.u0 - 0.5)),
        "{stdout}"
    );
}

#[test]
fn usage_errors_exit_with_2() {
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(pipemeasure(dir.path(), &[], &[]).0, 2);
    assert_eq!(pipemeasure(dir.path(), &["undistort"], &[]).0, 2);
    assert_eq!(pipemeasure(dir.path(), &["--no-such-flag"], &[]).0, 2);
    // COLMAP's feature size out of its range names the option, before anything runs.
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &[
            "calibrate",
            "--device",
            "x",
            "--frames",
            "frames",
            "--colmap-image-size",
            "10",
        ],
        &[],
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("--colmap-image-size"), "{stderr}");
    assert!(!dir.path().join("colmap").exists());
}

/// `simulate lab` then `match` end to end through the binary: rendered frames, detection,
/// Algorithm 1 on the stand-in model, matching. Every output track holds views of one target
/// only (each observation's detected centre lies within 2 px of the true projected centre of
/// exactly one scene target, and one track's observations all name the same target), and a
/// missing frame folder is a clear error.
#[test]
fn match_command_tracks_hold_one_target_each() {
    let dir = tempfile::tempdir().unwrap();
    common::simulate(
        dir.path(),
        "lab",
        &[
            "lab", "--like", "p30", "--width", "1280", "--height", "720", "--frames", "10",
        ],
    );
    let (code, stdout, stderr) = pipemeasure(
        dir.path(),
        &[
            "match",
            "--frames",
            "lab/frames",
            "--sfm",
            "lab/sparse",
            "--json",
            "tracks.json",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("matched"), "{stdout}");
    let truth = pipemeasure::sim::truth::Truth::read(&dir.path().join("lab/truth.json")).unwrap();
    let out: serde_json::Value = common::read_json(&dir.path().join("tracks.json"));
    let targets = out["targets"].as_array().unwrap();
    assert!(targets.len() >= 20, "{} targets", targets.len());
    for t in targets {
        let mut ids = Vec::new();
        for o in t["observations"].as_array().unwrap() {
            let frame = truth
                .frames
                .iter()
                .find(|f| f.name == o["frame"].as_str().unwrap())
                .unwrap();
            let (cx, cy) = (
                o["ellipse"]["cx"].as_f64().unwrap(),
                o["ellipse"]["cy"].as_f64().unwrap(),
            );
            // Every scene target whose true centre projects within 2 px (the truth's per-frame
            // list leaves out targets within 4 px of the border; the detector need not).
            let camera = truth.camera.camera();
            let near: Vec<u32> = truth
                .targets
                .iter()
                .filter(|t| {
                    let c = nalgebra::Point3::from(nalgebra::Vector3::from(t.centre));
                    pipemeasure::sim::truth::project(&camera, frame, &c)
                        .is_some_and(|uv| (uv.x - cx).hypot(uv.y - cy) < 2.0)
                })
                .map(|t| t.id)
                .collect();
            assert_eq!(near.len(), 1, "observation {o} is not one truth target");
            ids.push(near[0]);
        }
        assert!(
            ids.iter().all(|i| *i == ids[0]),
            "a track mixes targets {ids:?}"
        );
    }
    // With a profile (here the true camera): the stand-in's poses were adjusted with its own
    // SIMPLE_RADIAL camera, so the features do not fit the profile until the poses are
    // re-adjusted to it; afterwards Algorithm 1's σ is the features' 0.5 px.
    let profile = Profile::uncalibrated("truecam", &truth.camera.camera(), BTreeMap::new());
    profile
        .write(&dir.path().join("truecam.json"), false)
        .unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &[
            "match",
            "--frames",
            "lab/frames",
            "--sfm",
            "lab/sparse",
            "--device",
            "truecam.json",
            "--json",
            "tracks_profile.json",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    let out: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("tracks_profile.json")).unwrap(),
    )
    .unwrap();
    let a1 = &out["algorithm1"];
    let (before, after) = (
        a1["reprojection_sigma_before_readjustment_px"]
            .as_f64()
            .unwrap(),
        a1["reprojection_sigma_px"].as_f64().unwrap(),
    );
    let noise = truth
        .sfm
        .as_ref()
        .unwrap()
        .stand_in
        .as_ref()
        .unwrap()
        .feature_noise_px;
    assert!(
        after > 0.8 * noise && after < 1.1 * noise,
        "σ after re-adjustment {after} px, feature noise {noise} px"
    );
    assert!(
        before > 1.5 * after,
        "σ before {before} px, after {after} px"
    );
    assert!(stderr.contains("after re-adjusting the poses"), "{stderr}");
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["match", "--frames", "nowhere", "--sfm", "lab/sparse"],
        &[],
    );
    assert_eq!(code, 1);
    assert!(stderr.contains("nowhere"), "{stderr}");
}

#[test]
fn calibrate_command_writes_a_profile_and_a_report() {
    let dir = tempfile::tempdir().unwrap();
    common::simulate(
        dir.path(),
        "lab",
        &[
            "lab", "--like", "p30", "--width", "1280", "--height", "720", "--frames", "16",
        ],
    );
    let args = [
        "calibrate",
        "--device",
        "p30test",
        "--frames",
        "lab/frames",
        "--sfm",
        "lab/sparse",
        "--report",
        "report",
        "--quiet",
    ];
    // Without --out the profile goes to the user's data folder.
    let data = dir.path().join("data");
    let env = [("XDG_DATA_HOME", data.to_str().unwrap())];
    let written = data.join("pipemeasure/calibrations/p30test.json");
    let (code, stdout, stderr) = pipemeasure(dir.path(), &args, &env);
    assert_eq!(code, 0, "{stderr}\n{stdout}");
    assert!(
        stdout.contains(&format!("profile written to {}", written.display())),
        "{stdout}"
    );
    let profile = pipemeasure::profile::Profile::read(&written).unwrap();
    let truth = pipemeasure::sim::truth::Truth::read(&dir.path().join("lab/truth.json")).unwrap();
    let t = truth.camera.intrinsics;
    let e = profile.intrinsics;
    // 16 frames of 1280×720 with the real detector: a sanity bound, the 4K acceptance is in
    // the README's calibration table.
    assert!((e.c - t.c).abs() < 1.0, "c {} vs {}", e.c, t.c);
    assert!(
        (e.u0 - t.u0).abs() < 1.5 && (e.v0 - t.v0).abs() < 1.5,
        "{e:?} vs {t:?}"
    );
    assert!(
        profile.terms.contains(&pipemeasure::camera::Term::K1),
        "{:?}",
        profile.terms
    );
    assert!(profile.sigma0.unwrap() < 0.2);
    for f in [
        "report.json",
        "report.md",
        "radial_residuals.svg",
        "residual_vectors.svg",
        "camera_network.svg",
        "projection_uncertainty.svg",
    ] {
        assert!(dir.path().join("report").join(f).is_file(), "{f} missing");
    }
    // A second run refuses to overwrite; --force keeps a backup beside the profile.
    let (code, _, stderr) = pipemeasure(dir.path(), &args, &env);
    assert_eq!(code, 1);
    assert!(stderr.contains("--force"), "{stderr}");
    // A ./calibrations/p30test.json here is found first from this folder: said.
    std::fs::create_dir(dir.path().join("calibrations")).unwrap();
    std::fs::copy(&written, dir.path().join("calibrations/p30test.json")).unwrap();
    let mut forced = args.to_vec();
    forced.push("--force");
    let (code, _, stderr) = pipemeasure(dir.path(), &forced, &env);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        data.join("pipemeasure/calibrations/p30test.json.1.bak")
            .is_file()
    );
    assert!(
        stderr.contains(
            "note: from this folder `--device p30test` finds calibrations/p30test.json \
             (./calibrations) first"
        ),
        "{stderr}"
    );
    // From any other folder the name finds it, in the user data folder.
    let elsewhere = dir.path().join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    let (code, stdout, stderr) = pipemeasure(&elsewhere, &["profile", "list"], &env);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains(&format!(
            "p30test\tuser data folder\t{}\n",
            written.display()
        )),
        "{stdout}"
    );
    let (code, stdout, _) =
        pipemeasure(&elsewhere, &["profile", "show", "p30test", "--json"], &env);
    assert_eq!(code, 0);
    assert_eq!(
        stdout.trim(),
        std::fs::read_to_string(&written).unwrap().trim()
    );
}

#[test]
fn calibrate_refuses_a_model_whose_frames_are_missing() {
    let dir = tempfile::tempdir().unwrap();
    common::simulate(
        dir.path(),
        "lab",
        &[
            "lab", "--like", "p30", "--width", "640", "--height", "360", "--frames", "9",
        ],
    );
    std::fs::create_dir(dir.path().join("other")).unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &[
            "calibrate",
            "--device",
            "x",
            "--frames",
            "other",
            "--sfm",
            "lab/sparse",
            "--out",
            "x.json",
        ],
        &[],
    );
    assert_eq!(code, 1);
    assert!(stderr.contains("are not in other"), "{stderr}");
    assert!(!dir.path().join("x.json").exists());
    // Too few frames for a calibration: a clear error, no profile.
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &[
            "calibrate",
            "--device",
            "x",
            "--frames",
            "lab/frames",
            "--sfm",
            "lab/sparse",
            "--out",
            "x.json",
        ],
        &[],
    );
    assert_eq!(code, 1);
    assert!(stderr.contains("at least"), "{stderr}");
    assert!(!dir.path().join("x.json").exists());
}

#[test]
fn fit_cylinder_command_reports_json_and_exit_3_when_nothing_is_found() {
    use pipemeasure::io::ply::{PointCloud, write_binary};
    let dir = tempfile::tempdir().unwrap();
    // A 50 mm pipe along y through (2, 0, 1), exact points, 1e6 m east.
    let pipe: Vec<nalgebra::Point3<f64>> = (0..6000)
        .map(|i| {
            let a = f64::from(i) * 0.731;
            let t = f64::from(i % 100) * 0.01;
            nalgebra::Point3::new(1.0e6 + 2.0 + 0.05 * a.cos(), t, 1.0 + 0.05 * a.sin())
        })
        .collect();
    write_binary(&dir.path().join("pipe.ply"), &PointCloud::from_points(pipe)).unwrap();
    let (code, stdout, stderr) = pipemeasure(
        dir.path(),
        &[
            "fit-cylinder",
            "pipe.ply",
            "--json",
            "--radius-min",
            "0.01",
            "--radius-max",
            "0.2",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert!((v["radius_m"].as_f64().unwrap() - 0.05).abs() < 1e-9, "{v}");
    assert_eq!(v["inliers"].as_u64().unwrap(), 6000);
    assert!(v["axis"]["direction"][1].as_f64().unwrap().abs() > 1.0 - 1e-9);
    // A plane: no cylinder, exit code 3.
    let plane: Vec<nalgebra::Point3<f64>> = (0..4000)
        .map(|i| nalgebra::Point3::new(f64::from(i % 64) * 0.01, f64::from(i / 64) * 0.01, 0.0))
        .collect();
    write_binary(
        &dir.path().join("plane.ply"),
        &PointCloud::from_points(plane),
    )
    .unwrap();
    let (code, _, stderr) = pipemeasure(dir.path(), &["fit-cylinder", "plane.ply"], &[]);
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("no cylinder found"), "{stderr}");
    // An empty cloud: a clear error naming the file.
    write_binary(&dir.path().join("empty.ply"), &PointCloud::default()).unwrap();
    let (code, _, stderr) = pipemeasure(dir.path(), &["fit-cylinder", "empty.ply"], &[]);
    assert_eq!(code, 1);
    assert!(
        stderr.contains("empty.ply") && stderr.contains("no finite points"),
        "{stderr}"
    );
}

/// `calibrate --check-points --network`: the truth's target centres, shuffled, in a survey
/// frame (rotated, offset by hundreds of km) with 0.02 mm noise and one foreign point, are associated by geometry; the RMS object-space error
/// after the similarity agrees with what the targets' own σ predict (within 30 %); every target
/// and adjusted frame is in report.json with its σ; the COLMAP export reads back with the
/// profile's camera and the targets' observations; bad check-point files are refused before
/// the calibration runs.
#[test]
fn calibrate_reports_the_network_and_check_points() {
    use rand::{Rng, SeedableRng};
    let dir = tempfile::tempdir().unwrap();
    common::simulate(
        dir.path(),
        "lab",
        &[
            "lab", "--like", "p30", "--width", "1280", "--height", "720", "--frames", "20",
        ],
    );
    let truth = pipemeasure::sim::truth::Truth::read(&dir.path().join("lab/truth.json")).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let rotation = nalgebra::UnitQuaternion::from_euler_angles(0.3, -0.2, 2.1);
    let offset = nalgebra::Vector3::new(500_000.0, 5_600_000.0, 120.0);
    let mut rows: Vec<String> = truth
        .targets
        .iter()
        .map(|t| {
            let noise = nalgebra::Vector3::from_fn(|_, _| {
                // Box–Muller: σ = 0.02 mm per axis.
                let (u1, u2): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random());
                2e-5 * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
            });
            let p = rotation * nalgebra::Vector3::from(t.centre) + offset + noise;
            format!("T{},{:.6},{:.6},{:.6}", t.id, p.x, p.y, p.z)
        })
        .collect();
    rows.push(format!(
        "STRAY,{:.6},{:.6},{:.6}",
        offset.x + 9.0,
        offset.y - 4.0,
        offset.z + 3.0
    ));
    // Shuffle (Fisher–Yates).
    for k in (1..rows.len()).rev() {
        rows.swap(k, rng.random_range(0..=k));
    }
    std::fs::write(
        dir.path().join("check.csv"),
        format!("id,x,y,z\n{}\n", rows.join("\n")),
    )
    .unwrap();
    let args = [
        "calibrate",
        "--device",
        "p30net",
        "--frames",
        "lab/frames",
        "--sfm",
        "lab/sparse",
        "--out",
        "prof.json",
        "--report",
        "report",
        "--network",
        "network",
        "--check-points",
        "check.csv",
        "--check-point-sigma",
        "0.00002",
        "--quiet",
        "--cross-validate",
    ];
    let (code, stdout, stderr) = pipemeasure(dir.path(), &args, &[]);
    assert_eq!(code, 0, "{stderr}\n{stdout}");
    assert!(stdout.contains("check points:"), "{stdout}");
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("report/report.json")).unwrap(),
    )
    .unwrap();
    let net = &report["network"];
    let targets = net["targets"].as_array().unwrap();
    let frames = net["frames"].as_array().unwrap();
    assert!(targets.len() >= 40, "{} targets", targets.len());
    assert_eq!(
        frames.len(),
        report["adjusted_frames"].as_array().unwrap().len()
    );
    for t in targets {
        assert!(t["views"].as_array().unwrap().len() >= 2, "{t}");
        assert!(
            t["std"]
                .as_array()
                .unwrap()
                .iter()
                .all(|s| s.as_f64().unwrap() > 0.0),
            "{t}"
        );
    }
    for f in frames {
        let s = f["centre_std"].as_array().unwrap();
        assert!(s.iter().all(|s| s.as_f64().unwrap() > 0.0), "{f}");
    }
    let cp = &report["check_points"];
    let points = cp["points"].as_array().unwrap();
    // Every matched target is a true target: its check point is the one of its own id.
    assert_eq!(
        cp["unassociated"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|u| *u == "STRAY")
            .count(),
        1
    );
    assert!(
        points.len() >= targets.len() - 2,
        "{} of {}",
        points.len(),
        targets.len()
    );
    let (rms, predicted, normalized) = (
        cp["rms_m"].as_f64().unwrap(),
        cp["predicted_rms_m"].as_f64().unwrap(),
        cp["normalized_rms"].as_f64().unwrap(),
    );
    eprintln!(
        "check points: {} associated, RMS {:.4} mm, predicted {:.4} mm, {normalized:.2} × their σ",
        points.len(),
        rms * 1e3,
        predicted * 1e3
    );
    // The residuals in units of the targets' own σ (Mahalanobis, after the similarity's 7
    // parameters): 1 when the σ are right. (The plain RMS is set by the few targets seen in
    // three or four views, whose σ are largest; it is reported beside it.)
    assert!(
        (normalized - 1.0).abs() < 0.3,
        "check-point residuals are {normalized} × their σ (RMS {rms} m, predicted {predicted} m)"
    );
    // The scale is the lab's: metres per SfM unit is 1 / the stand-in's similarity scale.
    let sim_scale = truth
        .sfm
        .as_ref()
        .unwrap()
        .stand_in
        .as_ref()
        .unwrap()
        .similarity
        .scale;
    assert!((cp["scale"].as_f64().unwrap() * sim_scale - 1.0).abs() < 1e-3);
    let md = std::fs::read_to_string(dir.path().join("report/report.md")).unwrap();
    assert!(md.contains("Check points:"), "{md}");
    // Cross-validation: the rotation between the halves' models can only explain part of
    // their difference; the σ are scaled by the observed/predicted ratio when it exceeds 1.
    let cv = &report["cross_validation"];
    let (raw, rotated, ratio, scaled) = (
        cv["rms_px"].as_f64().unwrap(),
        cv["rotated_rms_px"].as_f64().unwrap(),
        cv["ratio"].as_f64().unwrap(),
        cv["sigma_scaled_by"].as_f64().unwrap(),
    );
    eprintln!("cross-validation: {raw:.4} px, rotated {rotated:.4} px, ratio {ratio:.2}");
    assert!(
        rotated <= raw + 1e-9 && ratio.is_finite() && ratio > 0.0,
        "{cv}"
    );
    assert_eq!(scaled, ratio.max(1.0));
    // The COLMAP export, read by COLMAP itself and by us.
    if common::colmap_available() {
        let out = std::process::Command::new("colmap")
            .args(["model_analyzer", "--path"])
            .arg(dir.path().join("network"))
            .output()
            .unwrap();
        let log = String::from_utf8_lossy(&out.stdout).to_string()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success() && log.contains("Registered images"),
            "{log}"
        );
    }
    let model = pipemeasure::io::colmap::Reconstruction::read(&dir.path().join("network")).unwrap();
    assert_eq!(model.images.len(), frames.len());
    assert_eq!(model.points3d.len(), targets.len());
    let observations: usize = model.points3d.values().map(|p| p.track.len()).sum();
    assert_eq!(
        observations,
        report["observations"].as_array().unwrap().len()
    );
    let profile = pipemeasure::profile::Profile::read(&dir.path().join("prof.json")).unwrap();
    let cam =
        pipemeasure::camera::convert::brown_from_colmap(model.cameras.values().next().unwrap())
            .unwrap()
            .camera;
    assert!((cam.intrinsics.c - profile.intrinsics.c).abs() < 1e-9 * profile.intrinsics.c);
    // Bad check-point files fail at once, naming the problem.
    std::fs::write(
        dir.path().join("three.csv"),
        "id,x,y,z\na,0,0,0\nb,1,0,0\nc,0,1,0\n",
    )
    .unwrap();
    std::fs::write(
        dir.path().join("dup.csv"),
        "id,x,y,z\na,0,0,0\na,1,0,0\nc,0,1,0\nd,0,0,1\n",
    )
    .unwrap();
    std::fs::write(
        dir.path().join("far.csv"),
        "id,x,y,z\na,0,0,0\nb,1,0,0\nc,0,1,0\nd,0,0,1\ne,3,0.5,0\nf,0.2,7,1\n",
    )
    .unwrap();
    for (file, expect, code_expected) in [
        ("three.csv", "at least 4", 1),
        ("dup.csv", "dup.csv:3", 1),
        ("far.csv", "could be associated", 1),
    ] {
        let mut a = args.to_vec();
        a[14] = file;
        a.push("--force");
        let (code, _, stderr) = pipemeasure(dir.path(), &a, &[]);
        assert_eq!(code, code_expected, "{file}: {stderr}");
        assert!(stderr.contains(expect), "{file}: {stderr}");
    }
}

/// `fit-cylinder --near --within` streams the file and keeps only the region's points: on the
/// real mug scan, a 0.2 m region about the mug gives the mug (PCL's tutorial: 38.8 mm, its axis
/// along the table's normal ≈ (0, −0.84, −0.54)); a region with no point says so, naming the
/// file, exit 1.
#[test]
fn fit_cylinder_in_a_region_of_a_real_scan() {
    let tmp = tempfile::tempdir().unwrap();
    let mug = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/pcl_mug/table_scene_mug_stereo_textured.ply");
    let mug = mug.to_str().unwrap();
    let (code, stdout, stderr) = pipemeasure(
        tmp.path(),
        &[
            "fit-cylinder",
            mug,
            "--radius-min",
            "0",
            "--radius-max",
            "0.1",
            "--near=0.05,0.1,0.79",
            "--within",
            "0.2",
            "--json",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    let fit: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let r = fit["radius_m"].as_f64().unwrap();
    assert!((r - 0.0388).abs() < 1e-3, "{r}");
    let d = &fit["axis"]["direction"];
    let along = (d[1].as_f64().unwrap() * -0.84 + d[2].as_f64().unwrap() * -0.54).abs();
    assert!(along > 0.99, "{d}");
    let (code, _, stderr) = pipemeasure(
        tmp.path(),
        &["fit-cylinder", mug, "--near", "10,10,10", "--within", "0.1"],
        &[],
    );
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("table_scene_mug_stereo_textured.ply")
            && stderr.contains("no point within 0.1 m of (10, 10, 10)"),
        "{stderr}"
    );
}

/// `--version` names the package version, the commit the binary was built from (the
/// checkout's HEAD, when the tests run in one) and the build date.
#[test]
fn version_names_the_commit_and_the_build_date() {
    let dir = tempfile::tempdir().unwrap();
    let (code, stdout, stderr) = pipemeasure(dir.path(), &["--version"], &[]);
    assert_eq!(code, 0, "{stderr}");
    let line = stdout.trim();
    let prefix = format!("pipemeasure {} (commit ", env!("CARGO_PKG_VERSION"));
    let rest = line
        .strip_prefix(&prefix)
        .unwrap_or_else(|| panic!("{line}"));
    let (commit, date) = rest
        .strip_suffix(')')
        .and_then(|r| r.split_once(", built "))
        .unwrap_or_else(|| panic!("{line}"));
    let head = std::process::Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
    match head {
        Some(head) => assert_eq!(commit, head, "{line}"),
        None => assert_eq!(commit, "unknown", "{line}"),
    }
    let parts: Vec<&str> = date.split('-').collect();
    assert!(
        parts.len() == 3
            && parts[0].len() == 4
            && parts.iter().all(|p| p.parse::<u32>().is_ok())
            && (1..=12).contains(&parts[1].parse::<u32>().unwrap())
            && (1..=31).contains(&parts[2].parse::<u32>().unwrap()),
        "{line}"
    );
}

/// `man DIR` writes every page or none: with a folder where one page would go, it fails
/// naming that page, and no page (nor a temporary) is left in DIR.
#[test]
fn man_writes_every_page_or_none() {
    let dir = tempfile::tempdir().unwrap();
    let pages = dir.path().join("pages");
    std::fs::create_dir_all(pages.join("pipemeasure-pipes.1")).unwrap();
    let (code, _, stderr) = pipemeasure(dir.path(), &["man", "pages"], &[]);
    assert_ne!(code, 0, "{stderr}");
    assert!(stderr.contains("pipemeasure-pipes.1"), "{stderr}");
    let left: Vec<String> = std::fs::read_dir(&pages)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, vec!["pipemeasure-pipes.1".to_string()], "{left:?}");
    std::fs::remove_dir(pages.join("pipemeasure-pipes.1")).unwrap();
    let (code, stdout, stderr) = pipemeasure(dir.path(), &["man", "pages"], &[]);
    assert_eq!(code, 0, "{stderr}");
    let written = std::fs::read_dir(&pages).unwrap().count();
    assert!(written > 20, "{written} pages");
    assert!(
        stdout.contains(&format!("{written} man pages written")),
        "{stdout}"
    );
}

/// The man pages committed in `man/` are what the command line's definitions generate now
/// (`pipemeasure man man` regenerates them after a change to the options).
#[test]
fn the_committed_man_pages_are_current() {
    let dir = tempfile::tempdir().unwrap();
    let (code, _, stderr) = pipemeasure(dir.path(), &["man", "pages"], &[]);
    assert_eq!(code, 0, "{stderr}");
    let committed = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("man");
    let list = |d: &std::path::Path| -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    };
    let generated = list(&dir.path().join("pages"));
    assert_eq!(
        generated,
        list(&committed),
        "run `pipemeasure man man` and commit man/"
    );
    assert!(generated.contains(&"pipemeasure-calibrate.1".to_string()));
    for name in generated {
        let now = std::fs::read_to_string(dir.path().join("pages").join(&name)).unwrap();
        let was = std::fs::read_to_string(committed.join(&name)).unwrap();
        assert!(
            now == was,
            "man/{name} is out of date: run `pipemeasure man man`"
        );
    }
}

/// `completions` prints a script each shell accepts that completes the subcommands and the
/// options of the main command.
#[test]
fn completions_complete_subcommands_and_options() {
    let dir = tempfile::tempdir().unwrap();
    for shell in ["bash", "zsh", "fish"] {
        let (code, script, stderr) = pipemeasure(dir.path(), &["completions", shell], &[]);
        assert_eq!(code, 0, "{shell}: {stderr}");
        for word in ["calibrate", "pipes", "tls-targets", "readout-time"] {
            assert!(script.contains(word), "{shell}: no {word}");
        }
    }
    let (code, script, _) = pipemeasure(dir.path(), &["completions", "bash"], &[]);
    assert_eq!(code, 0);
    // bash parses it (when bash is there to ask).
    let file = dir.path().join("pipemeasure.bash");
    std::fs::write(&file, script).unwrap();
    if let Ok(out) = std::process::Command::new("bash")
        .arg("-n")
        .arg(&file)
        .output()
    {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let (code, _, stderr) = pipemeasure(dir.path(), &["completions", "tcsh"], &[]);
    assert_eq!(code, 2, "{stderr}");
}

/// `doctor` lists COLMAP, ffmpeg and ffprobe with their versions, the profile folders with
/// their profiles and the machine; with a `PATH` that holds none of the programs it names each
/// with its install command and exits 1, and `calibrate` without `--sfm` stops before any work
/// with the same advice.
#[test]
fn doctor_names_each_program_and_calibrate_checks_them_first() {
    let dir = tempfile::tempdir().unwrap();
    let (code, stdout, stderr) = common::pipemeasure_with_profiles(dir.path(), &["doctor"]);
    for program in ["colmap", "ffmpeg", "ffprobe"] {
        assert!(stdout.contains(program), "{stdout}");
    }
    assert!(stdout.contains("p30"), "{stdout}");
    assert!(stdout.contains("cores"), "{stdout}");
    if stdout.contains("MISSING") {
        assert_eq!(code, 1, "{stderr}");
    } else {
        assert_eq!(code, 0, "{stderr}");
    }
    let empty = dir.path().join("bin");
    std::fs::create_dir(&empty).unwrap();
    let path = empty.to_str().unwrap();
    let (code, stdout, stderr) = pipemeasure(dir.path(), &["doctor"], &[("PATH", path)]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stdout.contains("MISSING  colmap")
            && stdout.contains("sudo apt-get install -y colmap")
            && stdout.contains("sudo apt-get install -y ffmpeg"),
        "{stdout}"
    );
    std::fs::create_dir(dir.path().join("frames")).unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["calibrate", "--device", "x", "--frames", "frames"],
        &[("PATH", path)],
    );
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("`colmap` is not installed") && stderr.contains("--sfm DIR"),
        "{stderr}"
    );
    assert!(!dir.path().join("calibrations").exists());
}
