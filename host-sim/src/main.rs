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
    /// Measure a simulated plant with one of the paper's protocols (writes a measurement CSV).
    Measure(host_sim::measure::MeasureArgs),
    /// Run the closed 2 kHz loop on a simulated plant (JSON summary on stdout).
    Simulate(host_sim::simulate::SimulateArgs),
    /// Fit the hidden robot to measurements (poly, ls, full).
    Fit(host_sim::fit::FitArgs),
    /// Build the correction-grid flash image from measurements at the grid nodes.
    Grid(host_sim::grid_build::GridArgs),
    /// Motor angles for targets, exactly as the firmware computes them (model + grid, f32).
    #[command(name = "command")]
    MotorCommand(host_sim::command::CommandArgs),
    /// VDI/DGQ 3441 and ISO 230-2 figures per axis line from repeated bidirectional runs.
    Accuracy(host_sim::accuracy::AccuracyArgs),
    /// Find where model and measurements disagree, name the missing effect, show the gap shrink.
    Diagnose(host_sim::diagnose::Args),
    /// The whole calibration on a built-in simulated machine: measure, fit, grid, verify.
    Demo(host_sim::demo::DemoArgs),
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
        Command::Measure(args) => host_sim::measure::run(args),
        Command::Simulate(args) => host_sim::simulate::run(args),
        Command::Fit(a) => host_sim::fit::run(&a),
        Command::Grid(a) => host_sim::grid_build::run(&a),
        Command::MotorCommand(a) => host_sim::command::run(&a),
        Command::Accuracy(a) => host_sim::accuracy::run(&a),
        Command::Diagnose(args) => host_sim::diagnose::run(args),
        Command::Demo(a) => host_sim::demo::run(&a),
    }
}
