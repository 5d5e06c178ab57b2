//! THE measurement path: every visit commanded exactly as the firmware commands it, the machine
//! settled and read. `host-sim measure`, the demo's pipeline, the diagnosis tests and studies all
//! measure through [`measure_visits`].
//!
//! Quasi-static: for each target the commanded encoder angles come from the hidden robot (nominal
//! or fitted) plus the correction grid through `Calibration::command_rad`, in f32 exactly as the
//! firmware computes them (singularity margin from the [`MachineSpec`]); the motors turn
//! continuously, so each command is unwrapped next to the previous one; the servo is taken to hold
//! each encoder at the commanded count (no dynamic loop is needed for a static pose), having
//! approached it in the direction the motor last moved ([`Approach`]); the machine
//! ([`super::machine::Machine`]) settles and its instrument reads the tool point. One measurement
//! of the six-bar plant costs one equilibrium solve (a few µs).
//!
//! The approach direction of motor j is the sign of the (wrapped) change of its command from the
//! start of the motion (the visit's `from_mm`, through the model's IK) to the target; a start the
//! model cannot reach counts as +1; a visit from a plan's list may prescribe it instead
//! ([`Visit::dir`]). Each measurement takes 1 s of machine time (`t_s` counts measurements).

use super::backlash::{approach_dir, Backlash};
use super::frame::InstrumentFrame;
use super::machine::{Machine, PlantMachine};
use super::protocol::{visits, Protocol, Visit};
use super::CalibError;
use crate::io::measurement_csv::Measurement;
use crate::machine_spec::MachineSpec;
use crate::numeric::max_rms;
use crate::plant::PlantConfig;
use kinematics_core::{wrap_angle_rad, Calibration};
use serde::Serialize;

pub use crate::machine_spec::Approach;

/// One measured visit: the CSV row and the truth behind it.
#[derive(Clone, Debug)]
pub struct Landed {
    pub row: Measurement,
    /// Where the tool really was (mm, instrument frame, noiseless).
    pub true_mm: [f64; 2],
}

/// Measured visits with their readings and truth in the machine frame (`frame`: the
/// registration of the instrument's set-up, `super::frame`): what accuracy is judged on. The
/// rows a session writes keep the instrument's readings as they were.
pub fn registered(landed: &[Landed], frame: &InstrumentFrame) -> Vec<Landed> {
    landed
        .iter()
        .map(|l| Landed {
            row: Measurement {
                measured_mm: frame.to_machine_mm(l.row.measured_mm),
                ..l.row.clone()
            },
            true_mm: frame.to_machine_mm(l.true_mm),
        })
        .collect()
}

/// The measurement rows of measured visits.
pub fn rows(landed: &[Landed]) -> Vec<Measurement> {
    landed.iter().map(|l| l.row.clone()).collect()
}

/// Commands every visit through `cal` and measures it on `machine` (see the module doc). A
/// visit that prescribes its approach (`Visit::dir`, a plan's list) is approached so; the others
/// by `approach`. `clock` counts measurements across calls (the rows' `t_s`).
pub fn measure_visits(
    machine: &mut dyn Machine,
    cal: &Calibration<'_>,
    visits: &[Visit],
    approach: Approach,
    spec: &MachineSpec,
    clock: &mut usize,
) -> Result<Vec<Landed>, CalibError> {
    measure_visits_compensated(machine, cal, None, visits, approach, spec, clock)
}

/// [`measure_visits`] with the direction-dependent backlash correction
/// ([`super::backlash::Backlash::command_rad`]) added to every command, each motor's approach
/// direction taken from the uncorrected command (the correction is microradians: it never
/// turns a direction).
pub fn measure_visits_compensated(
    machine: &mut dyn Machine,
    cal: &Calibration<'_>,
    backlash: Option<&Backlash>,
    visits: &[Visit],
    approach: Approach,
    spec: &MachineSpec,
    clock: &mut usize,
) -> Result<Vec<Landed>, CalibError> {
    let model = cal.model.cast::<f64>();
    let min_transmission = spec.min_transmission as f32;
    let mut previous = [0.0f64; 2];
    let mut out = Vec::with_capacity(visits.len());
    for v in visits {
        let at_target = |reason: String| CalibError::Target {
            target_mm: v.target_mm,
            reason,
        };
        let t32 = [v.target_mm[0] as f32, v.target_mm[1] as f32];
        let cmd = cal
            .command_rad(t32, min_transmission)
            .map_err(|e| at_target(e.to_string()))?;
        // The motors turn continuously: unwrap next to the previous command.
        let cmd = [0, 1].map(|i| previous[i] + wrap_angle_rad(f64::from(cmd[i]) - previous[i]));
        previous = cmd;
        let dir = match (v.dir, approach, model.inverse(v.from_mm, 0.0)) {
            (Some(d), _, _) => d,
            (None, Approach::Positive, _) | (None, Approach::FromVisit, Err(_)) => [1, 1],
            (None, Approach::FromVisit, Ok(f)) => approach_dir(f, cmd),
        };
        let cmd = backlash.map_or(cmd, |b| b.command_rad(cmd, dir));
        let r = machine
            .measure(cmd, dir)
            .map_err(|e| at_target(e.to_string()))?;
        out.push(Landed {
            row: Measurement {
                theta_deg: [r.encoder_rad[0].to_degrees(), r.encoder_rad[1].to_degrees()],
                measured_mm: r.measured_mm,
                target_mm: Some(v.target_mm),
                dir: Some(dir),
                run: Some(v.run),
                t_s: Some(*clock as f64),
                line: 0,
            },
            true_mm: r.true_mm,
        });
        *clock += 1;
    }
    Ok(out)
}

/// Measures one list as `host-sim measure` does: the machine's instrument noise restarted from
/// `noise_seed` (what a machine built with that seed would draw), the clock from 0. The demo's
/// pipeline measures every list through this, so the separate commands with the same seeds
/// give the same measurements.
pub fn measure_list(
    machine: &mut dyn Machine,
    cal: &Calibration<'_>,
    visits: &[Visit],
    approach: Approach,
    noise_seed: u64,
    spec: &MachineSpec,
) -> Result<Vec<Landed>, CalibError> {
    measure_list_compensated(machine, cal, None, visits, approach, noise_seed, spec)
}

/// [`measure_list`] with the direction-dependent backlash correction in every command
/// ([`measure_visits_compensated`]): `host-sim measure --model` with a model that carries
/// `backlash_urad`, the demo's pipeline after it has measured the backlash.
pub fn measure_list_compensated(
    machine: &mut dyn Machine,
    cal: &Calibration<'_>,
    backlash: Option<&Backlash>,
    visits: &[Visit],
    approach: Approach,
    noise_seed: u64,
    spec: &MachineSpec,
) -> Result<Vec<Landed>, CalibError> {
    machine.reseed(noise_seed);
    measure_visits_compensated(machine, cal, backlash, visits, approach, spec, &mut 0)
}

/// Where measured visits landed against their targets (µm): the figures `measure` prints and
/// the demo's verification reports.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Accuracy {
    /// |true position − target|: where the tool really landed (known in simulation only).
    pub max_um: f64,
    pub rms_um: f64,
    /// |measured − target|: what the instrument shows (truth + its noise).
    pub measured_max_um: f64,
    pub measured_rms_um: f64,
    pub n_targets: usize,
}

/// Error vectors (µm) of the truth against the targets.
pub fn true_error_vectors_um(landed: &[Landed]) -> Vec<[f64; 2]> {
    landed
        .iter()
        .map(|l| {
            let t = l.row.target_mm.unwrap_or(l.true_mm);
            [(l.true_mm[0] - t[0]) * 1e3, (l.true_mm[1] - t[1]) * 1e3]
        })
        .collect()
}

/// Error vectors (µm) of the readings against the targets: measured − target, what the
/// instrument shows (e.g. at the grid nodes).
pub fn measured_error_vectors_um(landed: &[Landed]) -> Vec<[f64; 2]> {
    landed
        .iter()
        .map(|l| {
            let t = l.row.target_mm.unwrap_or(l.row.measured_mm);
            [
                (l.row.measured_mm[0] - t[0]) * 1e3,
                (l.row.measured_mm[1] - t[1]) * 1e3,
            ]
        })
        .collect()
}

/// Where measured visits landed, against their targets.
pub fn accuracy(landed: &[Landed]) -> Accuracy {
    let truth: Vec<f64> = true_error_vectors_um(landed)
        .iter()
        .map(|e| e[0].hypot(e[1]))
        .collect();
    let measured: Vec<f64> = landed
        .iter()
        .map(|l| {
            let t = l.row.target_mm.unwrap_or(l.row.measured_mm);
            (l.row.measured_mm[0] - t[0]).hypot(l.row.measured_mm[1] - t[1]) * 1e3
        })
        .collect();
    let (t, m) = (max_rms(&truth), max_rms(&measured));
    Accuracy {
        max_um: t.max,
        rms_um: t.rms,
        measured_max_um: m.max,
        measured_rms_um: m.rms,
        n_targets: landed.len(),
    }
}

/// What `host-sim measure` runs (the library API of the protocols; the command itself also
/// measures plan lists through [`measure_list`]).
#[derive(Clone, Debug)]
pub struct MeasureOptions {
    pub protocol: Protocol,
    /// Seeds the random targets and the instrument noise.
    pub seed: u64,
    /// Overrides the plant instrument's noise σ (µm).
    pub noise_um: Option<f64>,
    pub spec: MachineSpec,
}

/// Runs a protocol on a plant, commanded through `cal`, approached from each visit's start,
/// and returns the measurements.
pub fn measure(
    plant: &PlantConfig,
    cal: &Calibration<'_>,
    opts: &MeasureOptions,
) -> Result<Vec<Measurement>, CalibError> {
    measure_compensated(plant, cal, None, opts)
}

/// [`measure`] with the direction-dependent backlash correction in every command (a model file
/// with `backlash_urad`: `host-sim measure --model`).
pub fn measure_compensated(
    plant: &PlantConfig,
    cal: &Calibration<'_>,
    backlash: Option<&Backlash>,
    opts: &MeasureOptions,
) -> Result<Vec<Measurement>, CalibError> {
    let mut machine =
        PlantMachine::from_config(plant.clone(), "measured plant", opts.noise_um, opts.seed)?;
    let visits = visits(opts.protocol, opts.seed, &opts.spec);
    let landed = measure_list_compensated(
        &mut machine,
        cal,
        backlash,
        &visits,
        Approach::FromVisit,
        opts.seed,
        &opts.spec,
    )?;
    Ok(rows(&landed))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::closed_loop::tests::nominal;

    fn run(
        plant: &PlantConfig,
        protocol: Protocol,
        seed: u64,
        cal: &Calibration<'_>,
        noise_um: Option<f64>,
    ) -> Vec<Measurement> {
        measure(
            plant,
            cal,
            &MeasureOptions {
                protocol,
                seed,
                noise_um,
                spec: MachineSpec::paper(),
            },
        )
        .unwrap()
    }

    fn worst_error_mm(rows: &[Measurement]) -> f64 {
        rows.iter()
            .map(|m| {
                let t = m.target_mm.unwrap();
                (m.measured_mm[0] - t[0]).hypot(m.measured_mm[1] - t[1])
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn ideal_plant_measures_the_targets() {
        let rows = run(&PlantConfig::ideal(), Protocol::Table1, 1, &nominal(), None);
        assert_eq!(rows.len(), 9);
        // f32 commands: 0.1 µm class.
        assert!(worst_error_mm(&rows) < 2e-4, "{}", worst_error_mm(&rows));
    }

    #[test]
    fn paper_plant_resembles_table1() {
        let rows = run(
            &PlantConfig::paper(),
            Protocol::Grid,
            1,
            &nominal(),
            Some(0.0),
        );
        assert_eq!(rows.len(), 21 * 31);
        let worst = worst_error_mm(&rows);
        let t1 = run(
            &PlantConfig::paper(),
            Protocol::Table1,
            1,
            &nominal(),
            Some(0.0),
        );
        for m in &t1 {
            let t = m.target_mm.unwrap();
            eprintln!(
                "{:?} err {:.3} {:.3}",
                t,
                m.measured_mm[0] - t[0],
                m.measured_mm[1] - t[1]
            );
        }
        eprintln!("worst over grid {worst}");
        assert!((1.3..1.8).contains(&worst), "worst error {worst} mm");
        // The reference point reads (nearly) its target, as in the paper.
        let p1 = &t1[0];
        assert!((p1.measured_mm[0] - 212.132).hypot(p1.measured_mm[1]) < 0.02);
    }

    #[test]
    fn protocols_and_directions() {
        let rows = run(
            &PlantConfig::paper(),
            Protocol::Random(40),
            3,
            &nominal(),
            None,
        );
        let mut seen = std::collections::HashSet::new();
        for m in &rows {
            seen.insert(m.dir.unwrap());
        }
        assert_eq!(seen.len(), 4, "{seen:?}");
    }

    #[test]
    fn unreachable_target_is_an_error() {
        let mut cal = nominal();
        cal.model.a_mm = 50.0;
        let opts = MeasureOptions {
            protocol: Protocol::Table1,
            seed: 1,
            noise_um: None,
            spec: MachineSpec::paper(),
        };
        let err = measure(&PlantConfig::ideal(), &cal, &opts).unwrap_err();
        assert!(err.to_string().contains("target (212.132, 0.000)"), "{err}");
    }

    /// The repeat protocol's measurements and `accuracy` fit together: both axis
    /// lines are analysed, none skipped, and on a backlash-only plant both show a reversal.
    #[test]
    fn the_repeat_protocol_gives_both_axis_lines() {
        use crate::effect::PhysicalEffect;
        let cfg = PlantConfig::paper()
            .with_only(PhysicalEffect::Backlash)
            .unwrap();
        let rows = run(&cfg, Protocol::Repeat, 1, &nominal(), Some(0.2));
        let r = crate::calib::accuracy::report(&rows).unwrap();
        assert!(r.skipped.is_empty(), "{:?}", r.skipped);
        let axes: Vec<&str> = r.lines.iter().map(|l| l.axis).collect();
        assert_eq!(axes, ["x", "y"]);
        for l in &r.lines {
            assert!(
                l.iso_230_2.b_um > 0.5,
                "{} line: reversal {} µm",
                l.axis,
                l.iso_230_2.b_um
            );
        }
    }

    #[test]
    fn backlash_alone_shows_as_a_direction_dependent_error() {
        use crate::effect::PhysicalEffect;
        let cfg = PlantConfig::paper()
            .with_only(PhysicalEffect::Backlash)
            .unwrap();
        let rows = run(&cfg, Protocol::Repeat, 1, &nominal(), None);
        // On the x line (y = 0) motor 1 and 2 move in opposite directions; ascending and
        // descending passes must be displaced in opposite directions by about J·β/2.
        let mut shift = [0.0f64; 2];
        let mut n = [0usize; 2];
        for m in rows
            .iter()
            .filter(|m| m.run == Some(0) && m.target_mm.unwrap()[1] == 0.0)
        {
            let k = usize::from(m.dir.unwrap()[0] < 0);
            shift[k] += m.measured_mm[0] - m.target_mm.unwrap()[0];
            n[k] += 1;
        }
        let (a, b) = (shift[0] / n[0] as f64 * 1e3, shift[1] / n[1] as f64 * 1e3);
        assert!(
            a * b < 0.0 && a.abs() > 0.5 && b.abs() > 0.5,
            "mean x error by direction: {a} um, {b} um"
        );
    }
}
