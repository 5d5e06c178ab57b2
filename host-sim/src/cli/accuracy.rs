//! `host-sim accuracy`: VDI/DGQ 3441 and ISO 230-2 figures per axis line
//! (`host_sim::calib::accuracy`) as JSON, and optionally the mean error at every target (PNG).

use anyhow::{anyhow, Result};
use host_sim::calib::accuracy::{mean_error_per_target, report};
use host_sim::io::measurement_csv::read_measurements;
use host_sim::io::plot::{vector_plot, VectorField};
use host_sim::io::KeyOrder;
use std::path::PathBuf;

/// VDI/DGQ 3441 and ISO 230-2 figures per axis line from repeated bidirectional runs.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Measurements with x_target_mm,y_target_mm and run on every row, rows in motion order.
    #[arg(long)]
    pub data: PathBuf,
    /// Optional PNG: mean error vector at every target.
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

/// `host-sim accuracy`.
pub fn run(args: &Args) -> Result<()> {
    let data = read_measurements(&args.data)?;
    let r = report(&data).map_err(|e| anyhow!("{}: {e}", args.data.display()))?;
    if let Some(plot) = &args.plot {
        let (base, err): (Vec<[f64; 2]>, Vec<[f64; 2]>) = mean_error_per_target(&data).into_iter().unzip();
        vector_plot(plot, "mean error at each target", &[VectorField { label: "measured − target", base_mm: &base, error_um: &err }])?;
    }
    super::print_json(&r, KeyOrder::Sorted)
}
