//! `host-sim simulate`: the closed 2 kHz loop on a plant (`host_sim::sim`), with a JSON summary
//! on stdout and, when asked, the sample log (CSV) and a plot of the paths, each written
//! atomically.

use anyhow::{bail, Result};
use host_sim::io::atomic::write_atomic;
use host_sim::io::plot::{xy_plot, Mark, Series};
use host_sim::io::KeyOrder;
use host_sim::plant::{PlantConfig, PlantModel};
use host_sim::sim::simulate::{format_log, simulate, SimulateOptions, MAX_SECONDS};
use host_sim::sim::trajectory::Trajectory;
use kinematics_core::Calibration;
use std::path::PathBuf;

/// Arguments of `host-sim simulate`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// `ideal`, `paper` or a plant TOML file.
    #[arg(long, default_value = "paper")]
    pub plant: String,
    /// Overrides the plant's linkage model: `sixbar` (compliant, solved) or `fivebar` (fast).
    #[arg(long)]
    pub plant_model: Option<String>,
    /// Simulated seconds (default: the trajectory's natural length).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// `circle`, `figure8`, `p2p` or a CSV file `t_s,x_mm,y_mm`.
    #[arg(long, default_value = "circle")]
    pub trajectory: String,
    /// Hidden-robot model the servo uses (default: nominal five-bar).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Correction grid image the servo uses.
    #[arg(long)]
    pub grid: Option<PathBuf>,
    /// Seeds the plant's instrument (unused by the loop itself; kept for reproducibility).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// CSV log of every sample.
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// PNG plot of commanded and actual paths.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    #[command(flatten)]
    pub machine: super::MachineArg,
}

pub fn run(args: &Args) -> Result<()> {
    let spec = args.machine.spec()?;
    let mut cfg = PlantConfig::by_name(&args.plant)?;
    host_sim::calib::machine::check_plant_fits(&cfg, &spec)?;
    match args.plant_model.as_deref() {
        None => {}
        Some("sixbar") => cfg.sixbar.model = PlantModel::Sixbar,
        Some("fivebar") => cfg.sixbar.model = PlantModel::Fivebar,
        Some(other) => bail!("unknown --plant-model '{other}' (known: sixbar, fivebar)"),
    }
    let trajectory = Trajectory::by_name(&args.trajectory, &spec)?;
    let seconds = args.seconds.unwrap_or_else(|| trajectory.natural_duration_s());
    if !(seconds > 0.0 && seconds <= MAX_SECONDS) {
        bail!("--seconds must be in (0, {MAX_SECONDS}], not {seconds}");
    }
    let (model, bytes) = super::load_calibration(args.model.as_deref(), args.grid.as_deref(), &spec.nominal)?;
    let cal = Calibration { model, grid: super::parse_grid(&bytes)? };
    let opts = SimulateOptions { seconds: Some(seconds), seed: args.seed, keep_log: args.log.is_some() || args.plot.is_some(), spec };
    let run = simulate(&cfg, &cal, &trajectory, &opts)?;
    if let Some(p) = &args.log {
        write_atomic(p, format_log(&run.log).as_bytes())?;
    }
    if let Some(p) = &args.plot {
        let set: Vec<[f64; 2]> = run.log.iter().map(|r| r.setpoint_mm).collect();
        let act: Vec<[f64; 2]> = run.log.iter().map(|r| r.tool_mm).collect();
        xy_plot(
            p,
            &format!("{} on {} plant: commanded vs actual", trajectory.name(), args.plant),
            "x (mm)",
            "y (mm)",
            &[
                Series { label: "commanded (setpoints)", points: &set, mark: Mark::Line },
                Series { label: "actual tool point", points: &act, mark: Mark::Line },
            ],
        )?;
    }
    super::print_json(&run.summary, KeyOrder::Declared)?;
    // A run that faulted is a failed run: the summary says why, the exit status says so.
    if let Some(fault) = &run.summary.fault {
        bail!("the simulation faulted: {fault}");
    }
    Ok(())
}
