//! The README's detection tables: accuracy of `pipemeasure detect` on simulated labs against
//! the simulator's truth.
//!
//! * `cargo run --release --example detect_table` — how recall, precision and centre error
//!   change with noise, blur, JPEG quality and target size (1920×1080, 10 frames per row,
//!   seed 7).
//! * `cargo run --release --example detect_table -- --acceptance` — the full 90-frame 4K labs
//!   of the three device presets (seed 1) at default noise and blur.
//!
//! Targets with a semi-minor axis ≥ 4 px must be found; see `experiments::detection`.

use pipemeasure::experiments::detection::{EvalConfig, EvalResult, evaluate};
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::render::RenderConfig;
use pipemeasure::sim::simulate::SimulateOptions;

fn row(label: &str, r: &EvalResult) {
    println!(
        "| {label} | {} | {:.2} % | {:.2} % | {:.4} | {:.4} |",
        r.required,
        100.0 * r.recall,
        100.0 * r.precision,
        r.centre_rms_px,
        r.centre_p99_px
    );
}

fn run(device: &str, width: u32, frames: usize, seed: u64, render: RenderConfig) -> EvalResult {
    let cfg = EvalConfig {
        options: SimulateOptions {
            device: device.into(),
            width,
            height: width * 9 / 16,
            seed,
            render,
            ..Default::default()
        },
        lab: LabConfig {
            frames,
            ..Default::default()
        },
        detect: Default::default(),
        min_semi_minor_px: pipemeasure::detect::MIN_SEMI_MINOR_TO_MEASURE_PX,
    };
    evaluate(&cfg).unwrap_or_else(|e| panic!("{e}"))
}

fn header(first: &str) {
    println!(
        "| {first} | targets to find | recall | precision | centre RMS (px) | centre p99 (px) |"
    );
    println!("| --- | --- | --- | --- | --- | --- |");
}

fn main() {
    if std::env::args().any(|a| a == "--acceptance") {
        header("device (90 frames, 3840×2160)");
        let mut all = EvalResult::default();
        for device in ["p30", "iphone11", "s10"] {
            let r = run(device, 3840, 90, 1, RenderConfig::default());
            row(device, &r);
            all.required += r.required;
            all.found += r.found;
            all.false_positives += r.false_positives;
            all.errors.extend(r.errors.iter().copied());
            all.semi_minor.extend(r.semi_minor.iter().copied());
        }
        all.recall = all.found as f64 / all.required as f64;
        all.precision = all.found as f64 / (all.found + all.false_positives) as f64;
        let mut e = all.errors.clone();
        e.sort_by(f64::total_cmp);
        all.centre_rms_px = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
        all.centre_p99_px = e[(e.len() as f64 * 0.99).ceil() as usize - 1];
        row("all 270 frames", &all);
        println!();
        println!(
            "| semi-minor axis (all 270 frames) | targets found | centre RMS (px) | centre p99 (px) |"
        );
        println!("| --- | --- | --- | --- |");
        for (lo, hi) in [
            (4.0, 6.0),
            (6.0, 10.0),
            (10.0, 20.0),
            (20.0, 40.0),
            (40.0, 1e9),
        ] {
            let mut v: Vec<f64> = all
                .errors
                .iter()
                .zip(&all.semi_minor)
                .filter(|(_, b)| **b >= lo && **b < hi)
                .map(|(e, _)| *e)
                .collect();
            if v.is_empty() {
                continue;
            }
            v.sort_by(f64::total_cmp);
            let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
            let p99 = v[(v.len() as f64 * 0.99).ceil() as usize - 1];
            let label = if hi > 1e8 {
                format!("≥ {lo} px")
            } else {
                format!("{lo}–{hi} px")
            };
            println!("| {label} | {} | {rms:.4} | {p99:.4} |", v.len());
        }
        return;
    }
    let base = RenderConfig::default();
    header("setting (1920×1080, 10 frames)");
    row(
        "default (read noise 1 DN, shot 0.02, blur σ 0.7 px, PNG)",
        &run("p30", 1920, 10, 7, base.clone()),
    );
    for k in [0.0, 2.0, 4.0, 8.0] {
        let r = run(
            "p30",
            1920,
            10,
            7,
            RenderConfig {
                read_noise_dn: base.read_noise_dn * k,
                shot_noise: base.shot_noise * k,
                ..base.clone()
            },
        );
        row(&format!("noise × {k}"), &r);
    }
    for blur in [0.0, 1.2, 2.0] {
        row(
            &format!("blur σ {blur} px"),
            &run(
                "p30",
                1920,
                10,
                7,
                RenderConfig {
                    blur_sigma_px: blur,
                    ..base.clone()
                },
            ),
        );
    }
    for q in [95u8, 85, 70, 50] {
        row(
            &format!("JPEG quality {q}"),
            &run(
                "p30",
                1920,
                10,
                7,
                RenderConfig {
                    jpeg_quality: Some(q),
                    ..base.clone()
                },
            ),
        );
    }
    for w in [960u32, 3840] {
        row(
            &format!("frame width {w} (targets ×{:.1})", f64::from(w) / 1920.0),
            &run("p30", w, 10, 7, base.clone()),
        );
    }
}
