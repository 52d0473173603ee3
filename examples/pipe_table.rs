//! The paper's Table III on simulated sites: for each device preset, the pipe of interest
//! measured with the device profile from `calibrations/` (pre-calibration) and with COLMAP-style
//! in-situ radial self-calibration, against the truth and the TLS scan.
//!
//! ```text
//! cargo run --release --example pipe_table [-- --width 1920 --frames 60 --seed 1 --device p30 --out DIR]
//! ```
//!
//! Each site is simulated (rendered frames, SfM stand-in, dense observations, TLS) into
//! `DIR/site_<device>` (default: a temporary folder), then measured twice. Prints the Markdown
//! table and writes `DIR/table3.json` when `--out` is given.

use std::path::PathBuf;

use pipemeasure::experiments::pipe::{SiteResult, run_site};
use pipemeasure::profile::load_device;
use pipemeasure::sim::devices::PRESETS;
use pipemeasure::sim::simulate::{SimulateOptions, SiteOptions, simulate_site};

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn fail(what: &str, e: impl std::fmt::Display) -> ! {
    eprintln!("{what}: {e}");
    std::process::exit(1);
}

fn main() {
    let width: u32 = arg("--width").and_then(|v| v.parse().ok()).unwrap_or(1920);
    let frames: usize = arg("--frames").and_then(|v| v.parse().ok()).unwrap_or(60);
    let seed: u64 = arg("--seed").and_then(|v| v.parse().ok()).unwrap_or(1);
    let only = arg("--device");
    let tmp = tempfile::tempdir().unwrap_or_else(|e| fail("temporary folder", e));
    let out: PathBuf = arg("--out").map_or_else(|| tmp.path().to_path_buf(), PathBuf::from);
    let mut results: Vec<SiteResult> = Vec::new();
    for preset in PRESETS {
        if only.as_deref().is_some_and(|d| d != preset.name) {
            continue;
        }
        let options = SimulateOptions {
            device: preset.name.to_string(),
            width,
            height: width * 9 / 16,
            seed,
            command: format!("examples/pipe_table --width {width} --frames {frames} --seed {seed}"),
            ..SimulateOptions::default()
        };
        let mut site = SiteOptions::default();
        site.site.frames = frames;
        site.tls.offset = [500_000.0, 5_600_000.0, 100.0];
        let dir = out.join(format!("site_{}", preset.name));
        let start = std::time::Instant::now();
        eprintln!(
            "{}: simulating the site into {}",
            preset.name,
            dir.display()
        );
        if let Err(e) = simulate_site(&options, &site, &dir, &|_| {}) {
            fail(preset.name, e);
        }
        let simulated = start.elapsed().as_secs_f64();
        let (_, profile) = load_device(preset.name).unwrap_or_else(|e| fail(preset.name, e));
        let result = run_site(&dir, &profile.camera(), &|m| eprintln!("  {m}"))
            .unwrap_or_else(|e| fail(preset.name, e));
        eprintln!(
            "  {:.1} s simulation, {:.1} s measurement",
            simulated,
            start.elapsed().as_secs_f64() - simulated
        );
        results.push(result);
    }
    println!(
        "\n| device | method | radius (mm) | accuracy vs truth (mm) | accuracy vs TLS (mm) | RMSE (mm) | inliers | scale error |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for r in &results {
        for row in &r.rows {
            println!(
                "| {} | {} | {:.2} ± {:.2} | {:+.2} | {:+.2} | {:.2} | {} | {:+.3} % |",
                r.device,
                row.method.name(),
                row.radius_m * 1e3,
                row.radius_std_m * 1e3,
                row.accuracy_m * 1e3,
                row.tls_accuracy_m * 1e3,
                row.rmse_m * 1e3,
                row.inliers,
                100.0 * row.scale_error
            );
        }
    }
    for r in &results {
        println!(
            "\n{}: truth {:.2} mm, TLS fit {:.2} mm, {} frames {}x{}",
            r.device,
            r.truth_radius_m * 1e3,
            r.tls_radius_m * 1e3,
            r.frames,
            r.image_size.0,
            r.image_size.1
        );
    }
    if arg("--out").is_some() {
        let path = out.join("table3.json");
        let json = serde_json::to_string_pretty(&results).unwrap_or_else(|e| fail("json", e));
        pipemeasure::io::atomic::write_bytes_atomic(&path, json.as_bytes())
            .unwrap_or_else(|e| fail("table3.json", e));
        println!("\nwritten to {}", path.display());
    }
}
