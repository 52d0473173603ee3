//! Solves a "Bundle Adjustment in the Large" problem and prints one JSON line:
//! `{"initial_cost","final_cost","iterations","seconds"}` (cost = ½·Σ squared residuals).
//!
//! ```text
//! cargo run --release --example bal -- ../shared/data/bal/problem-49-7776-pre.txt [--threads N]
//! ```
//!
//! The settings mirror Ceres' defaults for the comparison in the README: Levenberg–Marquardt,
//! Schur complement, squared loss, function tolerance 1e-6. The time covers the solve only
//! (not reading the file).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use pipemeasure::adjust::{AdjustConfig, bundle_adjust, problem_from_bal};
use pipemeasure::io::bal::read_bal;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let mut file: Option<PathBuf> = None;
    let mut threads = 0usize;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--threads" => {
                let v = args
                    .next()
                    .ok_or_else(|| anyhow::anyhow!("--threads needs a value"))?;
                threads = v
                    .parse()
                    .map_err(|_| anyhow::anyhow!("--threads {v}: not a number"))?;
            }
            _ if file.is_none() => file = Some(PathBuf::from(a)),
            _ => anyhow::bail!("usage: bal FILE [--threads N]"),
        }
    }
    let file = file.ok_or_else(|| anyhow::anyhow!("usage: bal FILE [--threads N]"))?;
    let bal = read_bal(&file)?;
    let mut problem = problem_from_bal(&bal)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let config = AdjustConfig::default();
    let start = Instant::now();
    let summary = pool.install(|| bundle_adjust(&mut problem, &config))?;
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "{}",
        serde_json::json!({
            "initial_cost": summary.initial_cost,
            "final_cost": summary.final_cost,
            "iterations": summary.iterations,
            "seconds": seconds,
        })
    );
    eprintln!(
        "termination {:?}, {} successful steps, {} observations",
        summary.termination, summary.successful_steps, summary.observations_used
    );
    Ok(())
}
