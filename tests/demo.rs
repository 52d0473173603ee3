//! `pipemeasure demo` on a tiny configuration (960×540, 30 lab frames, 20 site frames): the
//! whole product — simulate a lab, calibrate, simulate a site, measure — against the truth.
#![allow(clippy::unwrap_used)]

mod common;

use common::pipemeasure;

#[test]
fn the_demo_calibrates_and_measures_the_pipe_within_a_tenth_of_a_millimetre() {
    let tmp = tempfile::tempdir().unwrap();
    let (code, stdout, stderr) = pipemeasure(
        tmp.path(),
        &[
            "demo",
            "--out",
            "demo",
            "--width",
            "960",
            "--lab-frames",
            "30",
            "--site-frames",
            "20",
            "--quiet",
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("pre-calibration") && stdout.contains("in situ"),
        "{stdout}"
    );
    let dir = tmp.path().join("demo");
    let read = |name: &str| -> serde_json::Value { common::read_json(&dir.join(name)) };
    let truth = read("site/truth.json");
    let radius = truth["pipes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["of_interest"].as_bool().unwrap())
        .unwrap()["radius"]
        .as_f64()
        .unwrap();
    // The main command's measurement with the new profile: the poses re-adjusted to it and the
    // cloud re-triangulated, within 0.1 mm and 3σ of the truth; the σ includes the poses'.
    let m = read("measurement.json");
    let measured = m["radius_m"].as_f64().unwrap();
    let sigma = m["radius_std_m"].as_f64().unwrap();
    assert_eq!(m["cloud_source"], "retriangulated");
    assert!(m["pose_radius_std_m"].as_f64().unwrap() > 0.0, "{m}");
    assert!(
        (measured - radius).abs() < 1e-4 && (measured - radius).abs() < 3.0 * sigma,
        "{measured} ± {sigma} vs {radius}"
    );
    let (before, after) = (
        m["reprojection_sigma_before_px"].as_f64().unwrap(),
        m["reprojection_sigma_after_px"].as_f64().unwrap(),
    );
    assert!(after < 0.55 && before > after, "σ {before} → {after} px");
    // Both methods of the comparison, and the calibration itself.
    let demo = read("demo.json");
    for row in demo["site"]["rows"].as_array().unwrap() {
        let r = row["radius_m"].as_f64().unwrap();
        assert!(
            (r - radius).abs() < 1e-3,
            "{}: {r} vs {radius}",
            row["method"]
        );
    }
    let lab = read("lab/truth.json");
    let c_true = lab["camera"]["intrinsics"]["c"].as_f64().unwrap();
    let c = read("demo-p30.json")["intrinsics"]["c"].as_f64().unwrap();
    assert!((c / c_true - 1.0).abs() < 1e-3, "c {c} vs {c_true}");
    assert!(dir.join("pipe-inliers.ply").is_file());
    assert!(dir.join("calibration-report/report.md").is_file());
}
