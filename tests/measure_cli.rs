//! The main command, `pipemeasure --device NAME CLOUD`, on a simulated site: the pipe of
//! interest against the simulator's truth, the TLS reference, and the bad inputs a site engineer
//! will meet (each a clear error naming what is wrong, with nothing written).
#![allow(clippy::unwrap_used)]

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use common::pipemeasure_with_profiles as run;
use pipemeasure::profile::Profile;
use pipemeasure::sim::devices::{P30, preset_camera};

/// Site coordinates: the TLS list and scan carry a large offset.
const OFFSET: [f64; 3] = [500_000.0, 5_600_000.0, 100.0];

/// A 960×540, 20-frame p30 site in `dir/site`; returns the truth's pipe of interest (radius,
/// axis point in TLS coordinates).
fn simulate_site(dir: &Path) -> (f64, [f64; 3]) {
    let offset = format!("{},{},{}", OFFSET[0], OFFSET[1], OFFSET[2]);
    common::simulate(
        dir,
        "site",
        &[
            "site",
            "--like",
            "p30",
            "--width",
            "960",
            "--frames",
            "20",
            "--tls-offset",
            &offset,
        ],
    );
    let truth: serde_json::Value = common::read_json(&dir.join("site/truth.json"));
    let pipe = truth["pipes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["of_interest"].as_bool().unwrap())
        .unwrap();
    let a = pipe["axis_point"].as_array().unwrap();
    let axis = [0, 1, 2].map(|k| a[k].as_f64().unwrap() + OFFSET[k]);
    (pipe["radius"].as_f64().unwrap(), axis)
}

#[test]
fn the_main_command_measures_the_pipe_of_interest_and_handles_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (radius, axis) = simulate_site(dir);
    let near = format!("{},{},{}", axis[0], axis[1], axis[2]);

    // The short form in the simulator's workspace: model, frames and targets found by default.
    let (code, stdout, stderr) = run(
        dir,
        &[
            "--device",
            "p30",
            "site/dense/fused.ply",
            "--near",
            &near,
            "--within",
            "0.4",
            "--tls-scan",
            "site/tls_scan.ply",
            "--json",
            "report.json",
            "--ply-out",
            "inliers.ply",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("pipe radius") && stdout.contains("TLS reference"),
        "{stdout}"
    );
    let report: serde_json::Value = common::read_json(&dir.join("report.json"));
    let r = report["radius_m"].as_f64().unwrap();
    let reference = report["reference_radius_m"].as_f64().unwrap();
    eprintln!(
        "measured {:.3} mm, TLS {:.3} mm, truth {:.3} mm",
        r * 1e3,
        reference * 1e3,
        radius * 1e3
    );
    assert!((r - radius).abs() < 1e-3, "radius {r} vs truth {radius}");
    assert!(
        (reference - radius).abs() < 0.5e-3,
        "TLS {reference} vs {radius}"
    );
    assert!((report["accuracy_m"].as_f64().unwrap() - (r - reference)).abs() < 1e-12);
    assert_eq!(report["frame"], "tls");
    assert_eq!(report["scale_method"], "similarity");
    assert!(report["scale_targets"].as_array().unwrap().len() >= 4);
    // The axis lies on the true axis, in TLS coordinates (1e6 m offsets), within what the frame
    // is known to: TLS targets with 1 mm noise per axis and SfM camera centres with 3 mm.
    let p: Vec<f64> = (0..3)
        .map(|k| report["axis"]["point"][k].as_f64().unwrap())
        .collect();
    let off_axis = ((p[1] - axis[1]).powi(2) + (p[2] - axis[2]).powi(2)).sqrt();
    assert!(off_axis < 5e-3, "axis {p:?} vs {axis:?}");
    let inliers = pipemeasure::io::ply::read(&dir.join("inliers.ply")).unwrap();
    assert_eq!(
        inliers.cloud.len(),
        report["inliers"].as_u64().unwrap() as usize
    );
    assert!(inliers.cloud.colors.is_some());

    // Two TLS targets (those seen in the most views, as the paper picks them): the paper's
    // scale, the association assumed and said so, the same radius.
    let ids: Vec<&str> = (0..2)
        .map(|k| report["two_target_ids"][k].as_str().unwrap())
        .collect();
    let ids = ids.join(",");
    let (code, stdout, stderr) = run(
        dir,
        &[
            "--device",
            "p30",
            "site/dense/fused.ply",
            "--tls-ids",
            &ids,
            "--json",
            "two.json",
            "--radius-min",
            "0.05",
            "--radius-max",
            "0.07",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("two targets") && stdout.contains("assumed"),
        "{stdout}"
    );
    let two: serde_json::Value = common::read_json(&dir.join("two.json"));
    assert_eq!(two["frame"], "scaled");
    let r2 = two["radius_m"].as_f64().unwrap();
    assert!(
        (r2 - radius).abs() < 1e-3,
        "two-target radius {r2} vs truth {radius}"
    );

    // Bad input, each a clear error and nothing written.
    let expect_error = |args: &[&str], code: i32, needle: &str| {
        let (c, _, stderr) = run(dir, args);
        assert_eq!(c, code, "{args:?}: {stderr}");
        assert!(
            stderr.contains(needle),
            "{args:?}: expected `{needle}` in {stderr}"
        );
    };
    let cloud = "site/dense/fused.ply";
    expect_error(
        &["--device", "p30", cloud, "--tls-ids", "1"],
        1,
        "at least two",
    );
    expect_error(
        &[
            "--device",
            "p30",
            cloud,
            "--tls-ids",
            "1,99",
            "--json",
            "x.json",
        ],
        1,
        "`99` is not in",
    );
    assert!(!dir.join("x.json").exists());
    expect_error(&[cloud], 1, "--device");
    expect_error(
        &["--device", "p30", cloud, "--sfm", "nowhere"],
        1,
        "--sfm nowhere: not found",
    );
    // A profile of another device (4:3 frames) is refused.
    let cam = preset_camera(&P30, 800, 600);
    let odd = dir.join("odd.json");
    Profile::uncalibrated("odd", &cam, BTreeMap::new())
        .write(&odd, false)
        .unwrap();
    expect_error(
        &["--device", odd.to_str().unwrap(), cloud],
        1,
        "another aspect ratio",
    );
    // Empty, all-NaN and cylinder-free clouds.
    let write = |name: &str, body: &str| -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, body).unwrap();
        p
    };
    let header = |n: usize| {
        format!(
            "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
        )
    };
    write("empty.ply", &header(0));
    expect_error(
        &["--scale", "1", "empty.ply"],
        1,
        "empty.ply: no finite points",
    );
    write("nan.ply", &format!("{}nan nan nan\nnan 1 2\n", header(2)));
    expect_error(&["--scale", "1", "nan.ply"], 1, "nan.ply: no finite points");
    let plane: String = (0..2500)
        .map(|k| format!("{} {} 0\n", (k % 50) as f64 * 0.01, (k / 50) as f64 * 0.01))
        .collect();
    write("plane.ply", &format!("{}{plane}", header(2500)));
    expect_error(&["--scale", "1", "plane.ply"], 3, "no pipe found");
    // An option value out of range is a usage error naming the option.
    expect_error(
        &["--scale=-2", "plane.ply"],
        2,
        "'-2' for '--scale <SCALE>'",
    );
    // Main-command options with a subcommand are a usage error.
    expect_error(&["--device", "p30", "profile", "list"], 2, "main command");
}
