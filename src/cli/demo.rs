//! `pipemeasure demo [--out DIR] [--like p30]`: the whole product on simulated data, nothing
//! outside the crate needed (the SfM stand-in instead of COLMAP). It runs the very commands a
//! user runs — `simulate lab`, `calibrate`, `simulate site`, the main measuring command — and
//! then the Table III comparison of the new profile against in-situ radial self-calibration on
//! the same site, and prints a short table against the simulator's truth.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Parser;
use pipemeasure::camera::Term;
use pipemeasure::experiments::pipe::{SiteResult, run_site};
use pipemeasure::profile::Profile;
use pipemeasure::sim::truth::Truth;

use super::{Cli, Globals};

/// Arguments of `demo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder (created; an existing demo there is replaced).
    #[arg(long, default_value = "pipemeasure-demo")]
    out: PathBuf,
    /// Device preset to imitate: p30, iphone11 or s10.
    #[arg(long, default_value = "p30")]
    like: String,
    /// Frame width, 64–8192 (the height follows 16:9).
    #[arg(long, default_value_t = 1920, value_parser = clap::value_parser!(u32).range(64..=8192))]
    width: u32,
    /// Frames of the lab video.
    #[arg(long, default_value_t = 40)]
    lab_frames: usize,
    /// Frames of the site video.
    #[arg(long, default_value_t = 40)]
    site_frames: usize,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// Runs one pipemeasure command line through the same dispatcher as the binary.
fn step(what: &str, args: &[String], globals: Globals) -> Result<()> {
    if !globals.quiet {
        eprintln!("\n== {what}: pipemeasure {}", args.join(" "));
    }
    let mut argv = vec!["pipemeasure".to_string()];
    argv.extend_from_slice(args);
    if globals.quiet {
        argv.push("--quiet".into());
    }
    let cli = Cli::try_parse_from(&argv).with_context(|| format!("{what}: bad arguments"))?;
    let Some(command) = cli.command else {
        return super::measure::run(
            &cli.measure,
            cli.measure.cloud.as_deref().unwrap_or(Path::new("")),
            globals,
        )
        .with_context(|| what.to_string());
    };
    super::run(command, globals).with_context(|| what.to_string())
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// Runs the demo.
pub fn run(args: &Args, globals: Globals) -> Result<()> {
    if pipemeasure::sim::devices::preset(&args.like).is_none() {
        return Err(super::usage(format!(
            "--like {}: not a device preset (p30, iphone11, s10)",
            args.like
        )));
    }
    let start = std::time::Instant::now();
    let out = &args.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let (lab, site) = (out.join("lab"), out.join("site"));
    let profile_path = out.join(format!("demo-{}.json", args.like));
    let report = out.join("calibration-report");
    let (width, seed) = (args.width.to_string(), args.seed.to_string());
    let common = |dir: &Path| {
        vec![
            "--like".to_string(),
            args.like.clone(),
            "--out".into(),
            s(dir),
            "--width".into(),
            width.clone(),
            "--seed".into(),
            seed.clone(),
            "--force".into(),
        ]
    };
    let mut a = vec!["simulate".to_string(), "lab".into()];
    a.extend(common(&lab));
    a.extend(["--frames".into(), args.lab_frames.to_string()]);
    step("1/5 simulating the calibration lab", &a, globals)?;
    step(
        "2/5 calibrating the device from the lab frames",
        &[
            "calibrate".into(),
            "--device".into(),
            format!("demo-{}", args.like),
            "--frames".into(),
            s(&lab.join("frames")),
            "--sfm".into(),
            s(&lab.join("sparse")),
            "--out".into(),
            s(&profile_path),
            "--report".into(),
            s(&report),
            "--force".into(),
        ],
        globals,
    )?;
    let mut a = vec!["simulate".to_string(), "site".into()];
    a.extend(common(&site));
    a.extend([
        "--frames".into(),
        args.site_frames.to_string(),
        "--tls-offset".into(),
        "500000,5600000,100".into(),
    ]);
    step("3/5 simulating the pipe site", &a, globals)?;
    let site_truth = Truth::read(&site.join("truth.json"))?;
    let interest = site_truth
        .pipes
        .iter()
        .find(|p| p.of_interest)
        .context("the site has no pipe of interest")?;
    let near = [0, 1, 2].map(|k| interest.axis_point[k] + [500_000.0, 5_600_000.0, 100.0][k]);
    let measurement = out.join("measurement.json");
    let inliers = out.join("pipe-inliers.ply");
    step(
        "4/5 measuring the pipe with the new profile",
        &[
            "--device".into(),
            s(&profile_path),
            s(&site.join("dense/fused.ply")),
            "--near".into(),
            format!("{},{},{}", near[0], near[1], near[2]),
            "--within".into(),
            "0.4".into(),
            "--tls-scan".into(),
            s(&site.join("tls_scan.ply")),
            "--json".into(),
            s(&measurement),
            "--ply-out".into(),
            s(&inliers),
        ],
        globals,
    )?;
    if !globals.quiet {
        eprintln!("\n== 5/5 the same site reconstructed with the profile and in situ (Table III)");
    }
    let profile = Profile::read(&profile_path)?;
    let log = |m: &str| {
        if !globals.quiet {
            eprintln!("  {m}");
        }
    };
    let result = run_site(&site, &profile.camera(), &log).map_err(anyhow::Error::msg)?;
    let lab_truth = Truth::read(&lab.join("truth.json"))?;
    print_table(&lab_truth, &profile, &result)?;
    outln!(
        "\nStep 4 re-adjusted the SfM model's poses to the profile (they had been adjusted with the SfM stand-in's own SIMPLE_RADIAL camera) and re-triangulated dense/fused.ply through the profile at those poses (fused.ply.vis names each point's images); step 5 re-fuses the dense observations through each method's camera."
    );
    let summary = DemoJson {
        schema: "pipemeasure.demo/1",
        device: &args.like,
        intrinsics: Term::ALL
            .iter()
            .map(|&t| {
                (
                    t.name(),
                    lab_truth.camera.intrinsics.get(t),
                    profile.intrinsics.get(t),
                    profile.std_dev.get(t),
                )
            })
            .collect(),
        site: &result,
    };
    pipemeasure::io::atomic::write_bytes_atomic(
        &out.join("demo.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    outln!(
        "\nwritten to {}: the profile {}, the calibration report {}, the lab and site simulations, the measurement {}, the pipe's inliers coloured by residual {}, and these tables as demo.json",
        out.display(),
        profile_path.display(),
        report.display(),
        measurement.display(),
        inliers.display()
    );
    outln!("demo finished in {:.0} s", start.elapsed().as_secs_f64());
    Ok(())
}

/// `OUT/demo.json`.
#[derive(serde::Serialize)]
struct DemoJson<'a> {
    schema: &'static str,
    device: &'a str,
    /// (term, truth, estimate, σ).
    intrinsics: Vec<(&'static str, f64, f64, f64)>,
    site: &'a SiteResult,
}

fn print_table(lab: &Truth, profile: &Profile, r: &SiteResult) -> Result<()> {
    let truth = &lab.camera.intrinsics;
    let est = &profile.intrinsics;
    outln!(
        "\nCalibration ({} lab, {}x{}): true vs estimated intrinsics",
        lab.camera.device,
        lab.camera.width,
        lab.camera.height
    );
    outln!("| term | truth | estimate ± σ |");
    outln!("|---|---|---|");
    for t in Term::ALL {
        let (tv, ev) = (truth.get(t), est.get(t));
        if tv == 0.0 && !profile.terms.contains(&t) {
            continue;
        }
        outln!(
            "| {} | {:.6} | {:.6} ± {:.6} |",
            t.name(),
            tv,
            ev,
            profile.std_dev.get(t)
        );
    }
    outln!(
        "\nPipe of interest (truth {:.2} mm; TLS scan's fit {:.2} mm), {} site frames {}x{}",
        r.truth_radius_m * 1e3,
        r.tls_radius_m * 1e3,
        r.frames,
        r.image_size.0,
        r.image_size.1
    );
    outln!("| method | radius ± σ (mm) | accuracy (mm) | vs TLS (mm) | RMSE (mm) | inliers |");
    outln!("|---|---|---|---|---|---|");
    for row in &r.rows {
        outln!("| {} | {} |", row.method.name(), row.markdown_cells());
    }
    Ok(())
}
