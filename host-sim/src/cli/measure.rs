//! `host-sim measure`: a protocol on a simulated plant, written as a measurement CSV
//! (`host_sim::calib::measure`).

use anyhow::Result;
use host_sim::calib::measure::{measure_compensated, MeasureOptions};
use host_sim::io::model_file::read_model_file;
use host_sim::calib::protocol::Protocol;
use host_sim::io::measurement_csv::write_measurements;
use host_sim::plant::PlantConfig;
use kinematics_core::Calibration;
use std::path::PathBuf;

/// Arguments of `host-sim measure`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// `ideal`, `paper` or a plant TOML file.
    #[arg(long)]
    pub plant: String,
    /// `table1`, `grid`, `random:N` or `repeat`.
    #[arg(long)]
    pub protocol: String,
    /// Seeds the random targets and the instrument noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output measurement CSV.
    #[arg(long)]
    pub out: PathBuf,
    /// Hidden-robot model to command with (default: the nominal five-bar); its backlash_urad,
    /// if any, is corrected by direction in every command.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Correction grid image to add to the commands.
    #[arg(long)]
    pub grid: Option<PathBuf>,
    /// Overrides the instrument's noise σ (µm).
    #[arg(long)]
    pub noise_um: Option<f64>,
}

pub fn run(args: &Args) -> Result<()> {
    let spec = super::machine_spec();
    let plant = PlantConfig::by_name(&args.plant)?;
    let protocol = Protocol::parse(&args.protocol)?;
    let (model, bytes) = super::load_calibration(args.model.as_deref(), args.grid.as_deref(), &spec.nominal)?;
    let cal = Calibration { model, grid: super::parse_grid(&bytes)? };
    super::check_noise_um(args.noise_um)?;
    // A model with a backlash correction (diagnose --out-model): every command corrected by its
    // motors' approach directions, as the servo would.
    let backlash = match &args.model {
        Some(p) => read_model_file(p)?.backlash().map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?,
        None => None,
    };
    let opts = MeasureOptions { protocol, seed: args.seed, noise_um: args.noise_um, spec };
    let rows = measure_compensated(&plant, &cal, backlash.as_ref(), &opts)?;
    write_measurements(&args.out, &rows)?;
    eprintln!("measure: {} measurements written to {}", rows.len(), args.out.display());
    Ok(())
}
