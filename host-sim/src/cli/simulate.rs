//! `host-sim simulate`: the closed 2 kHz loop on a plant (`host_sim::sim`), with a JSON summary
//! on stdout and, when asked, the sample log (CSV) and a plot of the paths, each written
//! atomically.
//!
//! What the servo feeds forward (`--feedforward`, default `dynamics`): the hidden robot's
//! identified dynamics on the trajectory's exact derivatives. The parameters come from
//! `--dynamics FILE` (`host-sim identify`), else from the `--grid` image's dynamics block (`HRDY`),
//! else they are identified on the plant first (`host_sim::calib::dynamics`: an excitation run,
//! a few seconds). `--mass-error-pct P` scales every mass and inertia of them by `1 + P/100`
//! (a model error, for robustness studies).
//!
//! `--telemetry-csv LOG` writes the run's telemetry as a controller sends it (every
//! `--decimation`-th sample, the controller's f32 values; `io::telemetry_csv`), so that a
//! simulated run and a controller's are read by the same tools.

use anyhow::{bail, Result};
use host_sim::calib::dynamics::identify;
use host_sim::dynamics::excitation::{excitation, ExcitationOptions};
use host_sim::dynamics::telemetry::{from_loop, meta_for};
use host_sim::io::plot::{xy_plot_png, Mark, Series};
use host_sim::io::policy::CommandFiles;
use host_sim::io::telemetry_csv::telemetry_text;
use host_sim::io::KeyOrder;
use host_sim::sim::closed_loop::{FeedForward, LoopSummary};
use host_sim::sim::motions::Trajectory;
use host_sim::sim::simulate::{format_log, simulate, SimulateOptions, MAX_SECONDS};
use kinematics_core::dynamics::PARAMETER_NAMES;
use serde::Serialize;
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
    /// `circle`, `figure8`, `p2p`, `p2p-trapezoid`, `circle-5g`, `figure8-5g`, `move-10mm`,
    /// `excitation` (the identification's motion, its knots played as the controller plays
    /// them; `host-sim identify`) or a CSV file `t_s,x_mm,y_mm`.
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
    /// What the servo feeds forward: `dynamics` (identified inverse dynamics on the exact
    /// derivatives), `constant` (the gains' constant inertia on them), `differences` (backward
    /// differences of the setpoints, the simplest loop).
    #[arg(long, default_value = "dynamics")]
    pub feedforward: String,
    /// Identified dynamic parameters (dynamics.json from `host-sim identify`).
    #[arg(long)]
    pub dynamics: Option<PathBuf>,
    /// Every mass and inertia of the fed-forward dynamics times `1 + P/100` (model error).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub mass_error_pct: f64,
    /// The run's telemetry, as a controller sends it (the telemetry CSV: what `identify
    /// --telemetry` and `diagnose --telemetry` read).
    #[arg(long)]
    pub telemetry_csv: Option<PathBuf>,
    /// Servo samples per telemetry sample (at least 20: 100 Hz, the link's fastest).
    #[arg(long, default_value_t = 20)]
    pub decimation: u32,
    /// With `--trajectory excitation`: its peak acceleration (g; as `identify`'s, 2 by
    /// default).
    #[arg(long, default_value_t = 2.0)]
    pub accel_g: f64,
}

/// What `simulate` prints: the loop's figures and where the fed-forward dynamics came from.
#[derive(Serialize)]
struct Output<'a> {
    #[serde(flatten)]
    summary: &'a LoopSummary,
    dynamics_source: Option<String>,
    dynamics: Option<Vec<(String, f64)>>,
}

pub fn run(args: &Args) -> Result<()> {
    // Both outputs staged, then renamed together; neither onto an input.
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--plant", super::plant_file(&args.plant))
        .input("--model", &args.model)
        .input("--grid", &args.grid)
        .input("--dynamics", &args.dynamics)
        .output("--log", &args.log)
        .output("--plot", &args.plot)
        .output("--telemetry-csv", &args.telemetry_csv)
        .check()?;
    let spec = args.machine.spec()?;
    let mut cfg = super::common_args::plant_for(&args.plant, &spec)?;
    super::common_args::override_plant_model(&mut cfg, args.plant_model.as_deref())?;
    if !(20..=2000).contains(&args.decimation) {
        bail!("--decimation must be 20 to 2000, not {}", args.decimation);
    }
    let accel_mm_s2 = super::common_args::excitation_accel_mm_s2(args.accel_g)?;
    let trajectory = match args.trajectory.as_str() {
        "excitation" => excitation(
            &spec,
            &ExcitationOptions {
                accel_mm_s2,
                ..ExcitationOptions::default()
            },
        )?
        .trajectory(),
        name => Trajectory::by_name(name, &spec)?,
    };
    let seconds = args
        .seconds
        .unwrap_or_else(|| trajectory.natural_duration_s());
    if !(seconds > 0.0 && seconds <= MAX_SECONDS) {
        bail!("--seconds must be in (0, {MAX_SECONDS}], not {seconds}");
    }
    if !(args.mass_error_pct > -100.0 && args.mass_error_pct <= 1000.0) {
        bail!(
            "--mass-error-pct must be in (-100, 1000], not {}",
            args.mass_error_pct
        );
    }
    let loaded = super::load_calibration(
        args.model.as_deref(),
        args.grid.as_deref(),
        &spec,
        &args.machine,
    )?;
    let cal = loaded.calibration()?;
    let (feedforward, source) = match args.feedforward.as_str() {
        "differences" => (FeedForward::Differences, None),
        "constant" => (FeedForward::Constant, None),
        "dynamics" => {
            let (d, source) = match (&args.dynamics, cal.grid.as_ref().and_then(|g| g.dynamics())) {
                (Some(p), _) => (
                    super::common_args::read_dynamics(&args.machine, &spec, "--dynamics", p)?,
                    format!("--dynamics {}", p.display()),
                ),
                (None, Some(d)) => (
                    d.cast::<f64>(),
                    "the --grid image's dynamics block".to_string(),
                ),
                (None, None) => {
                    let id = identify(&cfg, &cal, &spec, args.seed)?;
                    (
                        id.dynamics,
                        format!(
                            "identified on the plant (excitation run, residual {:.4} N·m RMS)",
                            id.residual_rms_nm
                        ),
                    )
                }
            };
            let k = 1.0 + args.mass_error_pct / 100.0;
            let source = if args.mass_error_pct != 0.0 {
                format!("{source}, masses and inertias x{k}")
            } else {
                source
            };
            (FeedForward::Dynamics(d.scaled_masses([k; 5])), Some(source))
        }
        other => bail!("unknown --feedforward '{other}' (known: dynamics, constant, differences)"),
    };
    if args.mass_error_pct != 0.0 && !matches!(feedforward, FeedForward::Dynamics(_)) {
        bail!("--mass-error-pct applies to --feedforward dynamics only");
    }
    let opts = SimulateOptions {
        seconds: Some(seconds),
        seed: args.seed,
        keep_log: args.log.is_some() || args.plot.is_some() || args.telemetry_csv.is_some(),
        spec: spec.clone(),
        feedforward,
    };
    let run = simulate(&cfg, &cal, &trajectory, &opts)?;
    if let Some(p) = &args.log {
        outputs.bytes(p, format_log(&run.log).as_bytes())?;
    }
    if let Some(p) = &args.telemetry_csv {
        let log = from_loop(&run.log, meta_for(&spec, args.decimation));
        outputs.bytes(p, telemetry_text(&log).as_bytes())?;
    }
    if let Some(p) = &args.plot {
        let set: Vec<[f64; 2]> = run.log.iter().map(|r| r.setpoint_mm).collect();
        let act: Vec<[f64; 2]> = run.log.iter().map(|r| r.tool_mm).collect();
        let png = xy_plot_png(
            &format!(
                "{} on {} plant: commanded vs actual",
                trajectory.name(),
                args.plant
            ),
            "x (mm)",
            "y (mm)",
            &[
                Series {
                    label: "commanded (setpoints)",
                    points: &set,
                    mark: Mark::Line,
                },
                Series {
                    label: "actual tool point",
                    points: &act,
                    mark: Mark::Line,
                },
            ],
        )?;
        outputs.bytes(p, &png)?;
    }
    outputs.commit()?;
    let dynamics = match feedforward {
        FeedForward::Dynamics(d) => Some(
            PARAMETER_NAMES
                .iter()
                .map(|n| n.to_string())
                .zip(d.to_array())
                .collect(),
        ),
        _ => None,
    };
    let r = &run.summary;
    eprintln!(
        "simulate: {} on the {} plant for {:.2} s ({} samples, {:.1}x real time): tracking error max {:.2} µm, RMS {:.2} µm; following error max {:.2} µm; {}",
        r.trajectory,
        r.plant,
        r.simulated_s,
        r.samples,
        r.realtime_factor,
        r.max_tracking_err_um,
        r.rms_tracking_err_um,
        r.max_following_err_um,
        r.fault.as_deref().map_or("no fault".to_string(), |f| format!("FAULT: {f}"))
    );
    super::print_json(
        &Output {
            summary: &run.summary,
            dynamics_source: source,
            dynamics,
        },
        KeyOrder::Declared,
    )?;
    // A run that faulted is a failed run: the summary says why, the exit status says so.
    if let Some(fault) = &run.summary.fault {
        bail!("the simulation faulted: {fault}");
    }
    Ok(())
}
