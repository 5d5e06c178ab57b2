//! The moving machine's diagnosis on plants with effects hidden in them, drawn at random
//! (magnitudes, phases, periods, pairs) from seeds the tests do not choose by outcome: each
//! named exactly, nothing named on a plant without, the residual at least halved, and the
//! following error of a fresh 5 g motion on the plant itself no larger with the updated block
//! (much smaller where the effect shows at 5 g). And the refusals of logs that cannot be
//! diagnosed.
//!
//! The plants are the paper plant (friction, backlash, quantisation, the linkage's bodies) with
//! the five-bar tool point: the drives and the linkage's inertia are the six-bar's, only the
//! tool point is computed in closed form (the telemetry does not see it), which keeps each run
//! within a second.

use super::diagnose::{diagnose_telemetry, DiagnoseOptions};
use super::excitation::ExcitationOptions;
use super::identify::identify_on_plant;
use super::predict::Controller;
use super::report::DynamicReport;
use super::samples::SampleOptions;
use super::session::{run_on_plant, ExcitationRun, PlantRunOptions};
use super::DynError;
use crate::effect::PhysicalEffect;
use crate::machine_spec::MachineSpec;
use crate::plant::{Plant, PlantConfig, PlantModel};
use crate::sim::closed_loop::{loop_config, run_loop_configured, FeedForward};
use crate::sim::motions::Trajectory;
use kinematics_core::{Calibration, FiveBar, FiveBarDynamics, ServoConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::OnceLock;

/// The machine before anything is hidden in it, and its identified model (what the controller
/// feeds forward in every run below).
struct Bench {
    spec: MachineSpec,
    base: PlantConfig,
    d0: FiveBarDynamics<f64>,
    servo: ServoConfig,
}

fn cal() -> Calibration<'static> {
    Calibration {
        model: FiveBar::<f32>::paper_nominal(),
        grid: None,
    }
}

fn sample_options(spec: &MachineSpec) -> SampleOptions {
    SampleOptions {
        model: spec.nominal,
        min_transmission: spec.min_transmission,
        torque_limit_nm: [8.0; 2],
    }
}

fn run_options(spec: &MachineSpec, feedforward: FeedForward) -> PlantRunOptions {
    PlantRunOptions {
        spec: spec.clone(),
        excitation: ExcitationOptions::default(),
        decimation: 20,
        feedforward,
        servo: None,
        seed: 1,
    }
}

fn bench() -> &'static Bench {
    static BENCH: OnceLock<Bench> = OnceLock::new();
    BENCH.get_or_init(|| {
        let spec = MachineSpec::paper();
        let mut base = PlantConfig::paper();
        base.sixbar.model = PlantModel::Fivebar;
        let so = sample_options(&spec);
        let d0 = identify_on_plant(
            &base,
            &cal(),
            &run_options(&spec, FeedForward::Constant),
            &so,
        )
        .unwrap()
        .result
        .identified
        .dynamics;
        let servo = loop_config(&Plant::new(&base, 1), &spec);
        Bench {
            spec,
            base,
            d0,
            servo,
        }
    })
}

/// The excitation on `plant` with the controller feeding forward the machine's model.
fn telemetry(plant: &PlantConfig) -> ExcitationRun {
    let b = bench();
    run_on_plant(
        plant,
        &cal(),
        &run_options(&b.spec, FeedForward::Dynamics(b.d0)),
    )
    .unwrap()
}

fn diagnose(run: &ExcitationRun) -> Result<DynamicReport, DynError> {
    let b = bench();
    let opts = DiagnoseOptions {
        spec: b.spec.clone(),
        samples: sample_options(&b.spec),
        controller: Controller::new(&b.spec, b.spec.nominal, b.servo, b.d0).unwrap(),
    };
    diagnose_telemetry(&run.log, &run.path, &opts)
}

/// `effect` hidden in `plant` at a random magnitude large enough to matter (drawn from `rng`).
fn hide(plant: &mut PlantConfig, effect: PhysicalEffect, rng: &mut ChaCha8Rng) {
    let drives = [&mut plant.drive_1, &mut plant.drive_2];
    match effect {
        PhysicalEffect::CoulombFriction => {
            for d in drives {
                d.coulomb_friction_nm += rng.random_range(0.05..0.12);
            }
        }
        PhysicalEffect::ViscousFriction => {
            for d in drives {
                d.viscous_friction_nm_s_per_rad += rng.random_range(0.03..0.08);
            }
        }
        PhysicalEffect::ToolMass => plant.linkage.tool_mass_kg += rng.random_range(0.06..0.12),
        PhysicalEffect::MotorInertia => {
            let k = rng.random_range(0..2usize);
            let delta = if rng.random_bool(0.5) {
                rng.random_range(1.5e-3..3.0e-3)
            } else {
                -rng.random_range(1.5e-3..1.8e-3)
            };
            [&mut plant.drive_1, &mut plant.drive_2][k].inertia_kg_m2 += delta;
        }
        PhysicalEffect::Cogging => {
            let cycles = f64::from(rng.random_range(3..=12u32));
            for d in drives {
                d.cogging_nm = rng.random_range(0.05..0.1);
                d.cogging_cycles_per_motor_rev = cycles;
                d.cogging_phase_deg = rng.random_range(0.0..360.0);
            }
        }
        other => panic!("{other} has no hidden form here"),
    }
    plant.description = format!("{} + {effect}", plant.description);
}

/// The following error at the tool of `figure8-5g` on `plant` with `d` fed forward: RMS and max
/// (µm).
fn fresh_following_um(plant: &PlantConfig, d: FiveBarDynamics<f64>) -> (f64, f64) {
    let b = bench();
    let tr = Trajectory::by_name("figure8-5g", &b.spec).unwrap();
    let mut p = Plant::new(plant, 1);
    let s = run_loop_configured(
        &mut p,
        &cal(),
        &tr,
        tr.natural_duration_s(),
        &b.spec,
        &FeedForward::Dynamics(d),
        b.servo,
        None,
    )
    .unwrap();
    assert!(s.fault.is_none(), "{s:?}");
    (s.rms_following_err_um, s.max_following_err_um)
}

/// The block out of the report, as the servo takes it.
fn model_out(r: &DynamicReport) -> FiveBarDynamics<f64> {
    let m = r.model_out.as_ref().expect("the updated block");
    let p = kinematics_core::dynamics::PARAMETER_NAMES.map(|n| m[n]);
    FiveBarDynamics::from_array(p, bench().d0.coulomb_speed_rad_s)
}

/// Hides `effects` (drawn with `seed`), diagnoses, and checks: named exactly, residual at least
/// halved, a fresh 5 g motion's following error not larger with the updated block (at least
/// halved when the hidden effects cost the rated motion twice the following error).
fn hidden_effects_are_named(effects: &[PhysicalEffect], seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut plant = bench().base.clone();
    for e in effects {
        hide(&mut plant, *e, &mut rng);
    }
    let r = diagnose(&telemetry(&plant)).unwrap();
    eprintln!("{}{}", plant.description, super::report::table(&r));
    let mut named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    let mut hidden: Vec<&str> = effects.iter().map(|e| e.name()).collect();
    named.sort();
    hidden.sort();
    assert_eq!(named, hidden, "seed {seed}: {}", plant.description);
    assert!(
        r.final_rms_um <= 0.5 * r.initial_rms_um,
        "residual {} -> {} um",
        r.initial_rms_um,
        r.final_rms_um
    );
    let d0 = bench().d0;
    let (before, after) = (
        fresh_following_um(&plant, d0),
        fresh_following_um(&plant, model_out(&r)),
    );
    let clean = fresh_following_um(&bench().base, d0);
    eprintln!(
        "figure8-5g following error RMS / max: the plant without the effects {:.3} / {:.2} um; \
         with them, the model as it was {:.3} / {:.2} um, the updated block {:.3} / {:.2} um",
        clean.0, clean.1, before.0, before.1, after.0, after.1
    );
    assert!(after.0 <= 1.02 * before.0, "{before:?} -> {after:?}");
    if before.0 > 2.0 * clean.0 && !effects.contains(&PhysicalEffect::Cogging) {
        assert!(after.0 <= 0.5 * before.0, "{before:?} -> {after:?}");
    }
}

#[test]
fn nothing_is_named_on_a_plant_without_hidden_effects() {
    let r = diagnose(&telemetry(&bench().base)).unwrap();
    eprintln!("{}", super::report::table(&r));
    assert!(r.steps.is_empty(), "{:?}", r.steps);
    assert!(!r.unexplained, "{}", r.unexplained_description);
    assert_eq!(r.initial_rms_um, r.final_rms_um);
}

#[test]
fn a_hidden_coulomb_friction_is_named() {
    hidden_effects_are_named(&[PhysicalEffect::CoulombFriction], 101);
}

#[test]
fn a_hidden_viscous_friction_is_named() {
    hidden_effects_are_named(&[PhysicalEffect::ViscousFriction], 102);
}

#[test]
fn a_heavier_tool_is_named() {
    hidden_effects_are_named(&[PhysicalEffect::ToolMass], 103);
}

#[test]
fn a_motor_inertia_error_is_named() {
    hidden_effects_are_named(&[PhysicalEffect::MotorInertia], 104);
}

#[test]
fn cogging_is_named_with_its_period() {
    hidden_effects_are_named(&[PhysicalEffect::Cogging], 105);
}

#[test]
fn two_hidden_effects_are_both_named() {
    use PhysicalEffect::*;
    let pool = [
        CoulombFriction,
        ViscousFriction,
        ToolMass,
        MotorInertia,
        Cogging,
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(106);
    for seed in 107..109 {
        let a = rng.random_range(0..pool.len());
        let b = (a + rng.random_range(1..pool.len())) % pool.len();
        hidden_effects_are_named(&[pool[a], pool[b]], seed);
    }
}

/// A torque constant's error is most of the inertia's signature on this machine (its diagonal
/// inertia does not change with the configuration): named, or declared confounded with what
/// is named in its place.
#[test]
fn a_torque_constant_error_is_named_or_declared_confounded() {
    let mut plant = bench().base.clone();
    plant.drive_1.torque_constant_error_pct = 12.0;
    let r = diagnose(&telemetry(&plant)).unwrap();
    eprintln!("{}", super::report::table(&r));
    let named = r.steps.iter().any(|s| s.effect == "torque_constant");
    let declared = r
        .confounded
        .iter()
        .any(|g| g.iter().any(|e| e == "torque_constant"));
    assert!(named || declared, "{:?} {:?}", r.steps, r.confounded);
}

/// Logs that cannot be diagnosed are refused, saying what is missing.
#[test]
fn logs_too_short_with_gaps_or_of_another_machine_are_refused() {
    let run = telemetry(&bench().base);
    let refused = |log: &crate::io::telemetry_csv::TelemetryLog| {
        let r = ExcitationRun {
            log: log.clone(),
            ..run.clone()
        };
        diagnose(&r).unwrap_err().to_string()
    };
    // The first 2 s only: too short for the motion.
    let mut short = run.log.clone();
    short.rows.truncate(200);
    let e = refused(&short);
    assert!(e.contains("record the whole motion"), "{e}");
    // Samples lost on the way.
    let mut gaps = run.log.clone();
    gaps.rows.drain(400..420);
    let e = refused(&gaps);
    assert!(e.contains("gaps") && e.contains("decimation"), "{e}");
    // Another machine by its name, and by its angles.
    let mut named = run.log.clone();
    named.meta.as_mut().unwrap().machine =
        crate::io::machine_file::parse_machine(include_str!("../../machines/second.toml"))
            .unwrap()
            .identity();
    let e = refused(&named);
    assert!(e.contains("machine 'second'"), "{e}");
    let mut other = run.log.clone();
    for r in &mut other.rows {
        r.reference_rad[0] += 0.01;
    }
    let e = refused(&other);
    assert!(e.contains("another machine"), "{e}");
    // Another motion.
    let mut moved = run.log.clone();
    for r in &mut moved.rows {
        r.setpoint_mm[0] += 0.5;
    }
    let e = refused(&moved);
    assert!(
        e.contains("do not follow these knots") || e.contains("never leave"),
        "{e}"
    );
}
