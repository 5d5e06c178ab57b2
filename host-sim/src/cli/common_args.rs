//! What several commands do with the same kind of argument, done once: `--plant` and
//! `--plant-model`, a dynamics file and a measurement file (`--data` and the like) checked to
//! be of the machine, and the moving
//! machine's telemetry log (`--telemetry`) with the knots it is a run of (`--knots`), as
//! `identify` and `diagnose --telemetry` read them.

use super::MachineArg;
use anyhow::{anyhow, bail, Context, Result};
use host_sim::calib::machine::check_plant_fits;
use host_sim::io::dynamics_file::read_dynamics_file;
use host_sim::io::measurement_csv::{read_measurement_file, Measurement};
use host_sim::io::telemetry_csv::{read_telemetry, TelemetryLog};
use host_sim::link::link_protocol::Knot;
use host_sim::link::parse_knots_csv;
use host_sim::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use host_sim::plant::{PlantConfig, PlantModel};
use host_sim::sim::knots::KnotPath;
use kinematics_core::FiveBarDynamics;
use std::path::Path;

/// `--accel-g G`, the excitation's peak acceleration as `identify`, `simulate` and `diagnose
/// --telemetry` take it, checked (in (0, 20] g) and in mm/s².
pub fn excitation_accel_mm_s2(accel_g: f64) -> Result<f64> {
    if !(accel_g > 0.0 && accel_g <= 20.0) {
        bail!("--accel-g must be in (0, 20], not {accel_g}");
    }
    Ok(accel_g * STANDARD_GRAVITY_MM_S2)
}

/// `--plant-model NAME` applied to the plant: `sixbar` or `fivebar` (none: the plant's own).
pub fn override_plant_model(plant: &mut PlantConfig, name: Option<&str>) -> Result<()> {
    match name {
        None => {}
        Some("sixbar") => plant.sixbar.model = PlantModel::Sixbar,
        Some("fivebar") => plant.sixbar.model = PlantModel::Fivebar,
        Some(other) => bail!("unknown --plant-model '{other}' (known: sixbar, fivebar)"),
    }
    Ok(())
}

/// The plant `--plant NAME` names (`ideal`, `paper` or a plant TOML), checked to be built around
/// `spec`'s machine: a simulated run on another machine's plant would report figures of neither.
pub fn plant_for(name: &str, spec: &MachineSpec) -> Result<PlantConfig> {
    let plant = PlantConfig::by_name(name)?;
    check_plant_fits(&plant, spec)?;
    Ok(plant)
}

/// The identified dynamics of `--flag path` (a dynamics.json), checked to be of `spec`'s
/// machine: another machine's inertias fed forward would fight the servo.
pub fn read_dynamics(
    machine: &MachineArg,
    spec: &MachineSpec,
    flag: &str,
    path: &Path,
) -> Result<FiveBarDynamics<f64>> {
    let file = read_dynamics_file(path)?;
    machine.check_files(
        spec,
        &[super::file_machine(flag, path, file.machine.clone())],
    )?;
    file.dynamics()
        .map_err(|e| anyhow!("{}: {e}", path.display()))
}

/// The measurements of `--flag path`, checked to be of `spec`'s machine.
pub fn read_measurements(
    machine: &MachineArg,
    spec: &MachineSpec,
    flag: &str,
    path: &Path,
) -> Result<Vec<Measurement>> {
    let read = read_measurement_file(path)?;
    machine.check_files(spec, &[super::file_machine(flag, path, read.machine)])?;
    Ok(read.rows)
}

/// The telemetry log at `log_path`, checked to be `spec`'s machine's, and the knot path it is a
/// run of: the knots of `knots` (a knots CSV), else `default_knots` (the built-in excitation),
/// from the log's first setpoint.
pub fn telemetry_run(
    machine: &MachineArg,
    spec: &MachineSpec,
    log_path: &Path,
    knots: Option<&Path>,
    default_knots: impl FnOnce() -> Result<Vec<Knot>>,
) -> Result<(TelemetryLog, KnotPath)> {
    let log = read_telemetry(log_path)?;
    machine.check_files(
        spec,
        &[super::file_machine(
            "--telemetry",
            log_path,
            log.meta.as_ref().map(|m| m.machine.clone()),
        )],
    )?;
    let start = log
        .rows
        .first()
        .map(|r| r.setpoint_mm)
        .context("the telemetry log has no samples")?;
    let knots = match knots {
        Some(k) => {
            let text = std::fs::read_to_string(k)
                .with_context(|| format!("cannot read {}", k.display()))?;
            parse_knots_csv(&text).with_context(|| format!("in {}", k.display()))?
        }
        None => default_knots()?,
    };
    let path = KnotPath::new(start, &knots)?;
    Ok((log, path))
}
