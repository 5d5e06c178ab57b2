//! `host-sim simulate`: the closed 2 kHz loop on a plant, with a JSON summary, CSV log and plot.
//!
//! See [`crate::closed_loop`] for what is simulated and how errors are defined. The JSON summary
//! goes to stdout (one object); the log and plot are written atomically and only when asked.

use crate::closed_loop::{run_loop, LogRow};
use crate::measure::load_calibration;
use crate::io::atomic::write_atomic;
use crate::plant::{Plant, PlantConfig, PlantModel};
use crate::io::plot::{xy_plot, Mark, Series};
use crate::trajectory::Trajectory;
use anyhow::{anyhow, bail, Context, Result};
use kinematics_core::{Calibration, CorrectionGrid};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Arguments of `host-sim simulate`.
#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
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
}

fn format_log(rows: &[LogRow]) -> String {
    let mut s = String::from(
        "t_s,x_set_mm,y_set_mm,x_mm,y_mm,theta1_enc_rad,theta2_enc_rad,theta1_ref_rad,theta2_ref_rad,torque1_nm,torque2_nm,tracking_err_um,max_bar_tension_n\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{:.4},{:.6},{:.6},{:.6},{:.6},{:.9},{:.9},{:.9},{:.9},{:.5},{:.5},{:.4},{:.3}",
            r.t_s,
            r.setpoint_mm[0],
            r.setpoint_mm[1],
            r.tool_mm[0],
            r.tool_mm[1],
            r.encoder_rad[0],
            r.encoder_rad[1],
            r.reference_rad[0],
            r.reference_rad[1],
            r.torque_nm[0],
            r.torque_nm[1],
            r.tracking_err_um,
            r.max_bar_tension_n
        );
    }
    s
}

pub fn run(args: SimulateArgs) -> Result<()> {
    let mut cfg = PlantConfig::by_name(&args.plant)?;
    match args.plant_model.as_deref() {
        None => {}
        Some("sixbar") => cfg.sixbar.model = PlantModel::Sixbar,
        Some("fivebar") => cfg.sixbar.model = PlantModel::Fivebar,
        Some(other) => bail!("unknown --plant-model '{other}' (known: sixbar, fivebar)"),
    }
    let trajectory = Trajectory::by_name(&args.trajectory)?;
    let seconds = args.seconds.unwrap_or_else(|| trajectory.natural_duration_s());
    if !(seconds > 0.0 && seconds <= 3600.0) {
        bail!("--seconds must be in (0, 3600], not {seconds}");
    }
    let (model, bytes) = load_calibration(args.model.as_deref(), args.grid.as_deref())?;
    let grid = match &bytes {
        Some(b) => Some(CorrectionGrid::parse(b).map_err(|e| anyhow!("grid: {e}"))?),
        None => None,
    };
    let cal = Calibration { model, grid };
    let mut plant = Plant::new(&cfg, args.seed);
    let want_log = args.log.is_some() || args.plot.is_some();
    let mut rows = Vec::new();
    let summary = run_loop(&mut plant, &cal, &trajectory, seconds, want_log.then_some(&mut rows))?;
    if let Some(p) = &args.log {
        write_atomic(p, format_log(&rows).as_bytes())?;
    }
    if let Some(p) = &args.plot {
        let set: Vec<[f64; 2]> = rows.iter().map(|r| r.setpoint_mm).collect();
        let act: Vec<[f64; 2]> = rows.iter().map(|r| r.tool_mm).collect();
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
    use std::io::Write as _;
    writeln!(std::io::stdout(), "{}", serde_json::to_string_pretty(&summary)?).context("cannot write the summary to stdout")?;
    Ok(())
}
