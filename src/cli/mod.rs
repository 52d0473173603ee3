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
mod doctor;
mod experiments;
mod fit_cylinder;
mod frames;
mod generate;
mod hints;
mod matching;
mod measure;
mod pipes;
mod profile;
mod progress;
mod simulate;
mod undistort;
mod values;

use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// `pipemeasure --version`: the package version, the commit and the build date (`build.rs`).
pub(crate) const VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (commit ",
    env!("PIPEMEASURE_COMMIT"),
    ", built ",
    env!("PIPEMEASURE_BUILD_DATE"),
    ")"
);

/// pipemeasure: metric pipe measurements from phone video.
///
/// Main job: `pipemeasure --device NAME CLOUD.ply` measures the pipe in a site's dense cloud
/// (scale from the targets against the TLS list, robust cylinder fit, TLS reference with
/// `--tls-scan`). The subcommands are the steps and tools around it.
#[derive(Debug, Parser)]
#[command(
    name = "pipemeasure",
    version = VERSION,
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
    /// Choose the frames of a video (per second the one that moves least and is sharpest) and
    /// write them, e.g. a site's video before COLMAP.
    Frames(frames::Args),
    /// Match circular targets across the frames of an SfM model (paper Algorithms 1–3).
    Match(matching::Args),
    /// The pipe network of a cloud: every pipe once as straight segments with axis endpoints,
    /// radius, nominal size and coverage; what is not a pipe refused with the reason.
    Pipes(pipes::Args),
    /// Show, list or convert device profiles.
    #[command(subcommand)]
    Profile(profile::Command),
    /// Simulate the calibration lab or a pipe site with exact ground truth.
    #[command(subcommand)]
    Simulate(simulate::Command),
    /// Print a shell completion script (bash, zsh, fish, elvish, powershell), e.g.
    /// `pipemeasure completions bash > ~/.local/share/bash-completion/completions/pipemeasure`.
    Completions(generate::CompletionsArgs),
    /// Write the man pages (`pipemeasure.1` and one per subcommand) into a folder.
    Man(generate::ManArgs),
    /// Check what the product needs before a long run: COLMAP (and whether it can do dense
    /// stereo), ffmpeg, the profile folders and profiles, the cores and memory.
    Doctor(doctor::Args),
}

/// Global options every subcommand sees.
#[derive(Clone, Copy, Debug)]
pub struct Globals {
    /// `--quiet`.
    pub quiet: bool,
}

impl Globals {
    /// A progress message on stderr, unless `--quiet`.
    pub fn log(self, message: &str) {
        if !self.quiet {
            eprintln!("{message}");
        }
    }
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
            eprintln!("error: {}", error_message(&err));
            exit_code_for(&err)
        }
    }
}

/// The error and its causes joined by `: `, each cause once: a cause whose text the message
/// already holds (an error that prints its source, as many do) is not repeated. Each cause in
/// the command line's words ([`hints::on_the_command_line`]: the options that give an input),
/// also where an outer error already printed it in the library's.
fn error_message(err: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in err.chain() {
        let text = cause.to_string();
        let said = hints::on_the_command_line(cause);
        if message.contains(&text) {
            if let Some(said) = said {
                message = message.replacen(&text, &said, 1);
            }
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(&said.unwrap_or(text));
    }
    message
}

/// A command-line value that clap cannot check on its own (two options that contradict each
/// other, a value the library refuses): exit code 2, like clap's own usage errors.
#[derive(Debug)]
pub struct UsageError(pub String);

impl std::fmt::Display for UsageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for UsageError {}

/// A usage error (exit code 2) with this message.
pub fn usage(message: impl Into<String>) -> anyhow::Error {
    UsageError(message.into()).into()
}

/// A command that ran and found nothing (no target, no match, no cylinder): exit code 3.
#[derive(Debug)]
pub struct NothingFound(pub String);

impl std::fmt::Display for NothingFound {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for NothingFound {}

fn run(command: Command, globals: Globals) -> Result<()> {
    match command {
        Command::Demo(args) => demo::run(&args, globals),
        Command::Experiments(args) => experiments::run(&args, globals),
        Command::Undistort(args) => undistort::run(&args, globals),
        Command::Detect(args) => detect::run(&args, globals),
        Command::Match(args) => matching::run(&args, globals),
        Command::Calibrate(args) => calibrate::run(&args, globals),
        Command::FitCylinder(args) => fit_cylinder::run(&args, globals),
        Command::Frames(args) => frames::run(&args, globals),
        Command::Pipes(args) => pipes::run(&args, globals),
        Command::Profile(cmd) => profile::run(&cmd),
        Command::Simulate(cmd) => simulate::run(&cmd, globals),
        Command::Completions(args) => generate::completions(&args),
        Command::Man(args) => generate::man(&args),
        Command::Doctor(args) => doctor::run(&args),
    }
}

fn is_broken_pipe(err: &anyhow::Error) -> bool {
    err.chain().any(|e| {
        e.downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// 2 for an invalid option value, 3 when nothing was found (no target, no match, no
/// cylinder), 1 for every other failure.
fn exit_code_for(err: &anyhow::Error) -> ExitCode {
    use pipemeasure::measure::CylinderError;
    use pipemeasure::measure::scale::ScaleError;
    if err.chain().any(|e| e.is::<UsageError>()) {
        return ExitCode::from(2);
    }
    let nothing_found = err.chain().any(|e| {
        e.is::<NothingFound>()
            || matches!(
                e.downcast_ref::<CylinderError>(),
                Some(CylinderError::NotFound { .. } | CylinderError::NoPipe { .. })
            )
            || e.downcast_ref::<ScaleError>()
                .is_some_and(ScaleError::is_nothing_found)
    });
    ExitCode::from(if nothing_found { 3 } else { 1 })
}
