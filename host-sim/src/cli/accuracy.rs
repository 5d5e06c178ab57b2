//! `host-sim accuracy`: VDI/DGQ 3441 and ISO 230-2 figures per axis line
//! (`host_sim::calib::accuracy`) as JSON, and optionally the mean error at every target (PNG).

use anyhow::{anyhow, Result};
use host_sim::calib::accuracy::{mean_error_per_target, report, AccuracyReport};
use host_sim::io::plot::{vector_plot_png, VectorField};
use host_sim::io::policy::CommandFiles;
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
    /// The calibrated model.json whose registered instrument frame maps the readings into the
    /// machine frame (default: the readings as they are).
    #[arg(long, value_name = "MODEL")]
    pub instrument_frame: Option<PathBuf>,
    #[command(flatten)]
    pub machine: super::MachineArg,
}

/// `host-sim accuracy`.
pub fn run(args: &Args) -> Result<()> {
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--data", &args.data)
        .input("--instrument-frame", &args.instrument_frame)
        .output("--plot", &args.plot)
        .check()?;
    let spec = args.machine.spec()?;
    let rows = super::common_args::read_measurements(&args.machine, &spec, "--data", &args.data)?;
    let data = super::frame_of(args.instrument_frame.as_deref())?.register(&rows);
    // Figures outside the workspace are no accuracy of this machine: say so (the figures stand).
    let outside = data
        .iter()
        .filter(|m| {
            m.target_mm
                .is_some_and(|t| !spec.workspace.contains(t, 1e-3))
        })
        .count();
    if outside > 0 {
        eprintln!(
            "accuracy: {outside} of {} rows have targets outside machine '{}''s workspace",
            data.len(),
            spec.name
        );
    }
    let r = report(&data).map_err(|e| anyhow!("{}: {e}", args.data.display()))?;
    if let Some(plot) = &args.plot {
        let (base, err): (Vec<[f64; 2]>, Vec<[f64; 2]>) =
            mean_error_per_target(&data).into_iter().unzip();
        let png = vector_plot_png(
            "mean error at each target",
            &[VectorField::new("measured − target", &base, &err)],
            &[],
        )?;
        outputs.bytes(plot, &png)?;
    }
    outputs.commit()?;
    print_summary(&r, spec.instrument_sigma_um, &spec.name);
    super::print_json(&r, KeyOrder::Sorted)
}

/// The figures per axis line as a table on stderr, to what the instrument resolves.
fn print_summary(r: &AccuracyReport, sigma_um: f64, machine: &str) {
    let p = super::um_decimals(sigma_um);
    eprintln!(
        "accuracy: {} axis line(s) of machine '{machine}' (µm; instrument σ {sigma_um} µm)",
        r.lines.len()
    );
    eprintln!(
        "  {:<4} {:>9} {:>10} | {:>7} {:>7} {:>7} {:>7} | {:>7} {:>7} {:>7}",
        "axis", "at_mm", "length_mm", "A", "R", "B", "E", "P", "Ps", "Pa"
    );
    for l in &r.lines {
        let (i, v) = (&l.iso_230_2, &l.vdi_3441);
        eprintln!(
            "  {:<4} {:>9.3} {:>10.3} | {:>7.p$} {:>7.p$} {:>7.p$} {:>7.p$} | {:>7.p$} {:>7.p$} {:>7.p$}",
            l.axis, l.at_mm, l.length_mm, i.a_um, i.r_um, i.b_um, i.e_um, v.p_um, v.ps_um, v.pa_um
        );
    }
    for s in &r.skipped {
        eprintln!("accuracy: skipped: {s}");
    }
    eprintln!("accuracy: the full report (per target, per metre) is the JSON on stdout");
}
