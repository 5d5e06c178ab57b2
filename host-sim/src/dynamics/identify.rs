//! The hidden robot's dynamic parameters from a telemetry log: the samples matched with the
//! knots (`samples`), one regressor row pair per sample (`kinematics_core::dynamics::regressor`,
//! the code the servo feeds forward with), the least-squares fit of `calib::dynamics` (base
//! parameters on a rhombus, a parameter the data does not move refused by name, friction
//! estimated below zero clamped).
//!
//! What is identified is what the controller's torque command needs: the parameters in the
//! units of the torque it writes (a drive whose torque constant is off by some per cent
//! identifies every parameter off by as much, which is what its feed-forward must be).

use super::samples::{match_log, Matched, SampleOptions};
use super::session::{run_on_link, run_on_plant, ExcitationRun, LinkRunOptions, PlantRunOptions};
use super::telemetry::{check, LogFacts};
use super::DynError;
use crate::calib::dynamics::{fit_rows, Identified, COULOMB_SPEED_RAD_S};
use crate::io::dynamics_file::DynamicsFile;
use crate::io::telemetry_csv::TelemetryLog;
use crate::link::{LinkClient, Progress};
use crate::machine_spec::MachineSpec;
use crate::plant::PlantConfig;
use crate::sim::knots::KnotPath;
use kinematics_core::dynamics::{regressor, PARAMETERS};
use kinematics_core::Calibration;
use serde::Serialize;
use std::io::{Read, Write};

/// Fewest telemetry samples a log must have (1 s at 100 Hz).
pub const MIN_ROWS: usize = 100;

/// What the identification from telemetry found.
#[derive(Clone, Debug, Serialize)]
pub struct TelemetryIdentification {
    /// The parameters (`dynamics` is what the servo takes).
    #[serde(flatten)]
    pub identified: Identified,
    /// The log: samples, decimation, whether it named its machine.
    pub telemetry_samples: usize,
    pub decimation: u64,
    pub machine_named: bool,
    /// The tick the stream started at, and how closely the setpoints matched the knots (mm).
    pub start_tick: i64,
    pub match_error_mm: f64,
    /// Samples of the motion left out: at rest, at the torque limit, unreachable.
    pub samples_at_rest: usize,
    pub samples_saturated: usize,
    pub samples_unreachable: usize,
}

/// The log checked and matched (what identification and diagnosis both start from).
pub fn checked_samples(
    log: &TelemetryLog,
    path: &KnotPath,
    spec: &MachineSpec,
    opts: &SampleOptions,
) -> Result<(LogFacts, Matched), DynError> {
    let facts = check(log, spec, MIN_ROWS)?;
    let matched = match_log(log, &facts, path, opts)?;
    Ok((facts, matched))
}

/// Identifies the parameters from `log`, a run of the knots `path` on `spec`'s machine.
pub fn identify_from_telemetry(
    log: &TelemetryLog,
    path: &KnotPath,
    spec: &MachineSpec,
    opts: &SampleOptions,
) -> Result<TelemetryIdentification, DynError> {
    let (facts, m) = checked_samples(log, path, spec, opts)?;
    let mut rows = Vec::with_capacity(m.samples.len() * 2 * PARAMETERS);
    let mut rhs = Vec::with_capacity(m.samples.len() * 2);
    let mut skipped = m.at_rest + m.saturated + m.unreachable;
    for s in &m.samples {
        let Ok(y) = regressor(&s.motion, COULOMB_SPEED_RAD_S) else {
            skipped += 1;
            continue;
        };
        for (row, tau) in y.iter().zip(s.torque_nm) {
            rows.extend_from_slice(row);
            rhs.push(tau);
        }
    }
    let identified = fit_rows(&rows, rhs, skipped).map_err(|e| {
        DynError::NotIdentifiable(format!(
            "{e} (the log has {} usable samples of {} s of motion: record the whole excitation)",
            m.samples.len(),
            path.end_s()
        ))
    })?;
    Ok(TelemetryIdentification {
        identified,
        telemetry_samples: log.rows.len(),
        decimation: facts.decimation,
        machine_named: facts.machine_named,
        start_tick: m.start_tick,
        match_error_mm: m.match_error_mm,
        samples_at_rest: m.at_rest,
        samples_saturated: m.saturated,
        samples_unreachable: m.unreachable,
    })
}

/// `dynamics.json` of an identification: the parameters, their standard deviations and how
/// they were obtained (`source`: where the telemetry came from).
pub fn dynamics_file(
    id: &TelemetryIdentification,
    spec: &MachineSpec,
    source: &str,
) -> DynamicsFile {
    let mut f = DynamicsFile::from_dynamics(&id.identified.dynamics);
    f.machine = Some(spec.identity());
    f.std_dev = id.identified.std_dev.iter().cloned().collect();
    f.identification = Some(serde_json::json!({
        "method": "least squares on the controller's telemetry of the excitation (host-sim identify)",
        "source": source,
        "machine": spec.name,
        "telemetry_samples": id.telemetry_samples,
        "samples_used": id.identified.samples_used,
        "decimation": id.decimation,
        "residual_rms_nm": id.identified.residual_rms_nm,
        "min_relative_singular_value": id.identified.min_relative_singular_value,
        "absorbed": id.identified.absorbed,
        "clamped": id.identified.clamped,
    }));
    f
}

/// An identification through a controller: the run and what was fitted to it.
#[derive(Clone, Debug)]
pub struct Identification {
    pub run: ExcitationRun,
    pub result: TelemetryIdentification,
}

/// Streams the excitation to the controller behind `client`, records its telemetry and fits
/// the parameters to it (`session::run_on_link`, then [`identify_from_telemetry`]).
pub fn identify_through_link<S: Read + Write>(
    client: &mut LinkClient<S>,
    run: &LinkRunOptions,
    samples: &SampleOptions,
    progress: Progress<'_>,
) -> Result<Identification, DynError> {
    let r = run_on_link(client, run, progress)?;
    let result = identify_from_telemetry(&r.log, &r.path, &run.spec, samples)?;
    Ok(Identification { run: r, result })
}

/// Runs the excitation on a simulated plant in the host loop and fits the parameters to its
/// telemetry (`session::run_on_plant`, then [`identify_from_telemetry`]).
pub fn identify_on_plant(
    plant: &PlantConfig,
    cal: &Calibration<'_>,
    run: &PlantRunOptions,
    samples: &SampleOptions,
) -> Result<Identification, DynError> {
    let r = run_on_plant(plant, cal, run)?;
    let result = identify_from_telemetry(&r.log, &r.path, &run.spec, samples)?;
    Ok(Identification { run: r, result })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::excitation::ExcitationOptions;
    use crate::dynamics::session::PlantRunOptions;
    use crate::dynamics::tuning::servo_config_for;
    use crate::io::telemetry_csv::{parse_telemetry, telemetry_text};
    use crate::plant::{Plant, PlantConfig};
    use crate::sim::closed_loop::{loop_config, run_loop_configured, FeedForward};
    use crate::sim::motions::Trajectory;
    use kinematics_core::{Calibration, FiveBar, FiveBarDynamics, ServoConfig};

    fn cal() -> Calibration<'static> {
        Calibration {
            model: FiveBar::<f32>::paper_nominal(),
            grid: None,
        }
    }

    fn options(spec: &MachineSpec) -> SampleOptions {
        SampleOptions {
            model: spec.nominal,
            min_transmission: spec.min_transmission,
            torque_limit_nm: [8.0; 2],
        }
    }

    /// The excitation on `plant` in the host loop, its telemetry through the CSV text, the fit.
    fn identify(
        plant: &PlantConfig,
        feedforward: FeedForward,
        servo: Option<ServoConfig>,
    ) -> TelemetryIdentification {
        let spec = MachineSpec::paper();
        let opts = PlantRunOptions {
            spec: spec.clone(),
            excitation: ExcitationOptions::default(),
            decimation: 20,
            feedforward,
            servo,
            seed: 1,
        };
        let id = identify_on_plant(plant, &cal(), &opts, &options(&spec)).unwrap();
        // Through the file: the same log, the same parameters.
        let log = parse_telemetry(&telemetry_text(&id.run.log)).unwrap();
        assert_eq!(
            log, id.run.log,
            "the file carries what the controller reports"
        );
        let again = identify_from_telemetry(&log, &id.run.path, &spec, &options(&spec)).unwrap();
        assert_eq!(again.identified.dynamics, id.result.identified.dynamics);
        id.result
    }

    /// The hidden robot's lumped truth on a rhombus (the distal inertias in the other motor's).
    fn base_truth(plant: &PlantConfig) -> [f64; 9] {
        let mut t = Plant::new(plant, 1).true_dynamics();
        t.motor_inertia_kg_m2[0] += t.distal_inertia_kg_m2[1];
        t.motor_inertia_kg_m2[1] += t.distal_inertia_kg_m2[0];
        t.distal_inertia_kg_m2 = [0.0; 2];
        t.to_array()
    }

    /// From 100 Hz telemetry of the excitation on the paper six-bar plant (stress, clearances,
    /// backlash, friction, quantisation): the bodies' lumped inertias and the tool mass within
    /// 5 % (about three of the fit's standard deviations), the friction within 15 %.
    #[test]
    fn the_paper_plants_dynamics_come_out_of_its_telemetry() {
        let plant = PlantConfig::paper();
        let id = identify(&plant, FeedForward::Constant, None);
        let (got, want) = (id.identified.dynamics.to_array(), base_truth(&plant));
        eprintln!("identified {got:?}\ntruth      {want:?}");
        assert_eq!(id.decimation, 20);
        assert!(id.match_error_mm < 1e-4, "{}", id.match_error_mm);
        for (k, tol) in [
            (0, 0.05),
            (1, 0.05),
            (2, 0.05),
            (5, 0.15),
            (6, 0.15),
            (7, 0.15),
            (8, 0.15),
        ] {
            assert!(
                (got[k] - want[k]).abs() < tol * want[k],
                "{}: {} vs {}",
                kinematics_core::dynamics::PARAMETER_NAMES[k],
                got[k],
                want[k]
            );
        }
    }

    fn max_following_um(plant: &PlantConfig, d: FiveBarDynamics<f64>, servo: ServoConfig) -> f64 {
        let spec = MachineSpec::paper();
        let tr = Trajectory::by_name("figure8-5g", &spec).unwrap();
        let mut p = Plant::new(plant, 1);
        let s = run_loop_configured(
            &mut p,
            &cal(),
            &tr,
            tr.natural_duration_s(),
            &spec,
            &FeedForward::Dynamics(d),
            servo,
            None,
        )
        .unwrap();
        assert!(s.fault.is_none(), "{s:?}");
        s.max_following_err_um
    }

    /// A 0.3 kg cutting head instead of the 40 g tool: the paper machine's identified model and
    /// gains leave the loop oscillating at 5 g (the gains are designed for a third less
    /// inertia); the excitation's telemetry (the observer off while it runs: the loop must be
    /// stable to be identified) gives the heavier machine's dynamics, and with them and the gains
    /// designed for them its figure-eight at 5 g follows within 1 µm of the 40 g machine's with
    /// its own. `cargo test -p host-sim --lib a_heavier_tool -- --nocapture` prints the figures
    /// (docs/validation/benchmarks.md).
    #[test]
    fn a_heavier_tool_is_identified_from_telemetry_and_follows_as_the_light_one() {
        let spec = MachineSpec::paper();
        let light = PlantConfig::paper();
        let mut heavy = light.clone();
        heavy.linkage.tool_mass_kg = 0.3;
        let d_light = identify(&light, FeedForward::Constant, None)
            .identified
            .dynamics;
        let default = loop_config(&Plant::new(&light, 1), &spec);
        let mut quiet = default;
        for a in &mut quiet.axes {
            a.observer_bandwidth_rad_s = 0.0;
        }
        let d_heavy = identify(&heavy, FeedForward::Dynamics(d_light), Some(quiet))
            .identified
            .dynamics;
        let want = base_truth(&heavy)[2];
        assert!(
            (d_heavy.tool_mass_kg - want).abs() < 0.05 * want,
            "tool mass {} vs {want}",
            d_heavy.tool_mass_kg
        );
        let tuned =
            |d: &FiveBarDynamics<f64>| servo_config_for(d, &spec.nominal, &spec, default).unwrap();
        let designed = max_following_um(&light, d_light, default);
        let stale = max_following_um(&heavy, d_light, default);
        let identified = max_following_um(&heavy, d_heavy, tuned(&d_heavy));
        eprintln!(
            "HEAVY_TOOL figure8-5g max following error: 40 g tool, its identified model and the \
             default gains {designed:.2} um; 0.3 kg tool with them {stale:.1} um; with its model \
             identified from telemetry (tool point mass {:.4} kg, truth {want:.4}) and the gains \
             designed for it {identified:.2} um",
            d_heavy.tool_mass_kg
        );
        assert!(stale > 10.0, "the stale model and gains: {stale} um");
        assert!(
            (identified - designed).abs() <= 1.0,
            "{identified} um vs the designed machine's {designed} um"
        );
    }
}
