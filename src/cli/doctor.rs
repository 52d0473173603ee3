//! `pipemeasure doctor`: what the product will need before a long run — COLMAP (and whether
//! it can do dense stereo), ffmpeg and ffprobe, the profile folders and the profiles in them,
//! the cores and the memory — with the install command for anything missing.

use anyhow::Result;
use pipemeasure::io::tools::{Tool, machine, probe};
use pipemeasure::profile::{PRESETS, devices_in, search_folders};

/// Arguments of `doctor`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Gigabytes, for the memory line.
fn gb(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 30) as f64
}

/// Prints the checks; an error (exit code 1) naming what is missing when a program is.
pub fn run(_: &Args) -> Result<()> {
    outln!("pipemeasure {}", super::VERSION);
    let mut missing = Vec::new();
    for tool in Tool::ALL {
        let status = probe(tool);
        match &status.version {
            Some(v) => {
                let cuda = match status.cuda {
                    Some(false) => {
                        " — built without CUDA: sparse reconstruction only, no dense stereo (the main command takes a dense cloud made elsewhere)"
                    }
                    Some(true) => " — with CUDA: dense stereo available",
                    None => "",
                };
                outln!("ok       {:<8} {v}{cuda}", tool.program());
            }
            None => {
                outln!(
                    "MISSING  {:<8} needed for {}; install: {}",
                    tool.program(),
                    tool.needed_for(),
                    tool.install()
                );
                missing.push(tool.program());
            }
        }
    }
    outln!("profiles, searched in this order:");
    for folder in search_folders() {
        let names = devices_in(&folder.path);
        outln!(
            "         {} ({}): {}",
            folder.path.display(),
            folder.origin,
            if !folder.path.is_dir() {
                "no such folder".to_string()
            } else if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            }
        );
    }
    let presets: Vec<&str> = PRESETS.iter().map(|(n, _)| *n).collect();
    outln!("         built in: {}", presets.join(", "));
    let m = machine();
    let memory = match (m.memory_total, m.memory_available) {
        (Some(t), Some(a)) => format!("{:.1} GB memory, {:.1} GB available", gb(t), gb(a)),
        (Some(t), None) => format!("{:.1} GB memory", gb(t)),
        _ => "memory unknown".to_string(),
    };
    outln!("machine  {} cores, {memory}", m.cores);
    if !missing.is_empty() {
        anyhow::bail!("missing: {} (install as shown above)", missing.join(", "));
    }
    Ok(())
}
