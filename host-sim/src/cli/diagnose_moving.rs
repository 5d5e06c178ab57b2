//! `host-sim diagnose --telemetry LOG`: the moving machine's diagnosis
//! (`host_sim::dynamics::diagnose`): the controller's telemetry of the excitation against its
//! dynamics model: the gap-shrink table on stdout (as the static diagnosis prints it), the
//! report JSON (`--out`, the same contract), and the dynamics block with the effects named
//! (`--out-dynamics`, a dynamics.json for `grid --dynamics`).
//!
//! What the controller runs: `--grid` (its image: the model the encoders are read with and the
//! dynamics block it feeds forward), or `--model` and `--dynamics`; `--dynamics` overrides the
//! image's block. The knots the log is a run of: `--knots`, default the built-in excitation.

use super::MachineArg;
use anyhow::{bail, Context, Result};
use host_sim::dynamics::diagnose::{diagnose_telemetry, DiagnoseOptions};
use host_sim::dynamics::excitation::{excitation, ExcitationOptions};
use host_sim::dynamics::predict::Controller;
use host_sim::dynamics::report::table;
use host_sim::dynamics::samples::SampleOptions;
use host_sim::io::dynamics_file::{write_dynamics_file, DynamicsFile};
use host_sim::io::policy::CommandFiles;
use host_sim::io::{json_text, KeyOrder};
use kinematics_core::dynamics::PARAMETER_NAMES;
use kinematics_core::{Calibration, FiveBarDynamics};
use std::path::{Path, PathBuf};

/// The flags of the moving machine's diagnosis (`diagnose --telemetry`).
#[derive(clap::Args, Debug)]
pub struct MovingArgs {
    /// The controller's telemetry of the excitation (the telemetry CSV): diagnose the moving
    /// machine instead of measurements.
    #[arg(long)]
    pub telemetry: Option<PathBuf>,
    /// With --telemetry: the knots that were streamed (default: the built-in excitation).
    #[arg(long, requires = "telemetry")]
    pub knots: Option<PathBuf>,
    /// With --telemetry: the image the controller ran (its model and dynamics block).
    #[arg(long, requires = "telemetry")]
    pub grid: Option<PathBuf>,
    /// With --telemetry: the dynamics the controller fed forward (dynamics.json), if not the
    /// image's block.
    #[arg(long, requires = "telemetry")]
    pub dynamics: Option<PathBuf>,
    /// With --telemetry: the built-in excitation's peak acceleration (g), as it was run.
    #[arg(long, requires = "telemetry", default_value_t = 2.0)]
    pub accel_g: f64,
    /// With --telemetry: the built-in excitation's section length (s), as it was run.
    #[arg(long, requires = "telemetry", default_value_t = 8.0)]
    pub section_s: f64,
    /// With --telemetry: write the dynamics block with the effects named (dynamics.json).
    #[arg(long, requires = "telemetry")]
    pub out_dynamics: Option<PathBuf>,
}

/// The flags the moving diagnosis shares with the static one.
pub struct Shared<'a> {
    /// `--model`: the current model.
    pub model: Option<&'a Path>,
    /// `--out`: the report JSON.
    pub out: &'a Path,
    /// `--machine`.
    pub machine: &'a MachineArg,
}

/// `host-sim diagnose --telemetry`.
pub fn run(m: &MovingArgs, args: Shared<'_>) -> Result<()> {
    let Some(log_path) = &m.telemetry else {
        bail!("give --data (measurements) or --telemetry (the moving machine)");
    };
    let accel_mm_s2 = super::common_args::excitation_accel_mm_s2(m.accel_g)?;
    // Every file declared before anything runs: no output onto an input or another output.
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--telemetry", log_path)
        .input("--knots", &m.knots)
        .input("--grid", &m.grid)
        .input("--dynamics", &m.dynamics)
        .input("--model", args.model)
        .output("--out", args.out)
        .output("--out-dynamics", &m.out_dynamics)
        .check()?;
    let spec = args.machine.spec()?;
    let loaded = super::load_calibration(args.model, m.grid.as_deref(), &spec, args.machine)?;
    let Calibration { model, grid } = loaded.calibration()?;
    let fed_forward: FiveBarDynamics<f64> = match (&m.dynamics, grid.as_ref().and_then(|g| g.dynamics())) {
        (Some(p), _) => super::common_args::read_dynamics(args.machine, &spec, "--dynamics", p)?,
        (None, Some(d)) => d.cast(),
        (None, None) => bail!(
            "give the dynamics the controller fed forward: --dynamics FILE, or --grid with the image it ran (its dynamics block)"
        ),
    };
    let (log, path) = super::common_args::telemetry_run(
        args.machine,
        &spec,
        log_path,
        m.knots.as_deref(),
        || {
            let ex = excitation(
                &spec,
                &ExcitationOptions {
                    accel_mm_s2,
                    section_s: m.section_s,
                    ..ExcitationOptions::default()
                },
            )?;
            Ok(ex.knots)
        },
    )?;
    let servo = host_sim::sim::closed_loop::servo_config_at(&spec);
    let model = model.cast::<f64>();
    let opts = DiagnoseOptions {
        spec: spec.clone(),
        samples: SampleOptions {
            model,
            min_transmission: spec.min_transmission,
            torque_limit_nm: servo.axes.map(|a| f64::from(a.torque_limit_nm)),
        },
        controller: Controller::new(&spec, model, servo, fed_forward)?,
    };
    let report = diagnose_telemetry(&log, &path, &opts)
        .with_context(|| format!("diagnosing {}", log_path.display()))?;
    print!("{}", table(&report));
    // Everything computed before anything is written.
    outputs.bytes(args.out, json_text(&report, KeyOrder::Declared)?.as_bytes())?;
    if let Some(p) = &m.out_dynamics {
        let Some(out) = &report.model_out else {
            bail!("the effects named do not make a valid dynamics block: nothing written");
        };
        let d = FiveBarDynamics::from_array(
            PARAMETER_NAMES.map(|n| out[n]),
            fed_forward.coulomb_speed_rad_s,
        );
        let mut file = DynamicsFile::from_dynamics(&d);
        file.machine = Some(spec.identity());
        file.identification = Some(serde_json::json!({
            "method": "the dynamics fed forward with the effects the moving machine's diagnosis named (host-sim diagnose --telemetry)",
            "telemetry": log_path.display().to_string(),
            "machine": spec.name,
            "effects": report.steps.iter().map(|s| s.effect.clone()).collect::<Vec<_>>(),
            "carried": report.carried,
        }));
        outputs.with(p, |tmp| write_dynamics_file(tmp, &file))?;
    }
    outputs.commit()?;
    eprintln!(
        "diagnose: {} effect(s) named; report -> {}",
        report.steps.len(),
        args.out.display()
    );
    Ok(())
}
