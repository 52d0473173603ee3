//! Hostile input: no panic, no hang, no silent misread. Each defect's reproducer
//! through the binary, with the exit code and the message the README documents (0 success, 1
//! failure, 2 usage, 3 nothing found), and nothing half-written. The readers' own regression
//! tests sit next to them (`io::ply`, `io::frames`, `io::colmap`, `profile`, `measure`).
#![allow(clippy::unwrap_used)]

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use common::pipemeasure;
use image::{DynamicImage, ImageBuffer, Luma, Rgb};
use pipemeasure::profile::Profile;
use pipemeasure::sim::devices::{P30, preset_camera};

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// A binary PLY of `points` (float x y z), written by hand.
fn ply(points: &[[f32; 3]]) -> Vec<u8> {
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        points.len()
    )
    .into_bytes();
    for p in points {
        for v in p {
            b.extend(v.to_le_bytes());
        }
    }
    b
}

/// A 4-frame 480×270 p30 lab in `dir/lab` (frames, truth, stand-in model).
fn lab(dir: &Path) {
    common::simulate(
        dir,
        "lab",
        &["lab", "--like", "p30", "--width", "480", "--frames", "4"],
    );
}

/// Every file and folder under `dir`, relative, sorted (hidden temporaries included).
fn tree(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            out.push(p.strip_prefix(dir).unwrap().display().to_string());
            if p.is_dir() {
                stack.push(p);
            }
        }
    }
    out.sort();
    out
}

/// A PLY header integer beyond u64 panicked inside ply-rs (exit 101).
#[test]
fn ply_header_integer_beyond_u64_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    write(
        dir.path(),
        "big.ply",
        b"ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\nproperty float x\nend_header\n",
    );
    write(
        dir.path(),
        "ver.ply",
        b"ply\nformat ascii 99999999999999999999.0\nend_header\n",
    );
    for (file, line, field) in [
        ("big.ply", 3, "element count"),
        ("ver.ply", 2, "format version"),
    ] {
        let (code, _, stderr) = pipemeasure(dir.path(), &["fit-cylinder", file], &[]);
        assert_eq!(code, 1, "{stderr}");
        assert!(
            stderr.contains(&format!("{file}:{line}: field {field}")),
            "{stderr}"
        );
    }
}

/// A 263-byte binary PLY with `element junk 1000000000000` and no property spun for hours.
#[test]
fn ply_element_without_property_exits_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement junk 1000000000000\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
    b.extend([0u8; 12]);
    write(dir.path(), "junk.ply", &b);
    let (code, _, stderr) = pipemeasure(dir.path(), &["fit-cylinder", "junk.ply"], &[]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains(
            "junk.ply:3: element `junk` declares 1000000000000 instances but no property"
        ),
        "{stderr}"
    );
}

/// A duplicated property (`x y z x`) was read as a plausible wrong cloud, exit 0.
#[test]
fn ply_duplicated_property_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    write(
        dir.path(),
        "dup.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty float x\nend_header\n1 2 3 4\n",
    );
    let (code, _, stderr) = pipemeasure(dir.path(), &["fit-cylinder", "dup.ply"], &[]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("dup.ply:7: property `x` of element `vertex` declared a second time"),
        "{stderr}"
    );
}

/// 100 finite points near 1e308 made the cylinder fit panic ("cannot sample empty range").
#[test]
fn fit_cylinder_on_coordinates_near_1e308_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    let points: Vec<[f32; 3]> = (0..100)
        .map(|k| {
            let t = k as f32 / 100.0;
            [t * 3.0e38, -t * 3.0e38, 3.0e38]
        })
        .collect();
    write(dir.path(), "far.ply", &ply(&points));
    // f32 ends at 3.4e38; the same cloud in doubles near 1e308 is checked in `measure::cloud`.
    let (code, _, stderr) = pipemeasure(dir.path(), &["fit-cylinder", "far.ply"], &[]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("far.ply") && stderr.contains("more than the 1e9 m a cloud may span"),
        "{stderr}"
    );
}

/// Option values clap did not check exited 1 (and blamed the wrong option or the file).
#[test]
fn invalid_option_values_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "c.ply", &ply(&[[0.0, 0.0, 0.0]; 20]));
    let cases: [(&[&str], &str); 16] = [
        (
            &[
                "fit-cylinder",
                "c.ply",
                "--radius-min",
                "0.5",
                "--radius-max",
                "0.1",
            ],
            "--radius-min 0.5 must be below --radius-max 0.1",
        ),
        (
            &["fit-cylinder", "c.ply", "--radius-max", "inf"],
            "--radius-max",
        ),
        (
            &["fit-cylinder", "c.ply", "--radius-min=-1"],
            "--radius-min",
        ),
        (
            &["fit-cylinder", "c.ply", "--near", "0,0,0", "--within=-1"],
            "--within",
        ),
        (
            &["fit-cylinder", "c.ply", "--axis-hint", "0,0,0"],
            "--axis-hint",
        ),
        (
            &["fit-cylinder", "c.ply", "--near", "0,0,0"],
            "--near and --within go together",
        ),
        (&["--device", "p30", "c.ply", "--scale=-1"], "--scale"),
        (&["--device", "p30", "c.ply", "--scale", "nan"], "--scale"),
        (
            &["detect", "x.png", "--min-semi-minor", "0"],
            "--min-semi-minor",
        ),
        // The rolling shutter's readout time (merged from main): 0 < ms ≤ 100.
        (
            &[
                "calibrate",
                "--device",
                "d",
                "--frames",
                ".",
                "--readout-time",
                "0",
            ],
            "--readout-time",
        ),
        (
            &[
                "calibrate",
                "--device",
                "d",
                "--frames",
                ".",
                "--readout-time",
                "nan",
            ],
            "--readout-time",
        ),
        (&["--readout-time=-5", "c.ply"], "--readout-time"),
        (
            &["--rolling-shutter", "maybe", "c.ply"],
            "--rolling-shutter",
        ),
        (&["frames", "v.mp4", "--per-second", "0"], "--per-second"),
        (
            &["frames", "v.mp4", "--every-frame-at", "60fps"],
            "--every-frame-at",
        ),
        // A main-command option with a subcommand.
        (
            &["frames", "v.mp4", "--readout-time", "20"],
            "--readout-time",
        ),
    ];
    for (args, names) in cases {
        let (code, _, stderr) = pipemeasure(dir.path(), args, &[]);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert!(stderr.contains(names), "{args:?}: {stderr}");
    }
}

/// `calibrate --device ../../escaped` without `--out` wrote outside `calibrations/`.
#[test]
fn calibrate_device_must_be_a_name() {
    let dir = tempfile::tempdir().unwrap();
    let work = dir.path().join("a/b");
    std::fs::create_dir_all(work.join("frames")).unwrap();
    let (code, _, stderr) = pipemeasure(
        &work,
        &[
            "calibrate",
            "--device",
            "../../escaped",
            "--frames",
            "frames",
            "--sfm",
            "x",
        ],
        &[],
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("`../../escaped` is not a device name"),
        "{stderr}"
    );
    assert_eq!(tree(dir.path()), ["a", "a/b", "a/b/frames"]);
}

/// The profile was written before its report: a failing report left a profile behind. Every
/// destination is now checked before the work, and the outputs are moved into place together.
#[test]
fn calibrate_with_an_unwritable_report_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    lab(dir.path());
    write(
        dir.path(),
        "report",
        b"a file where the report folder should go",
    );
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
            "--report",
            "report/sub",
            "--quiet",
        ],
        &[],
    );
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("report/sub") && stderr.contains("is not a folder"),
        "{stderr}"
    );
    assert!(!dir.path().join("x.json").exists());
    assert_eq!(
        tree(dir.path())
            .iter()
            .filter(|p| p.contains("tmp"))
            .count(),
        0
    );
}

/// `profile list` stopped at a folder named `dir.json` with a self-contradicting message; a
/// profile path that is a folder said "not found".
#[test]
fn profile_list_and_show_with_a_folder_named_json() {
    let dir = tempfile::tempdir().unwrap();
    let cal = dir.path().join("cal");
    std::fs::create_dir_all(cal.join("dir.json")).unwrap();
    let cam = preset_camera(&P30, 320, 180);
    Profile::uncalibrated("small", &cam, BTreeMap::new())
        .write(&cal.join("small.json"), false)
        .unwrap();
    let env = [("PIPEMEASURE_CALIBRATIONS", cal.to_str().unwrap())];
    let (code, stdout, stderr) = pipemeasure(dir.path(), &["profile", "list"], &env);
    assert_eq!(code, 0, "{stderr}");
    // The one profile of the folder, and the presets built in; the folder named dir.json is
    // no profile.
    let names: Vec<&str> = stdout
        .lines()
        .map(|l| l.split('\t').next().unwrap())
        .collect();
    assert_eq!(names, ["iphone11", "p30", "s10", "small"], "{stdout}");
    assert!(
        stdout.contains(&format!(
            "small\t$PIPEMEASURE_CALIBRATIONS\t{}",
            cal.join("small.json").display()
        )),
        "{stdout}"
    );
    for device in ["dir", "cal/dir.json"] {
        let (code, _, stderr) = pipemeasure(dir.path(), &["profile", "show", device], &env);
        assert_eq!(code, 1, "{stderr}");
        assert!(
            stderr.contains("dir.json: is a directory, expected a file"),
            "{stderr}"
        );
    }
}

/// `profile show` accepted fx = 0 (`b1 = −c`); a second object after the profile was ignored.
#[test]
fn profile_show_refuses_fx_zero_and_a_second_object() {
    let dir = tempfile::tempdir().unwrap();
    let cam = preset_camera(&P30, 320, 180);
    let mut p = Profile::uncalibrated("small", &cam, BTreeMap::new());
    let text = p.to_json();
    write(
        dir.path(),
        "two.json",
        format!("{text}\n{text}\n").as_bytes(),
    );
    p.intrinsics.b1 = -p.intrinsics.c * (1.0 - 1e-15);
    write(dir.path(), "fx0.json", p.to_json().as_bytes());
    let (code, _, stderr) = pipemeasure(dir.path(), &["profile", "show", "fx0.json"], &[]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("fx0.json: field `intrinsics.b1`") && stderr.contains("pixel aspect"),
        "{stderr}"
    );
    let (code, _, stderr) = pipemeasure(dir.path(), &["profile", "show", "two.json"], &[]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("trailing characters"), "{stderr}");
}

/// A small profile (the p30 preset at 320×180) with its distortion changed by `edit`.
fn profile_with(dir: &Path, name: &str, edit: impl Fn(&mut Profile)) -> String {
    let cam = preset_camera(&P30, 320, 180);
    let mut p = Profile::uncalibrated("small", &cam, BTreeMap::new());
    edit(&mut p);
    let path = dir.join(name);
    p.write(&path, false).unwrap();
    path.display().to_string()
}

fn grey(w: u32, h: u32) -> DynamicImage {
    DynamicImage::ImageRgb8(ImageBuffer::from_fn(w, h, |x, y| {
        Rgb([(x * 3) as u8, (y * 5) as u8, 90])
    }))
}

/// A failed `undistort` left a partly filled output folder; a distortion that cannot be
/// inverted wrote black frames and exited 0.
#[test]
fn undistort_is_all_or_nothing_and_refuses_a_folding_distortion() {
    let dir = tempfile::tempdir().unwrap();
    let good = profile_with(dir.path(), "good.json", |_| {});
    let input = dir.path().join("frames");
    std::fs::create_dir(&input).unwrap();
    for k in 0..6 {
        grey(320, 180)
            .save(input.join(format!("f{k}.png")))
            .unwrap();
    }
    // The last frame's header is right (320×180) but its data stop early.
    let bytes = std::fs::read(input.join("f5.png")).unwrap();
    std::fs::write(input.join("f5.png"), &bytes[..bytes.len() / 2]).unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    write(&out, "keep.txt", b"the user's");
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["undistort", "--device", &good, "frames", "out"],
        &[],
    );
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("f5.png"), "{stderr}");
    assert_eq!(tree(&out), ["keep.txt"]);
    assert!(
        !tree(dir.path()).iter().any(|p| p.contains(".out.tmp")),
        "{:?}",
        tree(dir.path())
    );
    // With the broken frame gone every frame arrives, the user's file stays.
    std::fs::remove_file(input.join("f5.png")).unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["undistort", "--device", &good, "frames", "out"],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(
        tree(&out),
        [
            "cameras.txt",
            "f0.png",
            "f1.png",
            "f2.png",
            "f3.png",
            "f4.png",
            "keep.txt"
        ]
    );
    // k1 = −5: the distortion folds back a third of the way out.
    let folding = profile_with(dir.path(), "fold.json", |p| p.intrinsics.k1 = -5.0);
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &["undistort", "--device", &folding, "frames", "folded"],
        &[],
    );
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("cannot be inverted over the frame"),
        "{stderr}"
    );
    assert!(!dir.path().join("folded").exists());
    // `profile show` shows it, and says so; an invertible profile gets no such warning.
    let (code, _, stderr) = pipemeasure(dir.path(), &["profile", "show", &good], &[]);
    assert_eq!(code, 0, "{stderr}");
    assert!(!stderr.contains("`undistort` refuses"), "{stderr}");
    let (code, _, stderr) = pipemeasure(dir.path(), &["profile", "show", &folding], &[]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("warning") && stderr.contains("`undistort` refuses this profile"),
        "{stderr}"
    );
}

/// `match` used frames of another size than the model's camera (and decoded a 16000×16000
/// PNG in full); it exited 1 rather than 3 when nothing matched.
#[test]
fn match_checks_frame_sizes_and_exits_3_when_nothing_matches() {
    let dir = tempfile::tempdir().unwrap();
    lab(dir.path());
    let frames = dir.path().join("lab/frames");
    let first = frames.join("frame_0001.png");
    let original = std::fs::read(&first).unwrap();
    grey(960, 540).save(&first).unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &[
            "match",
            "--frames",
            "lab/frames",
            "--sfm",
            "lab/sparse",
            "--quiet",
        ],
        &[],
    );
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("frame_0001.png: the frame is 960x540 but the model's camera is 480x270"),
        "{stderr}"
    );
    std::fs::write(&first, original).unwrap();
    // Blank frames of the right size: no target, no match.
    for k in 1..=4 {
        DynamicImage::ImageLuma8(ImageBuffer::from_pixel(480, 270, Luma([200u8])))
            .save(frames.join(format!("frame_{k:04}.png")))
            .unwrap();
    }
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &[
            "match",
            "--frames",
            "lab/frames",
            "--sfm",
            "lab/sparse",
            "--quiet",
        ],
        &[],
    );
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("no target was matched"), "{stderr}");
    let (code, _, stderr) = pipemeasure(dir.path(), &["detect", "lab/frames/frame_0001.png"], &[]);
    assert_eq!(code, 3, "{stderr}");
}

/// A truncated JPEG (the first third of a frame) was accepted, its missing part grey.
#[test]
fn truncated_jpeg_frame_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = std::io::Cursor::new(Vec::new());
    grey(320, 180)
        .write_to(&mut bytes, image::ImageFormat::Jpeg)
        .unwrap();
    let bytes = bytes.into_inner();
    write(dir.path(), "cut.jpg", &bytes[..bytes.len() / 3]);
    let (code, _, stderr) = pipemeasure(dir.path(), &["detect", "cut.jpg"], &[]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains(
            "cut.jpg: file ends early: the JPEG data stop before the end-of-image marker"
        ),
        "{stderr}"
    );
}

/// The main command checked its `--json` destination only after the whole measurement; write
/// errors printed the OS error twice.
#[test]
fn destinations_are_checked_first_and_the_os_error_printed_once() {
    let dir = tempfile::tempdir().unwrap();
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &[
            "--device",
            "p30",
            "missing.ply",
            "--json",
            "no/such/folder/m.json",
        ],
        &[],
    );
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("no/such/folder/m.json") && !stderr.contains("missing.ply"),
        "{stderr}"
    );
    // A write that fails inside the work: the OS error appears once.
    write(dir.path(), "blocker", b"");
    let (code, _, stderr) = pipemeasure(
        dir.path(),
        &[
            "simulate",
            "lab",
            "--like",
            "p30",
            "--width",
            "64",
            "--frames",
            "2",
            "--out",
            "blocker/lab",
        ],
        &[],
    );
    assert_eq!(code, 1, "{stderr}");
    assert_eq!(stderr.matches("os error").count(), 1, "{stderr}");
}
