//! Sites as other people's multi-view stereo clouds are, not as this project's simulator made
//! them until then: an independent renderer's site cloud (two capped pipes, the 2-inch one
//! filmed in front of a 6-inch one; a millimetre of noise at a millimetre's spacing, 2 %
//! outliers, in the SfM model's units) made the main command refuse the 2-inch pipe as "flat
//! faces" (its 16-NN normals 15° off radial) and measure the 6-inch one instead, with a σ of
//! 0.02 mm and no hint. Rebuilt here with `simulate site --layout two-pipes` and the dense
//! cloud's 3D error along the surface normal and along the viewing ray.
#![allow(clippy::unwrap_used)]

mod common;

use std::path::Path;

use common::{pipemeasure, pipemeasure_with_profiles as run};
use serde_json::Value;

/// Site coordinates: the TLS list and scan carry a large offset.
const OFFSET: [f64; 3] = [500_000.0, 5_600_000.0, 100.0];

/// The two-pipe site with `dense` (the dense cloud's options) in `dir/site`; returns its truth.
fn simulate(dir: &Path, seed: &str, dense: &[&str]) -> Value {
    let offset = format!("{},{},{}", OFFSET[0], OFFSET[1], OFFSET[2]);
    let mut args = vec![
        "simulate",
        "site",
        "--layout",
        "two-pipes",
        "--like",
        "p30",
        "--width",
        "1280",
        "--seed",
        seed,
        "--tls-offset",
        &offset,
        "--out",
        "site",
        "--quiet",
    ];
    args.extend_from_slice(dense);
    let (code, _, stderr) = pipemeasure(dir, &args, &[]);
    assert_eq!(code, 0, "{stderr}");
    common::read_json(&dir.join("site/truth.json"))
}

/// A truth pipe: (radius, axis point in TLS coordinates).
fn pipe(truth: &Value, name: &str) -> (f64, [f64; 3]) {
    let p = truth["pipes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == name)
        .unwrap();
    let a = &p["axis_point"];
    (
        p["radius"].as_f64().unwrap(),
        [0, 1, 2].map(|k| a[k].as_f64().unwrap() + OFFSET[k]),
    )
}

/// Distance of `point` from the horizontal (along x) axis through `axis`.
fn off_axis(point: &Value, axis: &[f64; 3]) -> f64 {
    let p = [1, 2].map(|k| point[k].as_f64().unwrap());
    (p[0] - axis[1]).hypot(p[1] - axis[2])
}

/// The main command without `--near` and `pipes` on the same cloud: the 2-inch pipe chosen by
/// the frames and measured within 0.1 mm and 3σ of the truth, the 6-inch one listed (within
/// 0.1 mm), both found once and nothing else; each segment's ends within 3 cm of its caps.
fn check(dir: &Path, truth: &Value) {
    let (r2, a2) = pipe(truth, "pipe_2in");
    let (r6, a6) = pipe(truth, "pipe_6in");
    let (code, stdout, stderr) = run(
        dir,
        &[
            "--device",
            "p30",
            "site/dense/fused.ply",
            "--json",
            "m.json",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("pipe of interest *"), "{stdout}");
    let m: Value = common::read_json(&dir.join("m.json"));
    let (r, sigma) = (
        m["radius_m"].as_f64().unwrap(),
        m["radius_std_m"].as_f64().unwrap(),
    );
    eprintln!(
        "2-inch: {:.3} ± {:.3} mm for {:.3} mm ({:+.3} mm, {:.2} σ); chosen by {}",
        r * 1e3,
        sigma * 1e3,
        r2 * 1e3,
        (r - r2) * 1e3,
        (r - r2) / sigma,
        m["pipe_of_interest"]
    );
    assert_eq!(m["pipe_of_interest"]["by"], "frames", "{stdout}");
    assert_eq!(m["pipe_of_interest"]["ambiguous"], false);
    assert!((r - r2).abs() < 0.1e-3, "{r} vs {r2}");
    assert!((r - r2).abs() < 3.0 * sigma, "{r} ± {sigma} vs {r2}");
    assert!(off_axis(&m["axis"]["point"], &a2) < 5e-3);
    let pipes = m["pipes"].as_array().unwrap();
    assert_eq!(pipes.len(), 2, "{stdout}");
    let six = pipes.iter().find(|p| p["of_interest"] == false).unwrap();
    let r6m = six["radius_m"].as_f64().unwrap();
    assert!((r6m - r6).abs() < 0.1e-3, "6-inch {r6m} vs {r6}");
    assert!(off_axis(&six["start"], &a6) < 5e-3 && off_axis(&six["end"], &a6) < 5e-3);

    // `pipes` on the same cloud: each once, at its caps.
    let (code, stdout, stderr) = run(
        dir,
        &[
            "pipes",
            "site/dense/fused.ply",
            "--device",
            "p30",
            "--json",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{stderr}");
    let network: Value = serde_json::from_str(&stdout).unwrap();
    let segments = network["segments"].as_array().unwrap();
    assert_eq!(segments.len(), 2, "{:#}", network["segments"]);
    let pipes = truth["pipes"].as_array().unwrap();
    for s in segments {
        let r = s["radius_m"].as_f64().unwrap();
        let t = pipes
            .iter()
            .min_by(|a, b| {
                let d = |p: &Value| (p["radius"].as_f64().unwrap() - r).abs();
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        let (tr, axis) = pipe(truth, t["name"].as_str().unwrap());
        assert!((r - tr).abs() < 0.1e-3, "{r} vs {tr}");
        let half = 0.5 * t["length"].as_f64().unwrap();
        let mut xs = [
            s["start"][0].as_f64().unwrap(),
            s["end"][0].as_f64().unwrap(),
        ];
        xs.sort_by(f64::total_cmp);
        let ends = [axis[0] - half, axis[0] + half];
        for (found, cap) in xs.iter().zip(ends) {
            assert!(
                (found - cap).abs() < 0.03,
                "{}: end at x {found:.3}, cap at {cap:.3}",
                t["name"]
            );
        }
    }
}

/// The renderer's cloud: 1 mm of noise along the surface normal at 1 mm spacing, 2 % outliers.
#[test]
fn the_filmed_pipe_is_measured_in_a_dense_noisy_cloud() {
    let tmp = tempfile::tempdir().unwrap();
    let truth = simulate(
        tmp.path(),
        "1",
        &[
            "--dense-point-noise",
            "1",
            "--dense-outliers",
            "0.02",
            "--dense-spacing",
            "1",
        ],
    );
    check(tmp.path(), &truth);
}

/// A depth map's error: 2 mm along each point's reference view's ray, 5 % outliers, 1.5 mm
/// spacing, another seed.
#[test]
fn the_filmed_pipe_is_measured_with_noise_along_the_viewing_rays() {
    let tmp = tempfile::tempdir().unwrap();
    let truth = simulate(
        tmp.path(),
        "2",
        &[
            "--dense-point-noise",
            "2",
            "--dense-noise-along",
            "ray",
            "--dense-outliers",
            "0.05",
            "--dense-spacing",
            "1.5",
        ],
    );
    check(tmp.path(), &truth);
}
