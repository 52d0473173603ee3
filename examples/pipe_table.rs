//! The paper's Table III on simulated sites: for each device preset, the pipe of interest
//! measured with the device profile from `calibrations/` (pre-calibration) and with COLMAP-style
//! in-situ radial self-calibration, against the truth and the TLS scan
//! (`pipemeasure::experiments::pipe::table3`; `pipemeasure experiments` runs it with the other
//! experiments).
//!
//! ```text
//! cargo run --release --example pipe_table [-- --width 1920 --frames 60 --seed 1 --device p30 --out DIR --video]
//! ```
//!
//! Each site is simulated into `DIR/site_<device>` (default: a temporary folder), then measured
//! twice (three times with `--video`: the sites filmed as hand-held video, the rows' poses as
//! the third method). Prints the Markdown table and writes `DIR/table3.json` when `--out` is
//! given.

use std::path::PathBuf;

use pipemeasure::experiments::PresetRuns;
use pipemeasure::experiments::pipe::{Table3Options, table3, table3_markdown};

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn parsed<T: std::str::FromStr>(name: &str, default: T) -> Result<T, String> {
    arg(name).map_or(Ok(default), |v| {
        v.parse().map_err(|_| format!("{name} {v}: not a number"))
    })
}

fn main() -> Result<(), String> {
    let defaults = Table3Options::default();
    let options = Table3Options {
        runs: PresetRuns {
            devices: arg("--device").map_or(defaults.runs.devices, |d| vec![d]),
            width: parsed("--width", defaults.runs.width)?,
            frames: parsed("--frames", defaults.runs.frames)?,
            seed: parsed("--seed", defaults.runs.seed)?,
        },
        video: std::env::args().any(|a| a == "--video"),
    };
    let tmp = tempfile::tempdir().map_err(|e| format!("temporary folder: {e}"))?;
    let out: PathBuf = arg("--out").map_or_else(|| tmp.path().to_path_buf(), PathBuf::from);
    let command = format!(
        "examples/pipe_table --width {} --frames {} --seed {}",
        options.runs.width, options.runs.frames, options.runs.seed
    );
    let results = table3(&options, &out, &command, &|m| eprintln!("{m}"))?;
    println!("\n{}", table3_markdown(&results));
    if arg("--out").is_some() {
        let path = out.join("table3.json");
        let json = serde_json::to_string_pretty(&results).map_err(|e| e.to_string())?;
        pipemeasure::io::atomic::write_bytes_atomic(&path, json.as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!("written to {}", path.display());
    }
    Ok(())
}
