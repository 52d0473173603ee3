//! Real files no one on this project made (../shared/data): pinned contents.
#![allow(clippy::unwrap_used)]

mod common;

use std::path::Path;

use pipemeasure::io::ply;

const MUG: &str = "../shared/data/pcl_mug/table_scene_mug_stereo_textured.ply";

/// The PCL mug scan: a 640×480 organised stereo cloud, binary little-endian, with an empty
/// `face` element and a `camera` element after the vertices. Expected values were computed
/// independently with Python's `struct` over the raw bytes.
#[test]
fn mug_cloud_has_209280_finite_points() {
    let read = ply::read(Path::new(MUG)).unwrap();
    assert_eq!(read.vertices_in_file, 307_200);
    assert_eq!(read.skipped_non_finite, 97_920);
    assert_eq!(read.cloud.len(), 209_280);
    let first = read.cloud.points[0];
    // Vertex 6538 is the first finite one; these are its f32 coordinates widened to f64.
    assert_eq!(first.x, -0.381_909_996_271_133_4);
    assert_eq!(first.y, -0.448_199_987_411_499);
    assert_eq!(first.z, 2.025_799_989_700_317_4);
    assert_eq!(read.cloud.colors.as_ref().unwrap()[0], [67, 67, 62]);
    assert!(read.cloud.normals.is_none() && read.cloud.intensity.is_none());
    let n = read.cloud.len() as f64;
    let mean_z = read.cloud.points.iter().map(|p| p.z).sum::<f64>() / n;
    assert!(
        (mean_z - 1.264_727_422_063_287_4).abs() < 1e-12,
        "mean z {mean_z} m"
    );
}

const BOOFCV: &str = "../shared/data/boofcv_circle_grids";

/// The detections of a real photo, with the CLI's smallest semi-minor axis (3 px).
fn detect_photo(path: &Path) -> Vec<pipemeasure::detect::DetectedEllipse> {
    use pipemeasure::detect::{DetectConfig, Detector};
    let mut detector = Detector::new(DetectConfig {
        min_semi_minor_px: 3.0,
        ..DetectConfig::default()
    })
    .unwrap();
    let frame = pipemeasure::io::frames::read_frame(path).unwrap();
    detector.detect(&frame).ellipses
}

/// BoofCV's real photos of its 8×10 dot grid (`stills_regular`, 640×480 JPEG; the grid's
/// size is in its `calibration_target.yaml`): each of the six photos shows the whole grid, and
/// exactly its 80 dark dots are found, each with the fit quality of a sharp edge.
#[test]
fn boofcv_regular_grid_stills_show_exactly_the_80_dots() {
    let dir = Path::new(BOOFCV).join("stills_regular");
    let mut photos: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "jpg"))
        .collect();
    photos.sort();
    assert_eq!(photos.len(), 6);
    for p in &photos {
        let found = detect_photo(p);
        let dark = found
            .iter()
            .filter(|e| e.polarity == pipemeasure::detect::DiscPolarity::Dark)
            .count();
        assert_eq!((found.len(), dark), (80, 80), "{}", p.display());
        assert!(found.iter().all(|e| e.rms_px < 0.3), "{}", p.display());
    }
}

/// BoofCV's hexagonal grid (24 rows × 28 columns in its `calibration_target.yaml`: 336 dots —
/// half of 24 × 28, as alternate rows are offset; not 672): every dark dot of the six photos
/// that show the whole grid is found. Known gap (issue 18): up to two *light* round blobs off
/// the board — white pins on the brown background, with a one-sided shadow — are found too.
#[test]
fn boofcv_hexagonal_grid_stills_show_all_336_dots() {
    let dir = Path::new(BOOFCV).join("stills_hexagonal");
    for name in [
        "image01", "image02", "image03", "image04", "image05", "image07",
    ] {
        let found = detect_photo(&dir.join(format!("{name}.jpg")));
        let dark = found
            .iter()
            .filter(|e| e.polarity == pipemeasure::detect::DiscPolarity::Dark)
            .count();
        assert_eq!(dark, 336, "{name}");
        assert!(
            found.len() - dark <= 2,
            "{name}: {} light blobs",
            found.len() - dark
        );
    }
}

/// BoofCV's real hand-held video of its flat 8×10 dot grid on a carpet (640×480 H.264, every
/// 15th frame: 42 frames with motion blur, partial grids and frames without a dot), calibrated
/// as a user would: `pipemeasure calibrate --frames DIR` running COLMAP itself. It used to stop
/// with "the normal equations are singular" (a frame without targets in the free network). Now
/// it calibrates, and the camera agrees with BoofCV's chessboard
/// calibration of the same camera within the spread of BoofCV's two published calibrations
/// (6 px in the principal point, 5 px in the focal length; BoofCV's pixel origin is the first
/// pixel's centre, ours its corner: +0.5 px). Against BoofCV's own dot-video calibration it is
/// 6–8 px off in u0 and c (the gap the issue still tracks).
#[test]
fn boofcv_hand_held_dot_grid_video_calibrates() {
    if !common::program_available("ffmpeg", "-version", "apt-get install -y ffmpeg")
        || !common::colmap_available()
    {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let frames = tmp.path().join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let movie = Path::new(BOOFCV).join("video_regular/movie.mp4");
    let out = std::process::Command::new("ffmpeg")
        .args(["-loglevel", "error", "-i"])
        .arg(&movie)
        .args([
            "-vf",
            "select=not(mod(n\\,15))",
            "-vsync",
            "vfr",
            "-q:v",
            "2",
        ])
        .arg(frames.join("frame_%04d.jpg"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(std::fs::read_dir(&frames).unwrap().count(), 42);
    let (code, stdout, stderr) = common::pipemeasure(
        tmp.path(),
        &[
            "calibrate",
            "--device",
            "boofcv",
            "--frames",
            "frames",
            "--min-semi-minor",
            "3",
            "--out",
            "boofcv.json",
            "--report",
            "report",
            "--quiet",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}\n{stdout}");
    let profile = pipemeasure::profile::Profile::read(&tmp.path().join("boofcv.json")).unwrap();
    let i = profile.intrinsics;
    // BoofCV's chessboard calibration (chessboard_calibration/intrinsic.yaml), our origin.
    let (fx, fy, u0, v0) = (701.0, 698.6, 308.96, 247.34);
    eprintln!(
        "c {:.1} u0 {:.1} v0 {:.1} k1 {:.4} k2 {:.4}",
        i.c, i.u0, i.v0, i.k1, i.k2
    );
    assert!((i.c - 0.5 * (fx + fy)).abs() < 5.0, "c {}", i.c);
    assert!((i.u0 - u0).abs() < 6.0 && (i.v0 - v0).abs() < 6.0, "{i:?}");
    // The radial profile: BoofCV's k1 −0.2556, k2 0.1000 (chessboard) and −0.2735, 0.1457
    // (dots) bracket a displacement at the frame's corner (r ≈ 0.57 in units of f) of about
    // −30 px; ours within that spread.
    let r2 = (320.0f64.powi(2) + 240.0f64.powi(2)) / (0.5 * (fx + fy)).powi(2);
    let radial = |k1: f64, k2: f64| (k1 * r2 + k2 * r2 * r2) * r2.sqrt() * 0.5 * (fx + fy);
    let (lo, hi) = (radial(-0.2735, 0.1457), radial(-0.2556, 0.1000));
    let ours = radial(i.k1, i.k2);
    assert!(
        ours > lo.min(hi) - 3.0 && ours < lo.max(hi) + 3.0,
        "corner displacement {ours} px, BoofCV {lo}…{hi}"
    );
    // Whether the loop converges depends on COLMAP's run (not deterministic across runs): on
    // 2026-12-02 it stopped by camera stability at iteration 3 in two runs and ran out of
    // iterations in a third with the same camera to 0.4 px. The report says which.
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.path().join("report/report.json")).unwrap(),
    )
    .unwrap();
    eprintln!(
        "converged: {}, {}",
        report["converged"], report["stop_reason"]
    );
    assert!(
        report["stop_reason"]
            .as_str()
            .is_some_and(|s| !s.is_empty())
    );
}
