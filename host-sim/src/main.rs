//! `host-sim` command line: see `host-sim --help`.

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Plant simulation and calibration tools of the hidden-robot micro-mechanism.
#[derive(Parser)]
#[command(name = "host-sim", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Find where model and measurements disagree, name the missing effect, show the gap shrink.
    Diagnose(host_sim::diagnose::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Diagnose(args) => host_sim::diagnose::run(args),
    }
}
