//! The calibration loop on simulated labs of each device preset, scored against the truth:
//! the README's calibration table.
//!
//! ```text
//! cargo run --release --example calibration_table [-- --width 3840 --frames 90 --seed 1 --device p30]
//! ```

use pipemeasure::calibrate::pipeline::CalibrateConfig;
use pipemeasure::experiments::calibration::{prepare, run, score};
use pipemeasure::experiments::matching::Scenario;
use pipemeasure::sim::devices::PRESETS;

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn main() {
    let width: u32 = arg("--width").and_then(|v| v.parse().ok()).unwrap_or(3840);
    let frames: usize = arg("--frames").and_then(|v| v.parse().ok()).unwrap_or(90);
    let seed: u64 = arg("--seed").and_then(|v| v.parse().ok()).unwrap_or(1);
    let only = arg("--device");
    for preset in PRESETS {
        if only.as_deref().is_some_and(|d| d != preset.name) {
            continue;
        }
        let mut scenario = Scenario::default();
        scenario.options.device = preset.name.to_string();
        scenario.options.width = width;
        scenario.options.height = width * 9 / 16;
        scenario.options.seed = seed;
        scenario.lab.frames = frames;
        let start = std::time::Instant::now();
        let s = match prepare(&scenario) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{}: {e}", preset.name);
                std::process::exit(1);
            }
        };
        let prepared = start.elapsed().as_secs_f64();
        let cal = match run(&s, &CalibrateConfig::default(), &|m| eprintln!("  {m}")) {
            Ok(c) => c,
            Err(e) => {
                eprintln!("{}: {e}", preset.name);
                std::process::exit(1);
            }
        };
        let seconds = start.elapsed().as_secs_f64() - prepared;
        let sc = score(&s, &cal);
        println!(
            "\n### {} ({}x{}, {} frames, seed {seed}): {} targets, {} observations, σ0 {:.4} px, RMS {:.4} px, {} iterations, {seconds:.1} s (+{prepared:.1} s simulation)",
            preset.label,
            width,
            width * 9 / 16,
            frames,
            sc.targets,
            sc.observations,
            sc.sigma0,
            sc.residual_rms_px,
            sc.iterations
        );
        println!(
            "| term | truth | estimate | σ | error / σ |\n| --- | ---: | ---: | ---: | ---: |"
        );
        for (name, t, e, s) in &sc.terms {
            let z = if *s > 0.0 {
                format!("{:.2}", (e - t) / s)
            } else {
                "fixed".into()
            };
            println!("| {name} | {t:.6} | {e:.6} | {s:.2e} | {z} |");
        }
        println!(
            "selected: {:?}; truth's terms above 0.1 px: {:?}; largest distortion difference over the frame: {:.4} px",
            sc.selected, sc.significant_truth_terms, sc.max_distortion_difference_px
        );
        for w in &cal.warnings {
            println!("warning: {w}");
        }
    }
}
