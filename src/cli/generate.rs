//! What the command line says about itself, generated from its own definitions (as ripgrep
//! ships its completions and man page): `pipemeasure completions SHELL` prints a completion
//! script; `pipemeasure man DIR` writes the man pages — `pipemeasure.1` and one per
//! subcommand, `pipemeasure-calibrate.1`, `pipemeasure-simulate-lab.1`, … — as committed in
//! `man/` (a test checks they are current).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::CommandFactory;
use pipemeasure::io::atomic::StagedFile;

use super::Cli;

/// Arguments of `completions`.
#[derive(Debug, clap::Args)]
pub struct CompletionsArgs {
    /// The shell.
    #[arg(value_enum)]
    shell: clap_complete::Shell,
}

/// Arguments of `man`.
#[derive(Debug, clap::Args)]
pub struct ManArgs {
    /// Folder to write the man pages into (created if missing).
    dir: PathBuf,
}

/// The command's definition as the generated text shows it: the package version alone (the
/// commit and build date of `--version` would change every page with every commit).
fn command() -> clap::Command {
    Cli::command().version(env!("CARGO_PKG_VERSION"))
}

/// Prints the completion script for the shell.
pub fn completions(args: &CompletionsArgs) -> Result<()> {
    let mut cmd = command();
    let mut script = Vec::new();
    clap_complete::generate(args.shell, &mut cmd, "pipemeasure", &mut script);
    use std::io::Write as _;
    std::io::stdout()
        .write_all(&script)
        .context("writing the completion script")
}

/// Stages the man page of `cmd` (named `name`) and of each of its subcommands in `dir`
/// (written beside their destinations; removed again if dropped uncommitted).
fn stage_pages(cmd: &clap::Command, name: &str, dir: &Path) -> Result<Vec<StagedFile>> {
    let cmd = cmd.clone().name(name.to_string());
    let mut page = Vec::new();
    clap_mangen::Man::new(cmd.clone())
        .render(&mut page)
        .with_context(|| format!("rendering the man page of {name}"))?;
    let path = dir.join(format!("{name}.1"));
    // Staging refuses a page whose place is taken by a folder, before any page is committed.
    let staged = StagedFile::write(&path, |w| std::io::Write::write_all(w, &page))
        .with_context(|| format!("writing {}", path.display()))?;
    let mut written = vec![staged];
    for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()) {
        if sub.get_name() == "help" {
            continue;
        }
        written.extend(stage_pages(
            sub,
            &format!("{name}-{}", sub.get_name()),
            dir,
        )?);
    }
    Ok(written)
}

/// Writes every man page into `args.dir`: all of them or, when one cannot be written, none
/// (each is staged beside its destination first).
pub fn man(args: &ManArgs) -> Result<()> {
    std::fs::create_dir_all(&args.dir)
        .with_context(|| format!("creating {}", args.dir.display()))?;
    let mut cmd = command();
    cmd.build();
    let staged = stage_pages(&cmd, "pipemeasure", &args.dir)?;
    let count = staged.len();
    for page in staged {
        let path = page.destination().to_path_buf();
        page.commit()
            .with_context(|| format!("writing {}", path.display()))?;
    }
    outln!("{count} man pages written to {}", args.dir.display());
    Ok(())
}
