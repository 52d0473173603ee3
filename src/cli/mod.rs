//! Command-line interface (binary only): clap definitions, one module per subcommand, and the
//! single place where errors become exit codes (0 success, 1 failure, 2 usage, 3 nothing found).

/// `println!` that returns an error (e.g. a closed pipe) instead of panicking.
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*)?;
    }};
}

/// `print!` that returns an error instead of panicking.
macro_rules! out {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        write!(std::io::stdout().lock(), $($arg)*)?;
    }};
}

mod calibrate;
mod demo;
mod detect;
mod experiments;
mod fit_cylinder;
mod matching;
mod measure;
mod profile;
mod progress;
mod simulate;
mod undistort;

use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// pipemeasure: metric pipe measurements from phone video.
///
/// Main job: `pipemeasure --device NAME CLOUD.ply` measures the pipe in a site's dense cloud
/// (scale from the targets against the TLS list, robust cylinder fit, TLS reference with
/// `--tls-scan`). The subcommands are the steps and tools around it.
#[derive(Debug, Parser)]
#[command(
    name = "pipemeasure",
    version,
    about,
    long_about = None,
    after_help = "Main job: `pipemeasure --device NAME CLOUD.ply` measures the pipe in a site's dense cloud.\nFirst time? `pipemeasure demo` runs the whole product on simulated data.",
    subcommand_negates_reqs = true
)]
pub struct Cli {
    #[command(subcommand)]
    command: Option<Command>,

    #[command(flatten)]
    measure: measure::Args,

    /// Silence logs and progress bars on stderr.
    #[arg(long, global = true)]
    quiet: bool,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the whole product on simulated data: calibrate a simulated phone, measure a
    /// simulated pipe with the new profile and in situ, compare with the truth.
    Demo(demo::Args),
    /// Rerun the paper's experiments on simulated data (Fig. 7, Fig. 8, Table II, Table III),
    /// writing each table as Markdown and JSON and each figure as SVG.
    Experiments(experiments::Args),
    /// Undistort frames with a device profile into a pinhole camera, writing PNG frames and a
    /// COLMAP cameras.txt.
    Undistort(undistort::Args),
    /// Find circular targets and their best-fit ellipses in frames.
    Detect(detect::Args),
    /// Calibrate a device from a lab video's frames into its profile (paper's calibration
    /// loop: Algorithms 1–3, free-network self-calibrating adjustment, term selection).
    Calibrate(calibrate::Args),
    /// Fit the best-supported cylinder (or every cylinder) of a point cloud.
    FitCylinder(fit_cylinder::Args),
    /// Match circular targets across the frames of an SfM model (paper Algorithms 1–3).
    Match(matching::Args),
    /// Show, list or convert device profiles.
    #[command(subcommand)]
    Profile(profile::Command),
    /// Simulate the calibration lab or a pipe site with exact ground truth.
    #[command(subcommand)]
    Simulate(simulate::Command),
}

/// Global options every subcommand sees.
#[derive(Clone, Copy, Debug)]
pub struct Globals {
    /// `--quiet`.
    pub quiet: bool,
}

/// Parses the command line, runs it and maps the outcome to an exit code.
pub fn main() -> ExitCode {
    let cli = Cli::parse(); // clap prints usage errors itself and exits with 2
    let globals = Globals { quiet: cli.quiet };
    let outcome = match (cli.command, cli.measure.cloud.clone()) {
        (Some(_), _) if !cli.measure.given().is_empty() => {
            eprintln!(
                "error: {}: options of the main command (`pipemeasure --device NAME CLOUD.ply`), not of a subcommand",
                cli.measure.given().join(", ")
            );
            return ExitCode::from(2);
        }
        (Some(command), _) => run(command, globals),
        (None, Some(cloud)) => measure::run(&cli.measure, &cloud, globals),
        (None, None) => {
            use clap::CommandFactory;
            let _ = Cli::command().print_help();
            return ExitCode::from(2);
        }
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        // The reader of our output went away (`| head`): not a failure.
        Err(err) if is_broken_pipe(&err) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            exit_code_for(&err)
        }
    }
}

fn run(command: Command, globals: Globals) -> Result<()> {
    match command {
        Command::Demo(args) => demo::run(&args, globals),
        Command::Experiments(args) => experiments::run(&args, globals),
        Command::Undistort(args) => undistort::run(&args, globals),
        Command::Detect(args) => detect::run(&args, globals),
        Command::Match(args) => matching::run(&args, globals),
        Command::Calibrate(args) => calibrate::run(&args, globals),
        Command::FitCylinder(args) => fit_cylinder::run(&args, globals),
        Command::Profile(cmd) => profile::run(&cmd),
        Command::Simulate(cmd) => simulate::run(&cmd, globals),
    }
}

fn is_broken_pipe(err: &anyhow::Error) -> bool {
    err.chain().any(|e| {
        e.downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// 3 when nothing was found (no cylinder), 1 for every other failure.
fn exit_code_for(err: &anyhow::Error) -> ExitCode {
    let nothing_found = err.chain().any(|e| {
        matches!(
            e.downcast_ref::<pipemeasure::measure::CylinderError>(),
            Some(pipemeasure::measure::CylinderError::NotFound { .. })
        )
    });
    ExitCode::from(if nothing_found { 3 } else { 1 })
}
