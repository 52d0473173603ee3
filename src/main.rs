//! The `pipemeasure` command: see `pipemeasure --help` and the README.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
