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

/// The detections of a set of real photos with the default options, as `pipemeasure detect`
/// makes them of the frames it is given: every photo detected, then the set's stray polarity
/// dropped ([`pipemeasure::detect::drop_stray_polarity`]).
fn detect_set(paths: &[std::path::PathBuf]) -> Vec<pipemeasure::detect::Detection> {
    use pipemeasure::detect::{DetectConfig, Detector, drop_stray_polarity};
    let config = DetectConfig::default();
    let mut detector = Detector::new(config.clone()).unwrap();
    let mut found: Vec<_> = paths
        .iter()
        .map(|p| detector.detect(&pipemeasure::io::frames::read_frame(p).unwrap()))
        .collect();
    drop_stray_polarity(&mut found, config.stray_polarity_share);
    found
}

/// The detections of one real photo with every stray-polarity judgement left out: both
/// polarities, whatever their numbers.
fn detect_both_polarities(path: &Path) -> Vec<pipemeasure::detect::DetectedEllipse> {
    use pipemeasure::detect::{DetectConfig, Detector};
    let mut detector = Detector::new(DetectConfig {
        stray_polarity_share: 0.0,
        ..DetectConfig::default()
    })
    .unwrap();
    let frame = pipemeasure::io::frames::read_frame(path).unwrap();
    detector.detect(&frame).ellipses
}

/// BoofCV's real photos of its 8×10 dot grid (`stills_regular`, 640×480 JPEG; the grid's
/// size is in its `calibration_target.yaml`): each of the six photos shows the whole grid, and
/// with the default options exactly its 80 dark dots are found, each with the fit quality of a
/// sharp edge.
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
    for (p, found) in photos.iter().zip(detect_set(&photos)) {
        let found = found.ellipses;
        let dark = found
            .iter()
            .filter(|e| e.polarity == pipemeasure::detect::DiscPolarity::Dark)
            .count();
        assert_eq!((found.len(), dark), (80, 80), "{}", p.display());
        assert!(found.iter().all(|e| e.rms_px < 0.3), "{}", p.display());
    }
}

/// BoofCV's hexagonal grid (24 rows × 28 columns in its `calibration_target.yaml`: 336 dots —
/// half of 24 × 28, as alternate rows are offset; not 672): in the six photos that show the
/// whole grid, the default options find exactly the 336 dots and nothing else. Looking for both
/// polarities whatever their numbers, one or two white pins off the board show per photo
/// (domes with a one-sided shadow on the brown clipboard): their appearance — step residual
/// ≤ 0.05, interior 0.06–0.10 and surround 0.04–0.07 of the contrast — lies within what the
/// grid's own dots show in JPEG and H.264 (interior up to 0.08, surround up to 0.08), so no
/// appearance test drops them without dropping dots; they are dropped as the set's stray
/// polarity (8 of 2024 detections).
#[test]
fn boofcv_hexagonal_grid_stills_show_all_336_dots() {
    use pipemeasure::detect::DiscPolarity;
    let dir = Path::new(BOOFCV).join("stills_hexagonal");
    let photos: Vec<_> = [
        "image01", "image02", "image03", "image04", "image05", "image07",
    ]
    .iter()
    .map(|name| dir.join(format!("{name}.jpg")))
    .collect();
    let mut pins = 0;
    for (path, found) in photos.iter().zip(detect_set(&photos)) {
        let name = path.display();
        assert_eq!(found.ellipses.len(), 336, "{name}");
        assert!(
            found
                .ellipses
                .iter()
                .all(|e| e.polarity == DiscPolarity::Dark)
        );
        let both = detect_both_polarities(path);
        let light = both
            .iter()
            .filter(|e| e.polarity == DiscPolarity::Light)
            .count();
        assert_eq!(both.len() - light, 336, "{name}");
        assert!(light <= 2, "{name}: {light} light blobs");
        assert_eq!(found.diagnostics.stray_polarity, light, "{name}");
        pins += light;
    }
    assert!(pins > 0, "the pins the stray polarity is there for");
}

/// Extracts every 15th frame of BoofCV's hand-held 8×10 dot-grid video into `dir` as the issue
/// and `scripts/boofcv_video_grid.py` do (`frame_0001.jpg` … `frame_0042.jpg`).
fn extract_every_15th_frame(dir: &Path) {
    extract_every_15th_frame_of("video_regular", dir, 42);
}

/// Extracts every 15th frame of BoofCV's video in folder `video` into `dir` and checks there
/// are `count` of them.
fn extract_every_15th_frame_of(video: &str, dir: &Path, count: usize) {
    let movie = Path::new(BOOFCV).join(video).join("movie.mp4");
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
        .arg(dir.join("frame_%04d.jpg"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(std::fs::read_dir(dir).unwrap().count(), count);
}

/// The dot centres the default options find in each of the frames in `dir`
/// (`frame_0001.jpg` … `frame_{count}.jpg`), detected as one set as `pipemeasure detect`
/// does (the videos' dots go down to 2.4 px in semi-minor axis).
fn dot_centres_of_frames(dir: &Path, count: usize) -> Vec<Vec<nalgebra::Vector2<f64>>> {
    let paths: Vec<_> = (1..=count)
        .map(|k| dir.join(format!("frame_{k:04}.jpg")))
        .collect();
    detect_set(&paths)
        .iter()
        .map(|d| {
            d.ellipses
                .iter()
                .map(|e| nalgebra::Vector2::new(e.cx, e.cy))
                .collect()
        })
        .collect()
}

/// Calibrated on BoofCV's hand-held video of its hexagonal grid (every 15th frame: 35
/// frames of 640×480 H.264; 336 dots, half of its 24 × 28 in `calibration_target.yaml`, as
/// alternate rows are offset). Every frame shows the whole grid (checked by eye, and by the
/// hexagonal lattice `scripts/boofcv_detection_eval.py` grows over the detections: exactly the
/// 24 × 28 grid in all 35). In each frame, with the default options (the 35 frames one set),
/// exactly 336 are found, and none lies apart from the grid (farther from its nearest
/// detection than twice the frame's median nearest-detection distance, the grid's spacing). On
/// the densest views the dots' edges are 1.5 px apart and linking runs from one dot's edge into
/// its neighbour's: 23 dots in 5 frames were missed before each loop inside a chain, and each
/// short chain whole, proposed its dot (`detect::contours`).
#[test]
fn boofcv_hexagonal_video_frames_show_all_336_dots() {
    if !common::program_available("ffmpeg", "-version", "apt-get install -y ffmpeg") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    extract_every_15th_frame_of("video_hexagonal", tmp.path(), 35);
    let centres = dot_centres_of_frames(tmp.path(), 35);
    let mut short = Vec::new();
    for (k, found) in (1..=35).zip(centres) {
        let name = format!("frame_{k:04}.jpg");
        if found.len() != 336 {
            short.push(format!("{name}: {}", found.len()));
            continue;
        }
        let nearest: Vec<f64> = found
            .iter()
            .enumerate()
            .map(|(i, p)| {
                found
                    .iter()
                    .enumerate()
                    .filter(|&(j, _)| j != i)
                    .map(|(_, q)| (p - q).norm())
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        let apart: Vec<usize> = {
            let mut sorted = nearest.clone();
            sorted.sort_by(f64::total_cmp);
            let median = sorted[sorted.len() / 2];
            nearest
                .iter()
                .enumerate()
                .filter(|&(_, &d)| d > 2.0 * median)
                .map(|(i, _)| i)
                .collect()
        };
        assert!(
            apart.is_empty(),
            "{name}: detections apart from the grid: {apart:?}"
        );
    }
    assert!(
        short.is_empty(),
        "frames without exactly 336 dots: {short:?}"
    );
}

/// Calibrated on BoofCV's hand-held video of its 8×10 dot grid (every 15th frame: 42
/// frames of 640×480 H.264 with motion blur; dots down to 2.4 px in semi-minor axis, on wooden
/// boards and asphalt with pebbles, beside the clipboard's clip). The reference is independent:
/// OpenCV 4.6's `findCirclesGrid` (its own blob detector, symmetric 8×10 pattern, its
/// clustering finder where the plain one fails) found the whole grid in 39 of the frames
/// (`tests/fixtures/boofcv_video_grid.json`, written by `scripts/boofcv_video_grid.py`; in the
/// other three the grid runs out of the frame). In each of the 39, with the default options
/// (the 42 frames one set): each of the 80 grid positions has exactly one detection within 0.3 of
/// its grid spacing and 2 px (OpenCV's thresholded blob centroids differ from an edge fit by up
/// to 1.6 px on motion-blurred dots, 0.035 px in the median), and no detection lies farther than
/// half a spacing from every grid position. The three frames without a reference are left out:
/// a grid mapped from our own detections would not be an independent check.
#[test]
fn boofcv_video_frames_show_every_grid_dot_and_nothing_else() {
    if !common::program_available("ffmpeg", "-version", "apt-get install -y ffmpeg") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    extract_every_15th_frame(tmp.path());
    let fixture: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string("tests/fixtures/boofcv_video_grid.json").unwrap(),
    )
    .unwrap();
    assert_eq!(fixture["frames_extracted"], 42);
    let frames = fixture["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 39);
    let centres = dot_centres_of_frames(tmp.path(), 42);
    let mut offsets = Vec::new();
    for f in frames {
        let name = f["frame"].as_str().unwrap();
        let (rows, cols) = (
            f["rows"].as_u64().unwrap() as usize,
            f["cols"].as_u64().unwrap() as usize,
        );
        let grid: Vec<nalgebra::Vector2<f64>> = f["centres"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| nalgebra::Vector2::new(c[0].as_f64().unwrap(), c[1].as_f64().unwrap()))
            .collect();
        assert_eq!(grid.len(), rows * cols);
        // Each grid position's spacing: the distance to its nearest grid neighbour.
        let spacing: Vec<f64> = (0..grid.len())
            .map(|k| {
                let (r, c) = (k / cols, k % cols);
                [(0, 1), (1, 0), (0, -1), (-1, 0)]
                    .iter()
                    .filter_map(|&(dr, dc): &(isize, isize)| {
                        let (r2, c2) = (r as isize + dr, c as isize + dc);
                        (r2 >= 0 && c2 >= 0 && (r2 as usize) < rows && (c2 as usize) < cols)
                            .then(|| (grid[r2 as usize * cols + c2 as usize] - grid[k]).norm())
                    })
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        let k: usize = name
            .trim_start_matches("frame_")
            .trim_end_matches(".jpg")
            .parse()
            .unwrap();
        let found = &centres[k - 1];
        for (k, g) in grid.iter().enumerate() {
            let near: Vec<f64> = found
                .iter()
                .map(|p| (p - g).norm())
                .filter(|&d| d < 0.3 * spacing[k])
                .collect();
            assert_eq!(
                near.len(),
                1,
                "{name}: grid position {k} at {g:?}: {near:?}"
            );
            assert!(
                near[0] < 2.0,
                "{name}: grid position {k}: {} px off",
                near[0]
            );
            offsets.push(near[0]);
        }
        for p in found {
            let on_grid = grid
                .iter()
                .zip(&spacing)
                .any(|(g, s)| (p - g).norm() <= 0.5 * s);
            assert!(on_grid, "{name}: detection at {p:?} is off the grid");
        }
    }
    offsets.sort_by(f64::total_cmp);
    eprintln!(
        "{} dots; offset from OpenCV's centres: median {:.3} px, 99th percentile {:.3} px, max {:.3} px",
        offsets.len(),
        offsets[offsets.len() / 2],
        offsets[offsets.len() * 99 / 100],
        offsets[offsets.len() - 1]
    );
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
    let (tmp, profile, report) = calibrate_every_15th_frame("video_regular", 42, "boofcv");
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
    let radial = |k1: f64, k2: f64| corner_displacement(k1, k2, 0.5 * (fx + fy));
    let (lo, hi) = (radial(-0.2735, 0.1457), radial(-0.2556, 0.1000));
    let ours = radial(i.k1, i.k2);
    assert!(
        ours > lo.min(hi) - 3.0 && ours < lo.max(hi) + 3.0,
        "corner displacement {ours} px, BoofCV {lo}…{hi}"
    );
    // Whether the loop converges depends on COLMAP's run (not deterministic across runs): on
    // 2026-12-02 it stopped by camera stability at iteration 3 in two runs and ran out of
    // iterations in a third with the same camera to 0.4 px. The report says which.
    eprintln!(
        "converged: {}, {}",
        report["converged"], report["stop_reason"]
    );
    assert!(
        report["stop_reason"]
            .as_str()
            .is_some_and(|s| !s.is_empty())
    );
    calibrates_from_the_video_itself(tmp.path(), &profile);
}

/// Calibrated on BoofCV's hand-held video of its hexagonal grid (every 15th frame: 35
/// frames, 336 dots), calibrated as a user would (`calibrate --frames DIR`, COLMAP run by
/// calibrate).
///
/// * **One dot, one track**: the adjusted targets (`report.json`'s network), in their best-fit
///   plane, hold each dot of the grid once: 336 targets with a neighbour at the grid's spacing,
///   and no two targets within 0.3 of it (a dot split into two tracks); the issue allows 1 %
///   (3 dots). Measured 2026-12-04: 336 on the grid, none split, 2 targets off it (the
///   clipboard's pins), and `scripts/boofcv_detection_eval.py`'s lattice over the plane is
///   exactly the 24 × 28 grid.
/// * **The camera** against an independent calibration of the same camera: OpenCV 4.6's
///   `calibrateCamera` with the grid's printed layout (equilateral, 1.2 apart) on BoofCV's
///   hexagonal *stills* (six with the whole grid; k1, k2 as BoofCV's model; printed by
///   `scripts/opencv_calibrate_pipemeasure_centres.py`): fx 691.6, fy 690.7, u0 326.39, v0
///   248.61, k1 −0.2690, k2 0.1321 in our pixels. Within the spread of BoofCV's two
///   calibrations (5 px in c, 6 px in the principal point), and the radial displacement at the
///   frame's corner within 3 px. BoofCV's published calibration (fx 702.5, u0 315.1) is 10–11
///   px from both: it fits the stills' dots at RMS 0.309 px against OpenCV's 0.245 px, so it
///   is no reference for this camera to a few pixels.
/// * **The loop converges**: every iteration after the first moves the camera by less than its
///   projection σ over the frame, and the loop stops within its 10 iterations (the matches do
///   not change, or the camera moves by less than 0.1 σ). Until a joined track could grow
///   (`calibrate::tracks`), 8–43 free views per iteration came and went, the camera wandered
///   by 0.08–0.54 σ, and the loop ran out of iterations in one of two COLMAP runs; since, three
///   COLMAP models stopped at iterations 2, 3 and 4 (2026-12-04).
#[test]
fn boofcv_hexagonal_video_calibrates_with_one_track_per_dot() {
    if !common::program_available("ffmpeg", "-version", "apt-get install -y ffmpeg")
        || !common::colmap_available()
    {
        return;
    }
    let (_tmp, profile, report) = calibrate_every_15th_frame("video_hexagonal", 35, "boofhex");
    let i = profile.intrinsics;
    eprintln!(
        "c {:.2} u0 {:.2} v0 {:.2} k1 {:.4} k2 {:.4}",
        i.c, i.u0, i.v0, i.k1, i.k2
    );
    // OpenCV's known-layout calibration of the hexagonal stills (our pixel origin).
    let (fx, fy, u0, v0, k1, k2) = (691.6, 690.7, 326.39, 248.61, -0.2690, 0.1321);
    let f = 0.5 * (fx + fy);
    assert!((i.c - f).abs() < 5.0, "c {} against {f}", i.c);
    assert!((i.u0 - u0).abs() < 6.0, "u0 {} against {u0}", i.u0);
    assert!((i.v0 - v0).abs() < 6.0, "v0 {} against {v0}", i.v0);
    let (ours, theirs) = (
        corner_displacement(i.k1, i.k2, f),
        corner_displacement(k1, k2, f),
    );
    assert!(
        (ours - theirs).abs() < 3.0,
        "corner displacement {ours} px against {theirs} px"
    );

    let xyz: Vec<nalgebra::Vector3<f64>> = report["network"]["targets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            let p = t["xyz"].as_array().unwrap();
            nalgebra::Vector3::new(
                p[0].as_f64().unwrap(),
                p[1].as_f64().unwrap(),
                p[2].as_f64().unwrap(),
            )
        })
        .collect();
    let (on_grid, split) = grid_targets_and_splits(&xyz);
    eprintln!(
        "{} adjusted targets: {on_grid} on the grid, {split} pairs of them within 0.3 spacing",
        xyz.len()
    );
    assert!(split <= 3, "{split} dots split into several tracks");
    assert_eq!(on_grid - split, 336, "{on_grid} targets on the grid");

    let iterations = report["iterations"].as_array().unwrap();
    for it in iterations.iter().skip(1) {
        if let Some(ratio) = it["camera_change_ratio"].as_f64() {
            assert!(
                ratio < 1.0,
                "iteration {}: moved {ratio} σ",
                it["iteration"]
            );
        }
    }
    eprintln!(
        "{} iterations; converged: {}, {}",
        iterations.len(),
        report["converged"],
        report["stop_reason"]
    );
    assert_eq!(
        report["converged"].as_bool(),
        Some(true),
        "{}",
        report["stop_reason"]
    );
}

/// Every 15th frame of BoofCV's hand-held video in folder `video` (`count` frames) calibrated
/// as a user would: `pipemeasure calibrate --frames DIR` running COLMAP itself, with the
/// videos' smallest dots (`--min-semi-minor 3`). Returns the working folder, the profile
/// (`DEVICE.json`) and the report (`report/report.json`).
fn calibrate_every_15th_frame(
    video: &str,
    count: usize,
    device: &str,
) -> (
    tempfile::TempDir,
    pipemeasure::profile::Profile,
    serde_json::Value,
) {
    let tmp = tempfile::tempdir().unwrap();
    let frames = tmp.path().join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    extract_every_15th_frame_of(video, &frames, count);
    let out = format!("{device}.json");
    let (code, stdout, stderr) = common::pipemeasure(
        tmp.path(),
        &[
            "calibrate",
            "--device",
            device,
            "--frames",
            "frames",
            "--min-semi-minor",
            "3",
            "--out",
            &out,
            "--report",
            "report",
            "--quiet",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}\n{stdout}");
    let profile = pipemeasure::profile::Profile::read(&tmp.path().join(&out)).unwrap();
    let report = serde_json::from_str(
        &std::fs::read_to_string(tmp.path().join("report/report.json")).unwrap(),
    )
    .unwrap();
    (tmp, profile, report)
}

/// The radial displacement (px) of k1, k2 at the corner of BoofCV's 640 × 480 frames, for a
/// principal distance `f` (px) and the principal point at the centre.
fn corner_displacement(k1: f64, k2: f64, f: f64) -> f64 {
    let r2 = (320.0f64.powi(2) + 240.0f64.powi(2)) / (f * f);
    (k1 * r2 + k2 * r2 * r2) * r2.sqrt() * f
}

/// Of targets on a flat grid: how many lie on it (a neighbour within 1.5 × the grid's spacing,
/// the median nearest-neighbour distance, in their best-fit plane) and how many pairs of those
/// lie within 0.3 × the spacing of each other (one dot, two tracks).
fn grid_targets_and_splits(xyz: &[nalgebra::Vector3<f64>]) -> (usize, usize) {
    let n = xyz.len();
    let mean = xyz.iter().sum::<nalgebra::Vector3<f64>>() / n as f64;
    let scatter = xyz
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<nalgebra::Matrix3<f64>>();
    let eig = scatter.symmetric_eigen();
    let normal = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
    let flat: Vec<nalgebra::Vector3<f64>> = xyz
        .iter()
        .map(|p| (p - mean) - normal * normal.dot(&(p - mean)))
        .collect();
    let distance = |i: usize, j: usize| (flat[i] - flat[j]).norm();
    let nearest: Vec<f64> = (0..n)
        .map(|i| {
            (0..n)
                .filter(|&j| j != i)
                .map(|j| distance(i, j))
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    let mut sorted = nearest.clone();
    sorted.sort_by(f64::total_cmp);
    let spacing = sorted[n / 2];
    let on: Vec<usize> = (0..n).filter(|&i| nearest[i] < 1.5 * spacing).collect();
    let split = on
        .iter()
        .enumerate()
        .flat_map(|(a, &i)| on[a + 1..].iter().map(move |&j| (i, j)))
        .filter(|&(i, j)| distance(i, j) < 0.3 * spacing)
        .count();
    (on.len(), split)
}

/// BoofCV's dot calibration of its hand-held video (`video_regular/intrinsic.yaml`: fx 702.55,
/// fy 703.66, cx 314.61, cy 247.51, k1 −0.27349, k2 0.14570) in our model (c = fy,
/// b1 = fx − fy; the pixel origin at the first pixel's corner: +0.5 px).
fn boofcv_dot_calibration() -> pipemeasure::camera::Intrinsics {
    let (fx, fy) = (702.549_154_739_851_1, 703.657_987_453_425);
    pipemeasure::camera::Intrinsics {
        k1: -0.273_487_468_814_263_2,
        k2: 0.145_701_185_295_044_72,
        b1: fx - fy,
        ..pipemeasure::camera::Intrinsics::pinhole(
            fy,
            314.606_990_455_667 + 0.5,
            247.508_119_977_163_55 + 0.5,
        )
    }
}

/// On real video: `calibrate --video movie.mp4 --per-second 2` decodes
/// BoofCV's hand-held dot-grid video, chooses the frames (with their neighbours, so the
/// rolling shutter's readout time can be estimated), runs COLMAP and calibrates. Compared with
/// BoofCV's dot calibration of the same video by the projection difference over the frame
/// after the best rotation between the two cameras (mrcal's "implied rotation": a principal
/// point and a small rotation of the frames trade on a flat grid).
/// Called by [`boofcv_hand_held_dot_grid_video_calibrates`] with its every-15th-frame profile
/// (one COLMAP run and calibration fewer).
fn calibrates_from_the_video_itself(tmp: &Path, every: &pipemeasure::profile::Profile) {
    use pipemeasure::calibrate::checks::projection_difference_rotated;
    let movie = std::fs::canonicalize(Path::new(BOOFCV).join("video_regular/movie.mp4")).unwrap();
    let calibrate = |name: &str, source: &[&str]| {
        let out = format!("{name}.json");
        let mut args = vec![
            "calibrate",
            "--device",
            name,
            "--min-semi-minor",
            "3",
            "--out",
            &out,
            "--quiet",
        ];
        args.extend_from_slice(source);
        let (code, stdout, stderr) = common::pipemeasure(tmp, &args, &[]);
        assert_eq!(code, 0, "{stderr}\n{stdout}");
        pipemeasure::profile::Profile::read(&tmp.join(&out)).unwrap()
    };
    let video = calibrate(
        "video",
        &[
            "--video",
            movie.to_str().unwrap(),
            "--frames",
            "chosen",
            "--per-second",
            "2",
            // With third-order motions the loop does not settle on this video: from the
            // second iteration the camera moves by 0.2–0.3 px (a third of its σ) back and
            // forth as the matches change, up to the default cap of 10 (5 min 26 s in all,
            // 2026-12-04). Five keep CI within its 45 minutes.
            "--max-iterations",
            "5",
        ],
    );
    // The chosen frames, their neighbours and the sidecar are where calibrate said.
    let sidecar =
        pipemeasure::io::sidecar::FramesSidecar::read(&tmp.join("chosen/frames.json")).unwrap();
    assert!(
        sidecar.frames.len() >= 40,
        "{} frames",
        sidecar.frames.len()
    );
    // The choice took the least moving frames: their mean motion (choice.json, measured by
    // the flow) is below that of plain 1 fps extraction from the same measures.
    let choice: pipemeasure::video::ChoiceRecord =
        serde_json::from_str(&std::fs::read_to_string(tmp.join("chosen/choice.json")).unwrap())
            .unwrap();
    assert!(
        choice
            .frames
            .iter()
            .filter(|f| f.chosen)
            .all(|f| f.motion_px.is_some())
    );
    let (chosen, plain) = choice.mean_motion_px();
    eprintln!("mean motion: chosen {chosen:.2} px/frame, plain 1 fps {plain:.2}");
    assert!(chosen < plain);
    let boofcv = boofcv_dot_calibration();
    let size = (640, 480);
    let d_every = projection_difference_rotated(&every.intrinsics, &boofcv, size);
    let d_video = projection_difference_rotated(&video.intrinsics, &boofcv, size);
    eprintln!(
        "against BoofCV's dot calibration after the best rotation: every 15th frame {:.2} px max ({:.2} RMS), --video {:.2} px max ({:.2} RMS); readout {:?}",
        d_every.map.max, d_every.map.rms, d_video.map.max, d_video.map.rms, video.rolling_shutter
    );
    // `--video` agrees with BoofCV at least as well as every-15th-frame
    // extraction. Measured 2026-12-04: every 15th frame 4.64–4.69 px, --video 3.21 px (the
    // rolling shutter kept, readout 18.8 ± 4.8 ms). Before the neighbours' motions could start
    // from rest (`calibrate::selection::estimate_readout_time`), the selected motions missed
    // the neighbours by 10² to 10⁶ px, the rolling shutter was left out and --video gave
    // 7.24–7.36 px on these frames.
    assert!(
        d_video.map.max <= d_every.map.max,
        "--video {:.2} px, every 15th frame {:.2} px",
        d_video.map.max,
        d_every.map.max
    );
    assert!(
        video.rolling_shutter.is_some(),
        "the rolling shutter was left out"
    );
}
