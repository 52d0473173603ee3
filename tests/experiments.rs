//! `pipemeasure experiments --quick`: the paper's four experiments (and the video variant of
//! Table III) end to end on simulated data, each output file present and each result checked
//! against what the simulator's exact geometry implies.
#![allow(clippy::unwrap_used)]

mod common;

use common::pipemeasure;
use serde_json::Value;

/// Runs `pipemeasure experiments --quick --out ex --quiet` with `extra` options and the
/// repository's calibrations in a fresh folder; returns the folder, the exit code and stdout.
fn quick_experiments(extra: &[&str]) -> (tempfile::TempDir, i32, String, String) {
    let tmp = tempfile::tempdir().unwrap();
    let mut args = vec!["experiments", "--quick", "--out", "ex", "--quiet"];
    args.extend_from_slice(extra);
    let (code, stdout, stderr) = pipemeasure(
        tmp.path(),
        &args,
        &[("PIPEMEASURE_CALIBRATIONS", common::CALIBRATIONS)],
    );
    (tmp, code, stdout, stderr)
}

/// The JSON file `name` of an experiments folder.
fn read_json(dir: &std::path::Path, name: &str) -> Value {
    common::read_json(&dir.join(name))
}

#[test]
fn the_quick_experiments_write_every_table_and_figure_and_meet_the_goals() {
    let (tmp, code, stdout, stderr) = quick_experiments(&[]);
    assert_eq!(code, 0, "{stderr}");
    let dir = tmp.path().join("ex");
    for name in [
        "README.md",
        "fig7.md",
        "fig7.svg",
        "fig8.md",
        "fig8.svg",
        "table2.md",
        "table3.md",
    ] {
        let text = std::fs::read_to_string(dir.join(name)).unwrap();
        assert!(!text.is_empty(), "{name} is empty");
        if name.ends_with(".svg") {
            assert!(text.starts_with("<svg"), "{name}");
        }
    }
    assert!(stdout.contains("Table III"), "{stdout}");
    let read = |name: &str| read_json(&dir, name);

    // Fig. 7: with exact poses the eccentricity is the fitted centres' whole error, and
    // Algorithm 3 removes it: from three views on, 100x smaller.
    for row in read("fig7.json")["rows"].as_array().unwrap() {
        let (fitted, corrected) = (
            row["fitted_exact_mm"].as_f64().unwrap(),
            row["corrected_exact_mm"].as_f64().unwrap(),
        );
        if row["views"].as_u64().unwrap() >= 3 {
            assert!(corrected < fitted / 100.0, "{row}");
        }
    }
    // Fig. 8: Algorithm 3's eccentricity is within 5 % of the true one on average.
    let fig8 = read("fig8.json");
    let mean_true = fig8["mean_true_px"].as_f64().unwrap();
    assert!(fig8["mean_algorithm3_error_px"].as_f64().unwrap() < 0.05 * mean_true);

    // Table II: robust triangulation leaves no mismatch, and every setting beats the paper's F.
    let table2 = read("table2.json");
    let rows = table2["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 3);
    for (k, row) in rows.iter().enumerate() {
        let total = &row["total"];
        assert!(
            total["f_measure"].as_f64().unwrap() >= row["paper_f_measure"].as_f64().unwrap(),
            "{row}"
        );
        if k > 0 {
            assert_eq!(total["fp"].as_u64().unwrap(), 0, "{row}");
        }
    }

    // Table III: every preset's pipe, both methods, within 0.5 mm of the simulator's radius.
    let sites = read("table3.json");
    let sites = sites.as_array().unwrap();
    assert_eq!(sites.len(), 3);
    for site in sites {
        let truth = site["truth_radius_m"].as_f64().unwrap();
        let rows = site["rows"].as_array().unwrap();
        assert_eq!(rows.len(), 2);
        for row in rows {
            let r = row["radius_m"].as_f64().unwrap();
            assert!((r - truth).abs() < 0.5e-3, "{}: {row}", site["device"]);
        }
    }
}

#[test]
fn an_unknown_experiment_is_a_usage_error_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let (code, _, stderr) = pipemeasure(
        tmp.path(),
        &["experiments", "--only", "table9", "--out", "ex"],
        &[],
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("table9") && stderr.contains("table3"),
        "{stderr}"
    );
    assert!(!tmp.path().join("ex").exists());
}

/// `experiments --quick --only video-sites`: the three presets' sites filmed as hand-held
/// video; Table III's acceptance for video: every pre-calibration row (with and without the
/// rows' poses) within 0.2 mm of the simulator's radius. The default run leaves it out.
#[test]
fn the_video_table_iii_measures_every_preset_within_its_goal() {
    let (tmp, code, stdout, stderr) = quick_experiments(&["--only", "video-sites"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("Table III, video"), "{stdout}");
    let dir = tmp.path().join("ex");
    assert!(!dir.join("table3.json").exists());
    let sites = read_json(&dir, "video.json");
    let sites = sites.as_array().unwrap();
    assert_eq!(sites.len(), 3);
    for site in sites {
        let truth = site["truth_radius_m"].as_f64().unwrap();
        let rows = site["rows"].as_array().unwrap();
        let methods: Vec<&str> = rows.iter().map(|r| r["method"].as_str().unwrap()).collect();
        assert_eq!(
            methods,
            ["PreCalibration", "PreCalibrationRowPoses", "InSitu"],
            "{}",
            site["device"]
        );
        for row in &rows[..2] {
            let r = row["radius_m"].as_f64().unwrap();
            assert!((r - truth).abs() < 0.2e-3, "{}: {row}", site["device"]);
        }
    }
}
