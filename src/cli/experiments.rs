//! `pipemeasure experiments [--out DIR] [--quick] [--seed S] [--only LIST]`: the paper's four
//! experiments on simulated data — Fig. 7 and Fig. 8 (eccentricity of one target), Table II
//! (matching), Table III (pipe radius with the device profiles against in-situ radial
//! self-calibration) — each table written as Markdown and JSON, each figure as SVG, and an
//! index `README.md` naming the command and seed.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use pipemeasure::experiments::PresetRuns;
use pipemeasure::experiments::eccentricity::{EccentricityResult, EccentricityScenario};
use pipemeasure::experiments::matching::{table2, table2_runs};
use pipemeasure::experiments::pipe::{Table3Options, table3, table3_markdown};
use pipemeasure::experiments::video_lab::{video_lab_runs, video_labs, video_labs_markdown};
use pipemeasure::io::atomic::write_bytes_atomic;
use pipemeasure::report::plots::line_chart;

use super::Globals;

/// The experiments by name.
const ALL: [&str; 6] = [
    "fig7-8",
    "table2",
    "table3",
    "video",
    "video-labs",
    "video-sites",
];

/// The experiments run only when named; `video` names both.
const VIDEO: [&str; 2] = ["video-labs", "video-sites"];

/// Arguments of `experiments`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder (created; existing tables and figures there are replaced).
    #[arg(long, default_value = "pipemeasure-experiments")]
    out: PathBuf,
    /// A small configuration for CI: fewer combinations, smaller and fewer frames.
    #[arg(long)]
    quick: bool,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run only these, comma-separated: fig7-8, table2, table3, video-labs (the calibration
    /// labs filmed as hand-held video, calibrated with and without the rolling-shutter model),
    /// video-sites (Table III with the sites filmed as hand-held video), video (both). The
    /// video experiments run only when named.
    #[arg(long, value_delimiter = ',', value_parser = clap::builder::PossibleValuesParser::new(ALL))]
    only: Vec<String>,
}

/// The configurations: the paper's sizes, or the quick ones.
fn configs(args: &Args) -> (EccentricityScenario, PresetRuns, Table3Options, PresetRuns) {
    let mut ecc = EccentricityScenario {
        seed: args.seed,
        ..EccentricityScenario::default()
    };
    let mut t2 = PresetRuns {
        seed: args.seed,
        ..table2_runs()
    };
    let mut t3 = Table3Options::default();
    t3.runs.seed = args.seed;
    let mut labs = PresetRuns {
        seed: args.seed,
        ..video_lab_runs()
    };
    if args.quick {
        labs.width = 960;
        labs.frames = 40;
        ecc.combinations = 10;
        t2.width = 1920;
        t2.frames = 30;
        t3.runs.width = 960;
        t3.runs.frames = 20;
    }
    (ecc, t2, t3, labs)
}

/// Writes `name` under `out` atomically.
fn write(out: &Path, name: &str, text: &str) -> Result<()> {
    let path = out.join(name);
    write_bytes_atomic(&path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

fn json(value: &impl serde::Serialize) -> Result<String> {
    Ok(serde_json::to_string_pretty(value)?)
}

/// Writes a table under `out`: `FILE.md`, its Markdown `section` and the command that produced
/// it, and `FILE.json`, its `results`.
fn write_table(
    out: &Path,
    file: &str,
    section: &str,
    command: &str,
    results: &impl serde::Serialize,
) -> Result<()> {
    write(
        out,
        &format!("{file}.md"),
        &format!("{section}\nProduced by `{command}`.\n"),
    )?;
    write(out, &format!("{file}.json"), &json(results)?)
}

/// Runs the experiments.
pub fn run(args: &Args, globals: Globals) -> Result<()> {
    let wanted = |name: &str| {
        (args.only.is_empty() && !VIDEO.contains(&name))
            || args
                .only
                .iter()
                .any(|o| o == name || (o == "video" && VIDEO.contains(&name)))
    };
    let out = &args.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let command = format!(
        "pipemeasure experiments{} --seed {}{}",
        if args.quick { " --quick" } else { "" },
        args.seed,
        if args.only.is_empty() {
            String::new()
        } else {
            format!(" --only {}", args.only.join(","))
        }
    );
    let log = |message: &str| globals.log(message);
    let (ecc, t2, t3, labs) = configs(args);
    let mut index = format!(
        "# The paper's experiments on simulated data\n\nProduced by `{command}` (pipemeasure {}).\n",
        env!("CARGO_PKG_VERSION")
    );
    let start = std::time::Instant::now();
    if wanted("fig7-8") {
        log(
            "== Fig. 7 and Fig. 8: one target, Algorithm 3 against fitted centres and Luhmann's form",
        );
        let r = pipemeasure::experiments::eccentricity::run(&ecc).map_err(anyhow::Error::msg)?;
        write_eccentricity(out, &r, &command)?;
        let section = r.section_markdown();
        outln!("{section}");
        index.push_str(&section);
    }
    if wanted("table2") {
        log("== Table II: matching with Algorithm 2, robust triangulation and Algorithm 3");
        let t = table2(&t2, &|m| log(&format!("  {m}"))).map_err(anyhow::Error::msg)?;
        let section = t.section_markdown();
        write_table(out, "table2", &section, &command, &t)?;
        outln!("{section}");
        index.push_str(&section);
    }
    if wanted("video-labs") {
        log(
            "== The calibration labs filmed as hand-held video, with and without the rolling-shutter model",
        );
        let section = video_labs_section(&labs, out, &command, &log)?;
        outln!("{section}");
        index.push_str(&section);
    }
    let sections = [
        Table3Section {
            name: "table3",
            file: "table3",
            title: "Table III: the pipe radius with the device profiles and in situ",
            heading: "Table III — pipe radius, pre-calibration against in situ",
            sites: "table3-sites",
            conditions: "",
            footer: "\nPaper (Table III, real data): 0.5 mm with pre-calibration at best (iPhone 11), in situ about 45 % worse.\n",
            video: false,
        },
        Table3Section {
            name: "video-sites",
            file: "video",
            title: "Table III, video: the sites filmed as hand-held video",
            heading: "Table III, video — the sites filmed as hand-held video",
            sites: "video-sites",
            conditions: "; rolling shutter at the preset's readout time, 8 ms exposure, 3–9 °/s and 0.05–0.15 m/s at the frames",
            footer: "The rows' poses use the preset's readout time, as a profile calibrated from the lab video holds it.\n",
            video: true,
        },
    ];
    for s in sections.iter().filter(|s| wanted(s.name)) {
        log(&format!("== {}", s.title));
        let section = table3_section(s, &t3, out, &command, &log)?;
        outln!("{section}");
        index.push_str(&section);
    }
    write(out, "README.md", &index)?;
    outln!(
        "\nwritten to {} (tables as .md and .json, figures as .svg, index README.md) in {:.0} s",
        out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// One Table III run of `experiments`: the still sites or the sites filmed as video.
struct Table3Section {
    name: &'static str,
    /// The tables' file name (without extension).
    file: &'static str,
    title: &'static str,
    heading: &'static str,
    sites: &'static str,
    conditions: &'static str,
    footer: &'static str,
    video: bool,
}

/// Runs Table III as `s` says, writes `NAME.md` and `NAME.json` under `out` and returns the
/// markdown section.
fn table3_section(
    s: &Table3Section,
    t3: &Table3Options,
    out: &Path,
    command: &str,
    log: &dyn Fn(&str),
) -> Result<String> {
    let options = Table3Options {
        video: s.video,
        ..t3.clone()
    };
    let results = table3(&options, &out.join(s.sites), command, &|m| {
        log(&format!("  {m}"))
    })
    .map_err(anyhow::Error::msg)?;
    let mut section = format!(
        "\n## {}\n\n{} sites ({} frames of {}x{}, seed {}{}), simulated into `{}/`.\n\n",
        s.heading,
        options.runs.devices.join(", "),
        options.runs.frames,
        options.runs.width,
        options.runs.width * 9 / 16,
        options.runs.seed,
        s.conditions,
        s.sites,
    );
    section.push_str(&table3_markdown(&results));
    section.push_str(s.footer);
    write_table(out, s.file, &section, command, &results)?;
    Ok(section)
}

/// Runs the video labs' calibration table, writes `video-labs.md` and `video-labs.json` under
/// `out` and returns the markdown section.
fn video_labs_section(
    options: &PresetRuns,
    out: &Path,
    command: &str,
    log: &dyn Fn(&str),
) -> Result<String> {
    let results = video_labs(options, &out.join("video-labs"), command, &|m| {
        log(&format!("  {m}"))
    })
    .map_err(anyhow::Error::msg)?;
    let mut section = format!(
        "\n## Calibration from hand-held video — rolling shutter against global shutter\n\n{} labs ({} frames of {}x{} with their neighbours at ±1/30 s, seed {}; rolling shutter at the preset's readout time, 8 ms exposure, 3–9 °/s and 0.05–0.15 m/s at the frames, tremor), simulated into `video-labs/`; each calibrated from the same detections twice, the camera scored against the true one over the whole frame.\n\n",
        options.devices.join(", "),
        options.frames,
        options.width,
        options.width * 9 / 16,
        options.seed,
    );
    section.push_str(&video_labs_markdown(&results));
    write_table(out, "video-labs", &section, command, &results)?;
    Ok(section)
}

fn write_eccentricity(out: &Path, r: &EccentricityResult, command: &str) -> Result<()> {
    let produced = format!("\nProduced by `{command}`.\n");
    write(out, "fig7.md", &(r.fig7_markdown() + &produced))?;
    write(out, "fig8.md", &(r.fig8_markdown() + &produced))?;
    write(
        out,
        "fig7.json",
        &json(&serde_json::json!({"scenario": r.scenario, "rows": r.fig7}))?,
    )?;
    write(
        out,
        "fig8.json",
        &json(&serde_json::json!({
            "scenario": r.scenario,
            "rows": r.fig8,
            "mean_true_px": r.mean_true_px,
            "mean_algorithm3_error_px": r.mean_algorithm3_error_px,
            "mean_luhmann_error_px": r.mean_luhmann_error_px,
        }))?,
    )?;
    let fig7 = |f: fn(&pipemeasure::experiments::eccentricity::Fig7Row) -> f64| {
        r.fig7
            .iter()
            .map(|row| (row.views as f64, f(row)))
            .collect()
    };
    line_chart(
        &out.join("fig7.svg"),
        "Fig. 7: mean 3D error of the target centre",
        ("views", "error (mm, log)"),
        &[
            ("fitted centres, exact poses", fig7(|r| r.fitted_exact_mm)),
            ("Algorithm 3, exact poses", fig7(|r| r.corrected_exact_mm)),
            ("fitted centres, noisy poses", fig7(|r| r.fitted_noisy_mm)),
            ("Algorithm 3, noisy poses", fig7(|r| r.corrected_noisy_mm)),
        ],
        true,
    )?;
    let fig8 = |f: fn(&pipemeasure::experiments::eccentricity::Fig8Row) -> f64| {
        r.fig8.iter().map(|row| (row.view as f64, f(row))).collect()
    };
    line_chart(
        &out.join("fig8.svg"),
        "Fig. 8: eccentricity per view",
        ("view", "eccentricity (px)"),
        &[
            ("true", fig8(|r| r.true_px)),
            ("Algorithm 3", fig8(|r| r.algorithm3_px)),
            ("Luhmann", fig8(|r| r.luhmann_px)),
            ("error of Algorithm 3", fig8(|r| r.algorithm3_error_px)),
            ("error of Luhmann", fig8(|r| r.luhmann_error_px)),
        ],
        false,
    )?;
    Ok(())
}
