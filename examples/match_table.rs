//! Paper Table II on simulated labs: precision, recall, accuracy and F-measure of Algorithm 2
//! without robust triangulation, with it, and with it plus Algorithm-3 centres, and the
//! corrected-centre accuracy.
//!
//! `cargo run --release --example match_table -- [--frames N] [--width W] [--seed S] [--devices p30,iphone11,s10]`
//! (defaults: 90 frames of 3840x2160 per device preset, seed 1: the paper's 270 frames).

use std::time::Instant;

use pipemeasure::calibrate::matching::MatchConfig;
use pipemeasure::experiments::matching::{Scenario, centre_scores, prepare, run, score};
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::simulate::SimulateOptions;

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|k| args.get(k + 1))
        .cloned()
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().collect();
    let frames: usize = arg(&args, "--frames")
        .map_or(Ok(90), |s| s.parse())
        .map_err(|e| format!("--frames: {e}"))?;
    let width: u32 = arg(&args, "--width")
        .map_or(Ok(3840), |s| s.parse())
        .map_err(|e| format!("--width: {e}"))?;
    let seed: u64 = arg(&args, "--seed")
        .map_or(Ok(1), |s| s.parse())
        .map_err(|e| format!("--seed: {e}"))?;
    let devices = arg(&args, "--devices").unwrap_or_else(|| "p30,iphone11,s10".into());
    let settings: [(&str, MatchConfig); 3] = [
        (
            "Algorithm 2 without robust triangulation",
            MatchConfig {
                robust_triangulation: false,
                correct_before_triangulation: false,
                correct_centres: false,
                ..MatchConfig::default()
            },
        ),
        (
            "Algorithm 2 with robust triangulation",
            MatchConfig {
                correct_before_triangulation: false,
                correct_centres: false,
                ..MatchConfig::default()
            },
        ),
        (
            "Algorithm 2 with robust triangulation and corrected centres",
            MatchConfig::default(),
        ),
    ];
    let mut totals =
        vec![pipemeasure::experiments::matching::MatchScores::default(); settings.len()];
    for device in devices.split(',') {
        let scenario = Scenario {
            options: SimulateOptions {
                device: device.into(),
                width,
                height: width * 9 / 16,
                seed,
                ..SimulateOptions::default()
            },
            lab: LabConfig {
                frames,
                ..LabConfig::default()
            },
            ..Scenario::default()
        };
        let t = Instant::now();
        let prepared = prepare(&scenario)?;
        let detections: usize = prepared.observations.iter().map(Vec::len).sum();
        eprintln!(
            "{device}: {frames} frames, {detections} detections, {} pairs, Algorithm 1 σ {:.2} px, prepared in {:.1} s",
            prepared.algorithm1.pairs.len(),
            prepared.algorithm1.reprojection_sigma,
            t.elapsed().as_secs_f64()
        );
        for (k, (name, config)) in settings.iter().enumerate() {
            let t = Instant::now();
            let m = run(&prepared, config);
            let secs = t.elapsed().as_secs_f64();
            let s = score(&prepared, &m);
            let c = centre_scores(&prepared, &m, 0.5);
            println!(
                "{device} | {name} | tracks {} | TP {} FP {} FN {} | P {:.4} R {:.4} A {:.6} F {:.4} | mixed {} | ecc>0.5: {} views fitted {:.3} px out {:.4} px ({:.1}x) | {secs:.2} s",
                s.tracks,
                s.tp,
                s.fp,
                s.fn_,
                s.precision,
                s.recall,
                s.accuracy,
                s.f_measure,
                s.mixed_tracks,
                c.views,
                c.fitted_rms_px,
                c.corrected_rms_px,
                c.improvement
            );
            let t = &mut totals[k];
            t.tp += s.tp;
            t.fp += s.fp;
            t.fn_ += s.fn_;
            t.tn += s.tn;
        }
    }
    println!(
        "\n| Setting | TP | FP | FN | Precision | Recall | Accuracy | F-measure |\n|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    for ((name, _), t) in settings.iter().zip(&totals) {
        let p = t.tp as f64 / (t.tp + t.fp).max(1) as f64;
        let r = t.tp as f64 / (t.tp + t.fn_).max(1) as f64;
        let a = (t.tp + t.tn) as f64 / (t.tp + t.tn + t.fp + t.fn_).max(1) as f64;
        let f = if p + r > 0.0 {
            2.0 * p * r / (p + r)
        } else {
            0.0
        };
        println!(
            "| {name} | {} | {} | {} | {:.2} % | {:.2} % | {:.4} % | {:.2} % |",
            t.tp,
            t.fp,
            t.fn_,
            100.0 * p,
            100.0 * r,
            100.0 * a,
            100.0 * f
        );
    }
    Ok(())
}
