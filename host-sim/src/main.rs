//! `host-sim` command line: see `host-sim --help`.
//!
//! The work is done by the `host_sim` library; `cli/` (one file per subcommand) turns flags into
//! its options structs, checks them, and prints tables and JSON. Errors are printed as their
//! whole chain (`error: ...`) with a non-zero exit.

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    match cli::run(cli::Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
